"""MuJoCo against pybullet: the same piles? how fast?

    python scripts/bench/bench_physics.py --objects bunny,ring_screw --cycles 4 --out results/physics/ab.md

Per object and engine, the same dataset settings and seed (Siléane-like bulk piles of 75 parts seen
by the Siléane bunny camera, 1.5 m above the floor; ``--scene``, ``--drops``, ``--camera-file``
change that): the time one pile's physics takes in this process (the mean over ``--piles``
piles: the engines alone), then a dataset of ``--cycles`` cycles generated with ``--workers``
workers (scenes/s of the whole generator: physics, rendering, writing), and the pile statistics of
:func:`opnet.studies.scenes.pile_stats` on it (parts per scene, visibility histogram, pile height, share lying flat and
fully hidden). Each engine uses its own convex decomposition of concave parts (MuJoCo: CoACD;
pybullet: its V-HACD); their part counts are in the table. The datasets are kept under ``--keep``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
from opnet.cli.evaluate import resolve_object  # noqa: E402
from opnet.studies.scenes import VIS_LABELS, pile_stats, scene_overrides, scene_preset
from opnet.synthesis import SceneConfig, generate_dataset  # noqa: E402
from opnet.synthesis.collision import build_collision_model, convex_parts  # noqa: E402
from opnet.synthesis.cycle import cycle_rngs  # noqa: E402
from opnet.synthesis.layout import make_rig, sample_layout  # noqa: E402
from opnet.synthesis.physics import make_simulator  # noqa: E402

ENGINES = ("pybullet", "mujoco")


def physics_seconds(name: str, drops: int, scene: SceneConfig, piles: int, seed: int) -> tuple[float, int, int, int]:
    """(mean seconds per pile, convex parts, re-drops, unsettled drops) of the engine alone."""
    obj = resolve_object(name)
    rig = make_rig(obj, drops, piles, scene)
    collision = build_collision_model(obj.mesh, scene)  # cached: not timed
    parts = len(convex_parts(collision.obj_file)) if collision.obj_file else 1
    redrops = unsettled = 0
    start = time.perf_counter()
    with make_simulator(rig, collision, scene) as sim:
        for pile in range(piles):
            layout_rng, drop_rng = cycle_rngs(seed, pile)
            stats = sim.simulate(sample_layout(rig, scene, layout_rng), drops, drop_rng).stats
            redrops, unsettled = redrops + stats.redrops, unsettled + stats.unsettled
    return (time.perf_counter() - start) / piles, parts, redrops, unsettled


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", default="bunny,ring_screw")
    ap.add_argument("--engines", default=",".join(ENGINES))
    ap.add_argument("--scene", default="bulk")
    ap.add_argument("--drops", type=int, default=75)
    ap.add_argument("--cycles", type=int, default=4)
    ap.add_argument("--piles", type=int, default=2, help="piles timed for the engine alone")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--camera-file", default="conf/cameras/sileane_bunny.yaml")
    ap.add_argument("--camera-height", type=float, default=1.5)
    ap.add_argument("--set", action="append", default=[], help="scene key=value override (repeatable)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--keep", type=Path, default=Path("outputs/bench_physics"))
    ap.add_argument("--out", type=Path, default=None, help="also write the table (markdown) here")
    args = ap.parse_args()
    for engine in args.engines.split(","):
        if engine not in ENGINES:
            raise SystemExit(f"--engines: unknown physics engine {engine!r}; expected some of {ENGINES}")
    base = scene_overrides(args.camera_file, args.camera_height, args.set)
    rows = []
    for name in args.objects.split(","):
        for engine in args.engines.split(","):
            scene = scene_preset(args.scene, **{**base, "physics": engine})
            per_pile, parts, redrops, unsettled = physics_seconds(name, args.drops, scene, args.piles, args.seed)
            out = args.keep / f"{name}_{engine}"
            report = generate_dataset(resolve_object(name), out, args.cycles, args.drops, workers=args.workers,
                                      seed=args.seed, scene=scene, progress=False, previews=0)
            rows.append((name, engine, parts, per_pile, redrops, unsettled, report, pile_stats(out)))
            print(f"{name} {engine}: {per_pile:.1f} s/pile, {report.scenes_per_second:.2f} scenes/s", flush=True)
    head = ("| object | engine | convex parts | physics s / pile | re-drops, unsettled | scenes/s (" + str(args.workers)
            + " workers) | scenes | parts / scene | " + " | ".join(f"vis {v}" for v in VIS_LABELS)
            + " | pile top mm (sd) | mean part height mm | lying flat | fully hidden (full piles) |")
    lines = [
        (f"scene={args.scene} {' '.join(args.set)}, camera {args.camera_file} at {args.camera_height} m, {args.drops} drops, "
         f"seed {args.seed}; physics alone: {args.piles} piles in this process; generation: {args.cycles} cycles, "
         f"{args.workers} workers, {os.cpu_count()} CPUs."), "", head, "|" + "---|" * (head.count("|") - 1)]
    for name, engine, parts, per_pile, redrops, unsettled, r, s in rows:
        hist = " | ".join(f"{100 * h:.1f} %" for h in s["vis_hist"])
        lines.append(f"| {name} | {engine} | {parts} | {per_pile:.1f} | {redrops}, {unsettled} | {r.scenes_per_second:.2f} | "
                     f"{s['scenes']} | {s['parts_per_scene']:.1f} | {hist} | {s['height_max_mm']:.0f} ({s['height_max_sd_mm']:.0f}) | "
                     f"{s['height_mean_mm']:.0f} | {100 * s['flat']:.1f} % | {100 * s['hidden']:.1f} % |")
    text = "\n".join(lines)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.out.with_name(args.out.name + ".tmp")
        tmp.write_text(f"Command: `python scripts/bench/bench_physics.py {' '.join(sys.argv[1:])}`\n\n{text}\n")
        os.replace(tmp, args.out)


if __name__ == "__main__":
    main()
