"""What capping a part's convex pieces (``scene.max_convex_pieces``) saves in pile time and costs in shape.

    python scripts/bench/bench_convex_cap.py --objects tless20,itodd13,bunny --caps 0,20 --drops 40 --piles 2

Per part and cap: the convex pieces of its collision shape (the dense recipe's scene: CoACD for MuJoCo,
merged toward the cap while the merges add at most ``--budget`` of the volume),
the volume the merged pieces add to the full decomposition (Monte Carlo over the shape's box, % of the
full decomposition's volume), and the MuJoCo simulation of ``--piles`` piles of ``--drops`` parts (the
recipe's rig sized to the part; seeds 0, 1, ...; physics only, nothing rendered): seconds and steps per
pile, milliseconds per step, the share of a step spent finding contacts (``mj_collision``, timed on the
last pile at rest), re-drops. Both arms simulate the same piles in the same process, one after
the other (cap 0 = every piece of the decomposition). Times are CPU time of this process (MuJoCo runs on one
thread), which other jobs on the machine disturb less than wall time; compare rows of one run.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time

import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from opnet.cli.evaluate import resolve_object
from opnet.studies.scenes import dense_scene
from opnet.synthesis.collision import build_collision_model, convex_parts
from opnet.synthesis.cycle import cycle_rngs
from opnet.synthesis.layout import make_rig, sample_layout
from opnet.synthesis.physics import make_simulator


def _inside(parts: list[np.ndarray], points: np.ndarray) -> np.ndarray:
    """Which ``points`` lie in the union of the convex hulls of ``parts``."""
    from scipy.spatial import ConvexHull

    out = np.zeros(len(points), dtype=bool)
    for p in parts:
        eq = ConvexHull(p).equations
        out |= (points @ eq[:, :3].T + eq[:, 3] <= 1e-12).all(1)
    return out


def added_volume(full: list[np.ndarray], capped: list[np.ndarray], samples: int, seed: int = 0) -> float:
    """Volume inside ``capped`` but outside ``full``, as a fraction of ``full``'s (Monte Carlo)."""
    pts = np.concatenate(full)
    lo, hi = pts.min(0), pts.max(0)
    x = np.random.default_rng(seed).uniform(lo, hi, size=(samples, 3))
    a, b = _inside(full, x), _inside(capped, x)
    return float((b & ~a).sum() / max(a.sum(), 1))


def collision_share(sim, steps: int = 60) -> float:
    """Share of a MuJoCo step spent finding contacts, on a copy of the simulator's state: each step
    is followed by a contact pass of the same state, timed apart (so a load on the machine falls on
    both alike)."""
    import copy

    import mujoco

    m, d = sim.model, copy.deepcopy(sim.data)
    step = contacts = 0.0
    for _ in range(steps):
        t0 = time.process_time()
        mujoco.mj_step(m, d)
        t1 = time.process_time()
        mujoco.mj_collision(m, d)
        step, contacts = step + t1 - t0, contacts + time.process_time() - t1
    return contacts / step


def time_piles(obj, scene, collision, drops: int, piles: int) -> tuple[float, float, float, float, float]:
    """(CPU s per pile, steps per pile, CPU ms per step, re-drops per pile, contacts' share of a step
    in the last pile) of MuJoCo piles of ``collision`` in ``scene`` (sized to the part), nothing rendered."""
    rig = make_rig(obj, drops, piles, scene)
    seconds = steps = redrops = 0.0
    with make_simulator(rig, collision, scene) as sim:
        for pile in range(piles):
            layout_rng, drop_rng = cycle_rngs(0, pile)
            layout = sample_layout(rig, scene, layout_rng)
            t0 = time.process_time()
            states = sim.simulate(layout, drops, drop_rng)
            seconds += time.process_time() - t0
            steps += states.stats.steps
            redrops += states.stats.redrops
        share = collision_share(sim)
    return seconds / piles, steps / piles, 1e3 * seconds / max(steps, 1), redrops / piles, share


def pieces(collision) -> list[np.ndarray]:
    """The convex pieces of a collision model (its decomposition's, or the hull's vertices)."""
    return convex_parts(collision.obj_file) if collision.obj_file is not None else [collision.vertices]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", default="tless20,itodd13,bunny")
    ap.add_argument("--caps", default="0,20", help="max_convex_pieces values (0: no cap)")
    ap.add_argument("--drops", type=int, default=40)
    ap.add_argument("--piles", type=int, default=2)
    ap.add_argument("--budget", type=float, default=None,
                    help="convex_merge_budget (default: the recipe's; 1 merges down to the cap whatever it adds)")
    ap.add_argument("--samples", type=int, default=400_000, help="Monte Carlo points for the added volume")
    args = ap.parse_args()
    caps = [int(c) for c in args.caps.split(",")]
    base = dense_scene(views=1)
    if args.budget is not None:
        base = dataclasses.replace(base, convex_merge_budget=args.budget)
    print(f"the dense recipe's scene (MuJoCo), merge budget {base.convex_merge_budget:g} of the volume, "
          f"{args.piles} pile(s) of {args.drops} drops per row, 1 process\n")
    print("| object | cap | convex pieces | added volume | CPU s per pile | steps per pile | CPU ms per step | contacts |"
          " re-drops per pile |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in args.objects.split(","):
        obj = resolve_object(name)
        scenes = {cap: dataclasses.replace(base, max_convex_pieces=cap).for_part(obj.diameter) for cap in {0, *caps}}
        models = {cap: build_collision_model(obj.mesh, scene) for cap, scene in scenes.items()}
        full = pieces(models[0])
        for cap in caps:
            parts = pieces(models[cap])
            added = added_volume(full, parts, args.samples)
            s, steps, ms, redrops, share = time_piles(obj, scenes[cap], models[cap], args.drops, args.piles)
            print(f"| {name} | {cap or 'none'} | {len(parts)} | {100 * added:.1f} % | {s:.1f} | {steps:.0f} | {ms:.2f} | "
                  f"{100 * share:.0f} % | {redrops:.1f} |", flush=True)


if __name__ == "__main__":
    main()
