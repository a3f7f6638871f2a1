"""The Brégier et al. evaluation protocol (docs/method.md#matching-and-scores): per-scene
precision-recall curves with mutual-nearest-neighbour matching recomputed at every score threshold.

Matching at a threshold s, with P = the hypotheses of score >= s and distances over *all* ground
truth instances: a hypothesis is a true positive when its nearest instance j is within δ, is to be
found (min_occlusion <= occlusion_j <= max_occlusion) and has this hypothesis as its nearest among
P; a false positive when it is farther than δ from every instance or is not the nearest of its
instance (a duplicate); and ignored when it matches an instance that need not be found.

Unlike the official tool, which re-runs the matching at each threshold, the whole curve comes from
one pass: hypotheses sorted by score, a cumulative argmin over them gives, for every prefix and
every instance, its nearest hypothesis; equal scores enter together (a threshold admits every
hypothesis of score >= it).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from opnet.geometry.distance import PoseSpace
from opnet.metrics.curves import average_precision, best_f1, mean_curve, recall_at_precision
from opnet.metrics.records import GroundTruthSet, HypothesisSet
from opnet.metrics.report import EvaluationSummary, warn_non_monotone


@dataclass(frozen=True)
class SceneCurve:
    """Precision-recall curve of one scene, one point per score threshold.

    Attributes:
        thresholds: (T,) float64, ``+inf`` then the distinct hypothesis scores, descending.
        precision, recall: (T,) float64 in [0, 1].
        tp, fp: (T,) int64 true / false positives at each threshold.
        num_gt: ground truth instances in the scene (all of them take part in the matching).
        num_to_find: instances with min_occlusion <= occlusion <= max_occlusion.
        num_hypotheses: hypotheses in the scene (after max_nb_results).
    """

    thresholds: np.ndarray
    precision: np.ndarray
    recall: np.ndarray
    tp: np.ndarray
    fp: np.ndarray
    num_gt: int
    num_to_find: int
    num_hypotheses: int

    @property
    def ap(self) -> float:
        """Non-interpolated average precision of this scene's curve."""
        return average_precision(self.precision, self.recall)


def scene_curve_from_distances(
    distances: np.ndarray, score: np.ndarray, to_find: np.ndarray, delta: float, max_nb_results: int = -1
) -> SceneCurve:
    """The matching of docs/method.md#matching-and-scores at every threshold at once, from a
    precomputed distance matrix.

    Args:
        distances: (M, N) float64 metres, pose distance of hypothesis i to ground truth j (all N).
        score: (M,) float64 finite hypothesis scores, higher = more confident.
        to_find: (N,) bool, the instances that must be found.
        delta: metres, the largest distance of a correct pose.
        max_nb_results: k > 0 keeps only the k best-scored hypotheses at every threshold (ties in
            input order) and recall becomes TP / min(k, TP + FN); -1 (or any k < 0) = unlimited.
    Returns:
        The scene's curve.
    """
    D = np.asarray(distances, dtype=np.float64)
    score = np.asarray(score, dtype=np.float64).reshape(-1)
    to_find = np.asarray(to_find, dtype=bool).reshape(-1)
    M, N = len(score), len(to_find)
    if D.shape != (M, N):
        raise ValueError(f"distances must have shape ({M}, {N}) (hypotheses, instances), got {D.shape}")
    if not (np.isfinite(D).all() and np.isfinite(score).all()):
        raise ValueError("distances and scores must be finite (no NaN or inf)")
    if max_nb_results == 0:
        raise ValueError("max_nb_results must be positive, or negative for no limit; got 0")
    order = np.argsort(-score, kind="stable")
    s_sorted = score[order]
    last_of_group = np.append(s_sorted[1:] != s_sorted[:-1], True) if M else np.zeros(0, bool)
    thresholds = np.concatenate(([np.inf], s_sorted[last_of_group]))
    n_in = np.concatenate(([0], np.flatnonzero(last_of_group) + 1))  # |P| at each threshold
    if max_nb_results > 0:
        n_in = np.minimum(n_in, max_nb_results)
    tp, ignored = _true_positives(D[order], n_in, to_find, delta)
    fp = n_in - tp - ignored
    n_find = int(to_find.sum())
    wanted = min(n_find, max_nb_results) if max_nb_results > 0 else n_find
    precision = np.divide(tp, tp + fp, out=np.ones(len(tp)), where=(tp + fp) > 0)
    recall = tp / wanted if wanted > 0 else np.ones(len(tp))
    n_hyps = min(M, max_nb_results) if max_nb_results > 0 else M
    return SceneCurve(thresholds, precision, recall, tp, fp, N, n_find, n_hyps)


def _true_positives(
    D_sorted: np.ndarray, n_in: np.ndarray, to_find: np.ndarray, delta: float
) -> tuple[np.ndarray, np.ndarray]:
    """(TP, ignored) (T,) int64 for each prefix length ``n_in`` (T,) of the score-sorted
    hypotheses, from their distances D_sorted (M, N) to the instances."""
    M, N = D_sorted.shape
    tp = np.zeros(len(n_in), dtype=np.int64)
    ignored = np.zeros(len(n_in), dtype=np.int64)
    if M == 0 or N == 0:
        return tp, ignored
    nearest_gt = D_sorted.argmin(axis=1)  # (M,) fixed: the instance each hypothesis claims
    running_min = np.minimum.accumulate(D_sorted, axis=0)  # (M, N) over prefixes
    improved = np.ones((M, N), dtype=bool)
    # strict <: on ties the earlier (better-scored) hypothesis stays the nearest
    improved[1:] = D_sorted[1:] < running_min[:-1]
    # (M, N): index of the nearest hypothesis of each instance among the first m + 1
    nearest_hyp = np.maximum.accumulate(np.where(improved, np.arange(M)[:, None], 0), axis=0)
    rows = n_in[n_in > 0] - 1
    hyp = nearest_hyp[rows]  # (T', N) nearest hypothesis of every instance within each prefix
    # instance j is matched when its nearest hypothesis also has j as nearest instance, within delta
    matched = (nearest_gt[hyp] == np.arange(N)) & (running_min[rows] <= delta)
    tp[n_in > 0] = (matched & to_find).sum(axis=1)
    ignored[n_in > 0] = (matched & ~to_find).sum(axis=1)
    return tp, ignored


def instances_to_find(
    gt: GroundTruthSet, max_occlusion: float = 0.5, min_occlusion: float = -0.1
) -> np.ndarray:
    """(N,) bool: ``min_occlusion <= occlusion_rate <= max_occlusion`` (inclusive,
    docs/method.md#matching-and-scores)."""
    occ = gt.occlusion_rate
    return (occ >= min_occlusion) & (occ <= max_occlusion)


def pose_distances(hyps: HypothesisSet, gt: GroundTruthSet, space: PoseSpace) -> np.ndarray:
    """(M, N) float64 metres: Brégier distance of each hypothesis to each ground-truth instance."""
    if len(hyps) == 0 or len(gt) == 0:
        return np.zeros((len(hyps), len(gt)))
    tensors = (torch.from_numpy(np.ascontiguousarray(a)) for a in (hyps.R, hyps.t, gt.R, gt.t))
    return space.distance_matrix(*tensors).numpy()


def pose_distances_per_scene(
    pairs: Sequence[tuple[HypothesisSet, GroundTruthSet]], space: PoseSpace, budget: int = 1 << 22
) -> list[np.ndarray]:
    """:func:`pose_distances` of many scenes at once: [(M_s, N_s) float64 metres].

    Scenes are padded to a common size and their distances computed in batched tensor calls of at
    most ``budget`` entries (scenes sorted by size to limit the padding): one small call per scene
    costs far more in per-call overhead (and thread start-up on a busy machine) than the
    arithmetic. Same definition as :meth:`PoseSpace.distance_matrix`: the first representative of
    each hypothesis against every representative of each instance, minimised over the latter.
    """
    out = [np.zeros((len(h), len(g))) for h, g in pairs]
    K = space.num_representatives
    sizes = [(len(h), len(g)) for h, g in pairs]
    todo = sorted((i for i, (m, n) in enumerate(sizes) if m and n), key=lambda i: sizes[i])
    chunk: list[int] = []
    max_m = max_n = 0
    for i in [*todo, -1]:
        m, n = sizes[i] if i >= 0 else (0, 0)
        if chunk and (i < 0 or (len(chunk) + 1) * max(max_m, m) * max(max_n, n) * K > budget):
            blocks = _padded_distances([pairs[k] for k in chunk], space)
            for k, D in zip(chunk, blocks, strict=True):
                out[k] = D
            chunk, max_m, max_n = [], 0, 0
        chunk.append(i)
        max_m, max_n = max(max_m, m), max(max_n, n)
    return out


def _padded_distances(
    pairs: Sequence[tuple[HypothesisSet, GroundTruthSet]], space: PoseSpace
) -> list[np.ndarray]:
    S, M, N = len(pairs), max(len(h) for h, _ in pairs), max(len(g) for _, g in pairs)
    hyp_R, gt_R = np.zeros((S, M, 3, 3)), np.zeros((S, N, 3, 3))
    hyp_t, gt_t = np.zeros((S, M, 3)), np.zeros((S, N, 3))
    for s, (h, g) in enumerate(pairs):
        hyp_R[s, : len(h)], hyp_t[s, : len(h)] = h.R, h.t
        gt_R[s, : len(g)], gt_t[s, : len(g)] = g.R, g.t
    rep_h = space.representatives(torch.from_numpy(hyp_R), torch.from_numpy(hyp_t))[:, :, 0]  # (S, M, D)
    rep_g = space.representatives(torch.from_numpy(gt_R), torch.from_numpy(gt_t))  # (S, N, K, D)
    K, dim = rep_g.shape[-2:]
    D = torch.cdist(rep_h, rep_g.reshape(S, N * K, dim)).reshape(S, M, N, K).amin(dim=-1).numpy()
    return [D[s, : len(h), : len(g)].copy() for s, (h, g) in enumerate(pairs)]


def evaluate_scene(
    gt: GroundTruthSet,
    hyps: HypothesisSet,
    space: PoseSpace,
    max_occlusion: float = 0.5,
    min_occlusion: float = -0.1,
    max_nb_results: int = -1,
) -> SceneCurve:
    """Precision-recall curve of one scene (docs/method.md#matching-and-scores).

    Args:
        gt: the scene's ground truth; poses in the same frame as ``hyps``, metres.
        hyps: the scene's pose hypotheses with finite scores.
        space: the object's pose space (distance and threshold δ = ``space.delta``).
        max_occlusion, min_occlusion: instances to find have an occlusion rate in this range.
        max_nb_results: keep only the k best hypotheses at each threshold (-1: all).
    """
    _check_finite(gt, hyps)
    D = pose_distances(hyps, gt, space)
    to_find = instances_to_find(gt, max_occlusion, min_occlusion)
    return scene_curve_from_distances(D, hyps.score, to_find, space.delta, max_nb_results)


def evaluate_scenes(
    scenes: Mapping[str, tuple[GroundTruthSet, HypothesisSet]],
    space: PoseSpace,
    max_occlusion: float = 0.5,
    min_occlusion: float = -0.1,
    max_nb_results: int = -1,
) -> EvaluationSummary:
    """Evaluate a set of scenes of one object: per-scene curves, their mean curve and its metrics.

    Args:
        scenes: scene name -> (ground truth, hypotheses). Scores must be comparable across scenes
            (the mean curve uses global thresholds).
        space, max_occlusion, min_occlusion, max_nb_results: as in :func:`evaluate_scene`.
    Returns:
        AP of the mean curve (the headline "AP"), MAP (mean of per-scene APs), best F1 and recall
        at precision 0.5 / 0.99 of the mean curve, the mean curve, per-scene APs and counts.
        Warns (:class:`NonMonotoneRecallWarning`) when a recall decreases along a curve.
        Distances are computed for all scenes together (:func:`pose_distances_per_scene`).
    """
    if not scenes:
        raise ValueError("no scenes to evaluate")
    for gt, h in scenes.values():
        _check_finite(gt, h)
    distances = pose_distances_per_scene([(h, gt) for gt, h in scenes.values()], space)
    curves = {
        name: scene_curve_from_distances(
            D, h.score, instances_to_find(gt, max_occlusion, min_occlusion), space.delta, max_nb_results
        )
        for (name, (gt, h)), D in zip(scenes.items(), distances, strict=True)
    }
    return summarize(curves, max_occlusion=max_occlusion, delta=space.delta)


def summarize(
    curves: Mapping[str, SceneCurve], max_occlusion: float = 0.5, delta: float = float("nan")
) -> EvaluationSummary:
    """Combine per-scene curves into the summary of :func:`evaluate_scenes`."""
    values = list(curves.values())
    thresholds, precision, recall = mean_curve(
        [c.thresholds for c in values], [c.precision for c in values], [c.recall for c in values]
    )
    warn_non_monotone({name: c.recall for name, c in curves.items()}, recall)
    per_scene = {name: c.ap for name, c in curves.items()}
    return EvaluationSummary(
        ap=average_precision(precision, recall),
        map=float(np.mean(list(per_scene.values()))),
        f1=best_f1(precision, recall),
        recall_at_p50=recall_at_precision(precision, recall, 0.5),
        recall_at_p99=recall_at_precision(precision, recall, 0.99),
        per_scene=per_scene,
        precision=precision,
        recall=recall,
        thresholds=thresholds,
        scene_counts={name: _counts(c) for name, c in curves.items()},
        max_occlusion=max_occlusion,
        delta=delta,
    )


def _counts(c: SceneCurve) -> dict[str, Any]:
    return {
        "gt": c.num_gt,
        "to_find": c.num_to_find,
        "hypotheses": c.num_hypotheses,
        "tp": int(c.tp[-1]),
        "fp": int(c.fp[-1]),
        "ignored": int(c.num_hypotheses - c.tp[-1] - c.fp[-1]),
    }


def _check_finite(gt: GroundTruthSet, hyps: HypothesisSet) -> None:
    fields = (
        ("hypotheses", "score", hyps.score),
        ("hypotheses", "R", hyps.R),
        ("hypotheses", "t", hyps.t),
        ("ground truth", "occlusion_rate", gt.occlusion_rate),
        ("ground truth", "R", gt.R),
        ("ground truth", "t", gt.t),
    )
    for side, key, a in fields:
        if not np.isfinite(a).all():
            raise ValueError(f"{side}: {key!r} contains NaN or inf")


__all__ = [
    "SceneCurve",
    "evaluate_scene",
    "evaluate_scenes",
    "instances_to_find",
    "pose_distances",
    "pose_distances_per_scene",
    "scene_curve_from_distances",
    "summarize",
]
