"""Benchmark the synthetic data engine: scenes per second at 512 x 512 with 20 parts per cycle.

    python scripts/bench/bench_generate.py                       # bracket, 1 and 2 workers, 6 cycles each
    python scripts/bench/bench_generate.py --objects bracket,pin --cycles 6 --breakdown
    python scripts/bench/bench_generate.py --scene bulk --drops 75 --cycles 2   # Siléane-like bulk piles

Pool start-up (process spawn, imports, EGL and pybullet set-up) is reported separately and not
counted in scenes/s. ``--breakdown`` times physics, rendering and writing of one cycle in this
process. Objects: built-in names, or conf/object names (bunny, ring_screw, gear_shaft need ../shared).
``--scene`` names a conf/scene preset (``bulk``: 70-80 parts in several layers). The table also
gives the pile's occlusion in the last scene of every cycle: parts fully hidden (visibility 0)
and parts less than half visible.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from opnet.cli.evaluate import resolve_object  # noqa: E402
from opnet.objects import ObjectModel  # noqa: E402
from opnet.studies.scenes import scene_overrides, scene_preset
from opnet.synthesis import CycleGenerator, SceneConfig, generate_dataset  # noqa: E402
from opnet.synthesis.writer import write_cycle  # noqa: E402


def breakdown(obj: ObjectModel, drops: int, scene: SceneConfig, out: Path) -> str:
    """Per-scene milliseconds of physics, rendering and writing for one cycle, in this process."""
    with CycleGenerator(obj, drops, scene) as gen:
        gen.generate(0, 99)  # warm-up: caches, GL programs
        from opnet.synthesis.cycle import cycle_rngs
        from opnet.synthesis.layout import sample_layout

        layout_rng, drop_rng = cycle_rngs(0, 0)
        layout = sample_layout(gen.rig, scene, layout_rng)
        t0 = time.perf_counter()
        states = gen.simulator.simulate(layout, drops, drop_rng)
        t1 = time.perf_counter()
        gen.renderer.begin_cycle(layout.T_cam_world @ layout.T_world_bin)
        solo = sum(gen.renderer.render(layout.T_cam_world @ T).solo_renders for T in states.T_world_obj)
        t2 = time.perf_counter()
        result = gen.generate(0, 0)
        from opnet.datasets.ipa_params import write_parameters

        write_parameters(out, gen.rig.params)
        t3 = time.perf_counter()
        write_cycle(out, result)
        t4 = time.perf_counter()
    n = drops + 1
    return (
        f"{obj.name}: per scene physics {1e3 * (t1 - t0) / n:.0f} ms ({states.stats.steps / drops:.0f} steps/drop), "
        f"rendering {1e3 * (t2 - t1) / n:.0f} ms ({solo / n:.1f} solo renders/scene), writing {1e3 * (t4 - t3) / n:.0f} ms"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", default="bracket")
    ap.add_argument("--workers", default="1,2")
    ap.add_argument("--cycles", type=int, default=6)
    ap.add_argument("--drops", type=int, default=20)
    ap.add_argument("--resolution", type=int, default=512)
    ap.add_argument("--breakdown", action="store_true")
    ap.add_argument("--scene", default="default", help="conf/scene preset (e.g. bulk)")
    ap.add_argument("--camera-file", default=None, help="camera YAML / camera_params.txt (its clip planes used)")
    ap.add_argument("--camera-height", type=float, default=None)
    ap.add_argument("--set", action="append", default=[], help="scene key=value override (repeatable)")
    ap.add_argument("--keep", default=None, help="keep the generated datasets in this folder (for pile_stats.py)")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    scene = scene_preset(args.scene, resolution=args.resolution,
                         **scene_overrides(args.camera_file, args.camera_height, args.set))
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_generate_") as tmp_dir:
        tmp = args.keep or tmp_dir
        for name in args.objects.split(","):
            obj = resolve_object(name)
            if args.breakdown:
                print(breakdown(obj, args.drops, scene, Path(tmp) / f"{name}_breakdown"))
            for workers in (int(w) for w in args.workers.split(",")):
                out = Path(tmp) / f"{name}_w{workers}"
                r = generate_dataset(obj, out, args.cycles, args.drops, workers=workers, seed=args.seed, scene=scene,
                                     progress=False, previews=0)
                rows.append((name, workers, r, occlusion(out, args.drops)))
    print(f"\nscene={args.scene} {' '.join(args.set)}, camera {args.camera_file or f'{args.resolution} x {args.resolution}'}, "
          f"{args.drops} drops per cycle, {getattr(scene, 'views', 1)} view(s) per pile, {os.cpu_count()} CPUs. "
          "scenes/s: after the first worker is ready; steady: sum over workers of scenes / busy time\n")
    print("| object | workers | cycles | scenes | start-up s | total s | scenes/s | steady scenes/s "
          "| re-drops | unsettled | solo renders/scene | fully hidden | < 50 % visible |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, workers, r, (hidden, half) in rows:
        print(f"| {name} | {workers} | {r.cycles_generated} | {r.scenes_written} | {r.startup_seconds:.1f} | "
              f"{r.seconds:.1f} | {r.scenes_per_second:.2f} | {r.steady_scenes_per_second:.2f} | {r.redrops} | "
              f"{r.unsettled} | {r.solo_renders / max(r.scenes_written, 1):.1f} | {100 * hidden:.0f} % | {100 * half:.0f} % |")


def occlusion(root: Path, drops: int) -> tuple[float, float]:
    """Shares of parts fully hidden and less than half visible in the last scene of every cycle."""
    from opnet.datasets.ipa import IPADataset

    ds = IPADataset(root)
    vis = np.concatenate([ds[i].visibility for i in range(len(ds)) if ds.scene_name(i).endswith(f"_{drops:03d}")])
    return float((vis == 0).mean()), float((vis < 0.5).mean())


if __name__ == "__main__":
    main()
