"""Where one drop cycle's time goes: physics (spawn, stepping, settle checks), rendering (the scene
pass, the visibility passes), the sensor model, PNG encoding and writing.

    python scripts/bench/profile_generate.py --objects bunny,ring_screw --scene bulk --drops 75 \
        --camera-file conf/cameras/sileane_bunny.yaml --camera-height 1.5 --cycles 2

Runs in this process (one worker), after a warm-up render; each stage is timed by wrapping the
function that does it, so the table adds up to the cycle's wall time (the rest is "other"). The
percentages are of the whole cycle. ``--set key=value`` overrides any scene setting (repeatable;
``--set views=4`` renders four views of every settled pile). Objects are built-in names or conf/object names
(bunny and ring_screw read ../shared).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from opnet.cli.evaluate import resolve_object  # noqa: E402
from opnet.studies.scenes import scene_overrides, scene_preset
from opnet.synthesis import CycleGenerator, SceneConfig  # noqa: E402

#: (stage, module path, attribute owner, attribute): the functions whose time makes each stage
STAGES = (
    ("physics: spawn", "opnet.synthesis.physics", "BinSimulator", "_spawn"),
    ("physics: settle (step + checks)", "opnet.synthesis.physics", "BinSimulator", "_settle"),
    ("physics: world set-up", "opnet.synthesis.physics", "BinSimulator", "_build_world"),
    ("render: scene pass (depth + segmentation)", "opnet.synthesis.rendering", "SceneRenderer", "render"),
    ("render: visibility passes", "opnet.synthesis.rendering", "SceneRenderer", "_solo_counts"),
    ("sensor model", "opnet.synthesis.sensor", "SensorModel", "apply"),
    ("write: PNG encoding + file", "opnet.datasets.ipa", None, "write_png"),
    ("write: CSV and the rest", "opnet.synthesis.writer", None, "write_cycle"),
)


class StageClock:
    """Wraps functions so that their inclusive time is summed per stage (nested stages are not
    double counted: a stage's time excludes the stages called inside it)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._stack: list[list[float]] = []

    def wrap(self, stage: str, fn: Callable) -> Callable:
        def timed(*args, **kwargs):
            self._stack.append([0.0])
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                dt = time.perf_counter() - t0
                inner = self._stack.pop()[0]
                self.seconds[stage] += dt - inner
                self.calls[stage] += 1
                if self._stack:
                    self._stack[-1][0] += dt

        return timed

    @contextlib.contextmanager
    def installed(self) -> Iterator[None]:
        import importlib

        saved = []
        for stage, module_name, owner, attr in STAGES:
            module = importlib.import_module(module_name)
            target = getattr(module, owner) if owner else module
            if not hasattr(target, attr):
                continue
            original = getattr(target, attr)
            saved.append((target, attr, original))
            setattr(target, attr, self.wrap(stage, original))
        try:
            yield
        finally:
            for target, attr, original in saved:
                setattr(target, attr, original)


def profile_object(name: str, drops: int, scene: SceneConfig, piles: int) -> tuple[dict[str, float], float, int]:
    """(seconds per stage, wall seconds, scenes) over ``piles`` piles after a warm-up render."""
    import opnet.synthesis.writer as writer_module

    obj = resolve_object(name)
    clock = StageClock()
    with tempfile.TemporaryDirectory(prefix="profile_generate_") as tmp, CycleGenerator(obj, drops, scene) as gen:
        gen.renderer.begin_cycle(np.eye(4))  # warm-up: GL programs
        gen.renderer.render(np.zeros((0, 4, 4)))
        # the library before scene.views existed has generate(seed, cycle) only (a "before" profile)
        views = gen.generate_views if hasattr(gen, "generate_views") else lambda seed, p: [gen.generate(seed, p)]
        scenes = 0
        with clock.installed():
            t0 = time.perf_counter()
            for p in range(piles):
                for result in views(0, p):
                    writer_module.write_cycle(Path(tmp), result)
                    scenes += len(result.records)
            wall = time.perf_counter() - t0
    return dict(clock.seconds), wall, scenes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", default="bunny,ring_screw")
    ap.add_argument("--scene", default="bulk", help="conf/scene preset")
    ap.add_argument("--drops", type=int, default=75)
    ap.add_argument("--cycles", type=int, default=1, help="piles timed per object")
    ap.add_argument("--camera-file", default=None)
    ap.add_argument("--camera-height", type=float, default=None)
    ap.add_argument("--set", action="append", default=[], help="scene key=value override (repeatable)")
    args = ap.parse_args()
    scene = scene_preset(args.scene, **scene_overrides(args.camera_file, args.camera_height, args.set))
    print(f"scene={args.scene} {' '.join(args.set)}, camera {args.camera_file or 'built-in'}, {args.drops} drops, "
          f"{getattr(scene, 'views', 1)} view(s) per pile, {args.cycles} pile(s) timed per object, 1 process\n")
    print("| object | stage | s per pile | ms per scene | share |")
    print("|---|---|---|---|---|")
    for name in args.objects.split(","):
        seconds, wall, scenes = profile_object(name, args.drops, scene, args.cycles)
        seconds["other"] = wall - sum(seconds.values())
        for stage in [s for s, *_ in STAGES] + ["other"]:
            if stage in seconds:
                s = seconds[stage]
                print(f"| {name} | {stage} | {s / args.cycles:.2f} | {1e3 * s / scenes:.1f} | {100 * s / wall:.0f} % |")
        print(f"| {name} | **total** | {wall / args.cycles:.2f} | {1e3 * wall / scenes:.1f} | "
              f"{scenes / wall:.2f} scenes/s |")


if __name__ == "__main__":
    main()
