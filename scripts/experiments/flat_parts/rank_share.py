"""Ranking probe: hypotheses scored by their share of their place's scores, or by how the camera sees their axis

A part whose spin the depth does not show draws cells that disagree on it: the averaging leaves several clusters at
one place, each with part of the votes, and the metric counts all but one as false positives. A part whose spin
shows draws one cluster holding all the votes there. Scoring each hypothesis s * (s / S)^alpha, S the sum of the
scores of the hypotheses whose translation lies within rho * D of its own (itself counted), ranks the parts the
network agrees on first; it needs no training and no image. Scoring it s * cos(a)^beta, a the angle of its main
axis to its line of sight, ranks the parts seen end-on (whose spin shows) before those seen side-on.

    python scripts/experiments/flat_parts/rank_share.py CKPT [--rho 0.1 0.2 0.3] [--alpha 0.5 1 2] [--beta 0.5 1 2]

Records the checkpoint's outputs on its validation and held-out (test) splits once, decodes them as the checkpoint
records, and prints the AP of every setting on both splits (choose on ``val``), then where the false positives of
the decoding as recorded lie: at a part another hypothesis finds (a duplicate), at a part none finds (a wrong pose
of a missed part), at a part that need not be found (more than half hidden), or at no part.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
from scipy.spatial import cKDTree

from opnet.evaluation import AveragePrecision
from opnet.metrics.breakdown import axis_angle, main_axis
from opnet.metrics.diagnostics import scene_outcomes
from opnet.metrics.records import HypothesisSet
from opnet.studies.results import ProbePage


def share_scores(hyps: HypothesisSet, radius: float, alpha: float) -> HypothesisSet:
    """The hypotheses with scores s * (s / S)^alpha, S the summed score within ``radius`` (m) of each translation."""
    if len(hyps) < 2 or alpha == 0:
        return hyps
    s = np.asarray(hyps.score, dtype=np.float64)
    pairs = cKDTree(hyps.t).query_pairs(radius, output_type="ndarray")
    near = s.copy()
    np.add.at(near, pairs[:, 0], s[pairs[:, 1]])
    np.add.at(near, pairs[:, 1], s[pairs[:, 0]])
    share = s / np.maximum(near, 1e-300)
    return HypothesisSet(hyps.R, hyps.t, s * share**alpha, hyps.visibility)


def view_scores(hyps: HypothesisSet, axis: np.ndarray, beta: float) -> HypothesisSet:
    """The hypotheses with scores s * cos(a)^beta, a the angle of the hypothesis' main axis to its line of sight."""
    if not len(hyps) or beta == 0:
        return hyps
    cos = np.cos(np.radians(axis_angle(hyps.R, hyps.t, axis))).clip(0.05, 1.0)
    return HypothesisSet(hyps.R, hyps.t, np.asarray(hyps.score) * cos**beta, hyps.visibility)


#: a hypothesis whose translation lies within this fraction of D of a part's is at that part
AT_PART = 0.25


def false_positive_places(scenes: dict, space, diameter: float, max_occlusion: float) -> dict[str, list[int]]:
    """Each split's hypotheses counted by kind (all of them, and those scored at least the median true positive):
    true positive, ignored, duplicate, missed part, hidden part, no part; the matching is the metric's at the
    lowest threshold (:func:`opnet.metrics.diagnostics.scene_outcomes`)."""
    kinds = ("true positive", "ignored", "duplicate of a found part", "wrong pose of a missed part",
             "at a hidden part", "at no part")
    counts = {k: [0, 0] for k in kinds}
    labelled = []
    for (gt, _), o in zip(scenes.values(), scene_outcomes(scenes, space, diameter, max_occlusion), strict=True):
        h, matched = o.hypotheses, o.outcome == "matched"
        if not len(h) or not len(matched):
            continue
        kind_of = np.full(len(h), "", dtype=object)
        kind_of[o.nearest[matched & o.find]] = kinds[0]
        kind_of[o.nearest[matched & ~o.find]] = kinds[1]
        dt = np.linalg.norm(h.t[:, None] - gt.t[None], axis=-1)
        place = dt.argmin(1)
        at = dt.min(1) <= AT_PART * diameter
        found = matched & o.find
        for i in np.flatnonzero(kind_of == ""):
            if not at[i]:
                kind_of[i] = kinds[5]
            elif not o.find[place[i]]:
                kind_of[i] = kinds[4]
            else:
                kind_of[i] = kinds[2] if found[place[i]] else kinds[3]
        labelled += list(zip(kind_of, h.score.astype(float), strict=True))
    tp_scores = [s for k, s in labelled if k == kinds[0]]
    confident = float(np.median(tp_scores)) if tp_scores else np.inf
    for kind, score in labelled:
        counts[kind][0] += 1
        counts[kind][1] += score >= confident
    return counts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rho", type=float, nargs="+", default=[0.1, 0.2, 0.3, 0.5])
    ap.add_argument("--alpha", type=float, nargs="+", default=[0.5, 1.0, 2.0])
    ap.add_argument("--beta", type=float, nargs="+", default=[0.5, 1.0, 2.0])
    args, page, recorded, settings, decoded, obj = ProbePage.checkpoint_probe(ap, __doc__, __file__, argv)
    emit = page.emit
    space, diameter = obj.pose_space, obj.diameter
    emit(f"{args.ckpt}: decoding {settings}; D {diameter * 1000:.1f} mm. AP as decoded, the scores of the hypotheses "
         "multiplied by (s / S)^alpha, S the summed score within rho D (rho 0: none), and by cos(a)^beta, a the angle "
         "of the hypothesis' main axis to its line of sight; val: the run's validation split, test: its held-out piles")
    emit()
    axis = main_axis(space)
    emit("| rho (D) | alpha | beta | " + " | ".join(f"AP {s}" for s in args.splits) + " |")
    emit("|---|---|---|" + "---|" * len(args.splits))
    shares = [(0.0, 0.0)] + [(r, a) for r in args.rho for a in args.alpha]
    for rho, alpha in shares:
        for beta in [0.0, *args.beta]:
            aps = []
            for split, scenes in decoded.items():
                rescored = {k: (g, view_scores(share_scores(h, rho * diameter, alpha), axis, beta))
                            for k, (g, h) in scenes.items()}
                aps.append(AveragePrecision(space, recorded[split].max_occlusion).evaluate(rescored).ap)
            emit(f"| {rho:g} | {alpha:g} | {beta:g} | " + " | ".join(f"{a:.3f}" for a in aps) + " |")
    for split, scenes in decoded.items():
        counts = false_positive_places(scenes, space, diameter, recorded[split].max_occlusion)
        total = [sum(c[j] for c in counts.values()) for j in range(2)]
        emit(f"\n{split}: the hypotheses as decoded, by where they lie ({len(scenes)} scenes; a part's place: "
             f"within {AT_PART:g} D of it; confident: scored at least the median true positive)\n")
        emit("| hypothesis | all | per scene | confident | per scene |\n|---|---|---|---|---|")
        for kind, (n_all, n_conf) in counts.items():
            emit(f"| {kind} | {n_all / max(total[0], 1):.1%} | {n_all / len(scenes):.1f} | "
                 f"{n_conf / max(total[1], 1):.1%} | {n_conf / len(scenes):.1f} |")
    page.write(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
