"""Spin-hedge probe: what the metric gives for spins reported, not read

A spin the depth does not show can only be guessed. The metric counts a pose right when it lies within δ of a
symmetric equivalent of the truth, so a decoding that reports, beside each pose whose axis the camera sees side-on,
copies of it turned about that axis (evenly over the turn between symmetric equivalents, scored lower) finds more
parts without reading anything more of the image. This probe measures how much: it needs no training and no image.

    python scripts/experiments/flat_parts/spin_hedge.py CKPT [--side-on 0 45] [--copies 2 3] [--factor 0.05 0.2 0.5]

Records the checkpoint's outputs on its validation and held-out (test) splits once, decodes them as the checkpoint
records, then adds to every hypothesis whose main axis lies more than ``side-on`` degrees from its line of sight
``copies - 1`` copies turned by k / copies of the turn between symmetric equivalents (k = 1 .. copies - 1), each
scored ``factor`` times the hypothesis' own score: every such hypothesis (copied: all), or only those scored highest
within 0.25 D of their translation (copied: best). Prints the AP of every setting on both splits (choose on ``val``)
and the share of the parts to find that a true positive finds. Then, for the parts found as decoded (no copies), by
how the camera sees their axis: how often their true positive is the best-scored hypothesis within 0.25 D of the
part, how often another pose there scores higher, and how often it stands alone.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from opnet.evaluation import AveragePrecision
from opnet.metrics.breakdown import VIEWS, axis_angle, main_axis, view_of_axis
from opnet.metrics.diagnostics import scene_outcomes
from opnet.metrics.records import HypothesisSet
from opnet.studies.results import ProbePage


def best_at_place(hyps: HypothesisSet, radius: float) -> np.ndarray:
    """(N,) bool: no hypothesis of higher score lies within ``radius`` (m) of the hypothesis' translation."""
    s = np.asarray(hyps.score, dtype=np.float64)
    best = np.ones(len(s), dtype=bool)
    for i, j in cKDTree(hyps.t).query_pairs(radius, output_type="ndarray"):
        if s[i] < s[j]:
            best[i] = False
        elif s[j] < s[i]:
            best[j] = False
    return best


def hedged(hyps: HypothesisSet, axis: np.ndarray, period_deg: float, side_on: float, copies: int, factor: float,
           only: np.ndarray | None = None) -> HypothesisSet:
    """The hypotheses plus, for each one seen with its axis over ``side_on`` degrees from its line of sight (and
    ``only`` where given), ``copies - 1`` copies turned about the part's own ``axis`` by k / copies of
    ``period_deg``, scored ``factor`` times its own score."""
    if copies < 2 or not len(hyps):
        return hyps
    pick = axis_angle(hyps.R, hyps.t, axis) > side_on
    if only is not None:
        pick &= only
    if not pick.any():
        return hyps
    R, t, s = hyps.R[pick], hyps.t[pick], np.asarray(hyps.score)[pick]
    turns = [Rotation.from_rotvec(np.radians(period_deg * k / copies) * axis).as_matrix() for k in range(1, copies)]
    vis = None if hyps.visibility is None else np.concatenate(
        [hyps.visibility] + [np.asarray(hyps.visibility)[pick]] * len(turns))
    return HypothesisSet(np.concatenate([hyps.R] + [R @ q for q in turns]),
                         np.concatenate([hyps.t] + [t] * len(turns)),
                         np.concatenate([np.asarray(hyps.score)] + [s * factor] * len(turns)), vis)


def found_share(scenes: dict, space, diameter: float, max_occlusion: float) -> float:
    """Share of the parts to find that a true positive (the metric's matching) finds."""
    found = total = 0
    for o in scene_outcomes(scenes, space, diameter, max_occlusion):
        found += int(((o.outcome == "matched") & o.find).sum())
        total += int(o.find.sum())
    return found / max(total, 1)


def true_positive_rank(scenes: dict, space, diameter: float, max_occlusion: float) -> dict[str, list[int]]:
    """Per view of the part's axis (:data:`VIEWS`), the found parts counted as [alone at their place, their true
    positive the best-scored there, another pose there scored higher]; a place: within 0.25 D of the part."""
    counts = {v: [0, 0, 0] for v in VIEWS}
    axis = main_axis(space)
    for (gt, _), o in zip(scenes.values(), scene_outcomes(scenes, space, diameter, max_occlusion), strict=True):
        h = o.hypotheses
        if not len(h):
            continue
        view = view_of_axis(gt.R, gt.t, axis)
        for k in np.flatnonzero((o.outcome == "matched") & o.find):
            near = np.flatnonzero(np.linalg.norm(h.t - gt.t[k], axis=-1) <= 0.25 * diameter)
            kind = 0 if len(near) < 2 else (1 if near[np.argmax(h.score[near])] == o.nearest[k] else 2)
            counts[VIEWS[view[k]]][kind] += 1
    return counts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--side-on", type=float, nargs="+", default=[0.0, 45.0])
    ap.add_argument("--copies", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--factor", type=float, nargs="+", default=[0.05, 0.2, 0.5])
    args, page, recorded, settings, decoded, obj = ProbePage.checkpoint_probe(ap, __doc__, __file__, argv)
    emit = page.emit
    space, diameter = obj.pose_space, obj.diameter
    if space.revolution or len(space.group) < 2:
        raise SystemExit(f"error: {args.ckpt}: the part has no finite turn between symmetric equivalents to hedge")
    period = 360.0 / len(space.group)
    axis = main_axis(space)
    emit(f"{args.ckpt}: decoding {settings}; D {diameter * 1000:.1f} mm, turn between symmetric equivalents "
         f"{period:g}°")
    emit()
    emit("| copied | side-on over (°) | copies | factor | "
         + " | ".join(f"AP {s} | found {s}" for s in args.splits) + " |")
    emit("|---|---|---|---|" + "---|---|" * len(args.splits))
    grid = [("none", 0.0, 1, 1.0)] + [(m, a, c, f) for m in ("all", "best") for a in args.side_on
                                      for c in args.copies for f in args.factor]
    for copied, side_on, copies, factor in grid:
        cells = []
        for split, scenes in decoded.items():
            out = {}
            for k, (g, h) in scenes.items():
                only = best_at_place(h, 0.25 * diameter) if copied == "best" and len(h) else None
                out[k] = (g, hedged(h, axis, period, side_on, copies, factor, only))
            occ = recorded[split].max_occlusion
            cells.append(f"{AveragePrecision(space, occ).evaluate(out).ap:.3f} | "
                         f"{found_share(out, space, diameter, occ):.0%}")
        emit(f"| {copied} | {side_on:g} | {copies} | {factor:g} | " + " | ".join(cells) + " |")
    for split, scenes in decoded.items():
        emit(f"\n{split}: the parts found as decoded, by how the camera sees their axis; their true positive alone "
             "within 0.25 D of the part, the best-scored pose there, or outscored there by another pose\n")
        emit("| seen | found | alone | best-scored | outscored |\n|---|---|---|---|---|")
        for view, c in true_positive_rank(scenes, space, diameter, recorded[split].max_occlusion).items():
            n = max(sum(c), 1)
            emit(f"| {view.replace('_', '-')} | {sum(c)} | {c[0] / n:.0%} | {c[1] / n:.0%} | {c[2] / n:.0%} |")
    page.write(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
