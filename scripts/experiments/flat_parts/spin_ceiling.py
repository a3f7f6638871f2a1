"""The AP a perfect network can reach on a part whose spin the depth shows only from some views.

Every part to find in a split's ground truth is given back as its own hypothesis, exact in position and in
the tilt of its main axis. Where the camera sees that axis within ``--cutoffs`` degrees of the line of sight
(the views :mod:`spin_observability` finds the spin to show in), the spin is exact too; beyond, the depth holds
no spin, so the hypothesis turns the part about its axis by a spin drawn at random, and is ranked after every
exact one (the best a network could do: know which spins it cannot see). The Brégier AP of those hypotheses
(the project's evaluator, the part's own symmetry group), averaged over ``--draws`` random draws, is the
ceiling of AP as decoded on that split for any network that reads nothing the depth does not hold.

    python scripts/experiments/flat_parts/spin_ceiling.py --object itodd08 \\
        --root outputs/data/dense/itodd08_test_p12_d75_s1 --min-objects 70

``--root``: a generated dataset; every scene with at least ``--min-objects`` parts is scored (the new-parts
benchmark's held-out piles: 70). Prints a table (``--out``: also writes it, with the command, as a Markdown page).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402

from opnet.datasets.autodetect import open_dataset  # noqa: E402
from opnet.geometry.pose_numpy import rodrigues  # noqa: E402
from opnet.metrics.bregier import evaluate_scenes, instances_to_find  # noqa: E402
from opnet.metrics.breakdown import axis_angle, main_axis  # noqa: E402
from opnet.metrics.records import GroundTruthSet, HypothesisSet  # noqa: E402
from opnet.objects import object_from_config  # noqa: E402
from opnet.studies import compose_train, write_table_page  # noqa: E402


def ceiling_hypotheses(gt: GroundTruthSet, angles: np.ndarray, cutoff: float, axis: np.ndarray,
                       find: np.ndarray, rng: np.random.Generator) -> HypothesisSet:  # fmt: skip
    """The parts to find as hypotheses: exact within ``cutoff`` (score 1), turned about their axis by a random
    spin beyond it (score 0.5)."""
    R = np.asarray(gt.R[find], np.float64).copy()
    blind = angles[find] > cutoff
    spins = rng.uniform(0.0, 2 * np.pi, int(blind.sum()))
    R[blind] = R[blind] @ rodrigues(axis, spins)
    return HypothesisSet(R, np.asarray(gt.t[find], np.float64), np.where(blind, 0.5, 1.0))


def ceilings(scenes: dict[str, GroundTruthSet], obj, cutoffs: list[float], draws: int, max_occlusion: float,
             seed: int = 0) -> list[tuple[float, float, float, float]]:  # fmt: skip
    """Per cutoff: (cutoff, share of the parts to find within it, mean AP, sd AP over the draws)."""
    space = obj.pose_space
    axis = main_axis(space)
    finds = {k: instances_to_find(g, max_occlusion) for k, g in scenes.items()}
    angles = {k: axis_angle(g.R, g.t, axis) for k, g in scenes.items()}
    total = sum(int(f.sum()) for f in finds.values())
    rows = []
    for cutoff in cutoffs:
        seen = sum(int((angles[k][finds[k]] <= cutoff).sum()) for k in scenes)
        rng = np.random.default_rng(seed)
        aps = [evaluate_scenes({k: (g, ceiling_hypotheses(g, angles[k], cutoff, axis, finds[k], rng))
                                for k, g in scenes.items()}, space, max_occlusion).ap for _ in range(draws)]
        rows.append((cutoff, seen / max(total, 1), float(np.mean(aps)), float(np.std(aps))))
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--object", required=True, help="a conf/object name (its committed symmetry is scored)")
    ap.add_argument("--root", type=Path, required=True, help="a generated dataset")
    ap.add_argument("--min-objects", type=int, default=0)
    ap.add_argument("--cutoffs", type=float, nargs="+", default=[30, 40, 50, 60, 90])
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--max-occlusion", type=float, default=0.5)
    ap.add_argument("--out", type=Path, help="also write the table here (Markdown)")
    args = ap.parse_args(argv)
    obj = object_from_config(compose_train([f"object={args.object}"]).object)
    scenes = {}
    dataset = open_dataset(args.root)
    for i, (cycle, n) in enumerate(dataset.scenes()):
        gt = dataset.read_ground_truth(cycle, n)
        if len(gt) >= args.min_objects:
            scenes[dataset.scene_name(i)] = gt
    if not scenes:
        raise SystemExit(f"error: {args.root}: no scene with at least {args.min_objects} parts")
    lines = [f"{args.object} ({len(obj.pose_space.group)} symmetric equivalents), {args.root.as_posix()}: "
             f"{len(scenes)} scenes; {args.draws} draws of the random spins", "",
             "| spin seen up to (axis from the line of sight) | parts to find seen so | ceiling AP as decoded |",
             "|---|---|---|"]
    lines += [f"| {cutoff:g}° | {100 * share:.0f} % | {mean:.3f} ± {sd:.3f} |"
              for cutoff, share, mean, sd in ceilings(scenes, obj, args.cutoffs, args.draws, args.max_occlusion)]
    print("\n".join(lines))
    if args.out:
        write_table_page(args.out, "The AP a network reading only the spins the depth shows can reach", lines)


if __name__ == "__main__":
    main()
