"""How wrong is the spin the network is surest of, for a part seen end-on, oblique or side-on?

The error breakdown (:mod:`opnet.metrics.breakdown`) takes each part's *pose-nearest* hypothesis: among many,
one may hit the spin by chance. What a robot gets is the *best-scored* hypothesis at the part. For every part
to find in a split this script takes, among the decoded hypotheses whose origin lies within 0.15 D of the
part's, the one of highest score, and splits its rotation error along the part's main axis (tilt of the axis,
spin about it, on the nearest symmetric equivalent), counted by how the camera sees the axis
(:data:`opnet.metrics.breakdown.VIEWS`). A spin the depth shows lands near 0; a spin it does not show spreads
evenly up to half the turn between symmetric equivalents (36° for a cyclic 5 part).

    python scripts/experiments/flat_parts/spin_by_view.py \\
        outputs/new_parts/itodd08_recipe60/checkpoints/epoch011-ap0.2750.ckpt{,@train@80}

Each checkpoint runs on every STRIDE-th scene of SPLIT (default: the validation split, every 8th, as the
recipes' tuning), decoding as it records; the training split shows what the network learnt of the scenes it
saw. Prints a table per run (``--out``: also writes them, with the command, as a Markdown page).
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402
from lightning.pytorch import seed_everything  # noqa: E402

from opnet.cli.decoding_search import RecordedSplit, current_settings  # noqa: E402
from opnet.metrics.bregier import instances_to_find  # noqa: E402
from opnet.metrics.breakdown import VIEWS, main_axis, tilt_and_spin, view_of_axis  # noqa: E402
from opnet.studies import write_table_page  # noqa: E402

#: a hypothesis belongs to a part when its origin lies within this share of D of the part's
NEAR_D = 0.15
#: the spin error's bins, degrees (the last is open)
SPIN_EDGES = (0, 6, 12, 18, 24, 30, 36)


def best_scored_errors(recorded: RecordedSplit) -> dict[str, dict[str, np.ndarray | int]]:
    """View name -> {"tilt", "spin": degrees of each part's best-scored hypothesis, "none": parts without one}."""
    param = recorded.parameterization
    space, diameter = param.obj.pose_space, float(param.obj.diameter)
    axis = main_axis(space)
    R_hat: dict[int, list[np.ndarray]] = {v: [] for v in range(len(VIEWS))}
    R_true: dict[int, list[np.ndarray]] = {v: [] for v in range(len(VIEWS))}
    none = np.zeros(len(VIEWS), dtype=np.int64)
    for gt, hyps in recorded.scenes(current_settings(param)).values():
        find = np.where(instances_to_find(gt, recorded.max_occlusion))[0]
        views = view_of_axis(gt.R, gt.t, axis)
        for j in find:
            near = (np.where(np.linalg.norm(np.asarray(hyps.t) - gt.t[j], axis=-1) < NEAR_D * diameter)[0]
                    if len(hyps) else np.zeros(0, dtype=np.int64))  # fmt: skip
            if not len(near):
                none[views[j]] += 1
                continue
            best = near[np.argmax(np.asarray(hyps.score)[near])]
            R_hat[views[j]].append(np.asarray(hyps.R[best], np.float64))
            R_true[views[j]].append(np.asarray(gt.R[j], np.float64))
    out = {}
    for v, name in enumerate(VIEWS):
        if R_hat[v]:
            tilt, spin, _, _ = tilt_and_spin(space, axis, np.stack(R_hat[v]), np.stack(R_true[v]))
        else:
            tilt = spin = np.zeros(0)
        out[name] = {"tilt": tilt, "spin": spin, "none": int(none[v])}
    return out


def table(errors: dict[str, dict[str, np.ndarray | int]]) -> str:
    """The spin histogram (shares of the parts with a hypothesis) and the tilt's median per view, as Markdown."""
    bins = [f"{a}-{b}°" for a, b in zip(SPIN_EDGES[:-1], SPIN_EDGES[1:], strict=False)] + [f"≥{SPIN_EDGES[-1]}°"]
    head = " | ".join(f"spin {b}" for b in bins)
    lines = [f"| seen | parts | no hypothesis | {head} | tilt p50 ° | tilt > 90° |",
             "|---" * (len(bins) + 5) + "|"]
    for name, e in errors.items():
        spin, tilt = e["spin"], e["tilt"]
        n = len(spin)
        hist = np.histogram(spin, bins=[*SPIN_EDGES, 360])[0] / max(n, 1)
        lines.append(f"| {name.replace('_', '-')} | {n + e['none']} | {e['none']} | "
                     + " | ".join(f"{100 * h:.0f} %" for h in hist)
                     + f" | {np.median(tilt) if n else float('nan'):.1f}"
                     + f" | {100 * np.mean(tilt > 90) if n else 0:.0f} % |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", metavar="CKPT[@SPLIT[@STRIDE]]",
                    help="a checkpoint, scored on SPLIT (train, val or test; default val), every STRIDE-th scene "
                         "(default 8); several: a table each")  # fmt: skip
    ap.add_argument("--out", type=Path, help="also write the tables here (Markdown)")
    args = ap.parse_args(argv)
    lines: list[str] = []
    for run in args.runs:
        ckpt, split, stride = (run.split("@") + ["val", "8"][len(run.split("@")) - 1 :])[:3]
        if split not in ("train", "val", "test") or not stride.isdigit() or int(stride) < 1:
            raise SystemExit(f"error: {run}: expected CKPT[@SPLIT[@STRIDE]], SPLIT train, val or test, STRIDE >= 1")
        seed_everything(0, verbose=False)  # the training split's shuffle and augmentation: the same scenes each run
        recorded = RecordedSplit.record(ckpt, split, stride=int(stride))
        lines += [f"`{ckpt}`, {split} (every {stride}th scene), decoded as recorded: "
                  f"{current_settings(recorded.parameterization)}", "", table(best_scored_errors(recorded)), ""]
        print("\n".join(lines[-4:]), flush=True)
    if args.out:
        write_table_page(args.out, "The spin of each part's best-scored pose, by how the camera sees the part", lines)


if __name__ == "__main__":
    main()
