"""Precision-recall curves and their scalar summaries, as the official Brégier tool computes them
(docs/method.md#matching-and-scores). Pure numpy functions on curves indexed by decreasing score threshold.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: slack for comparisons of averaged precisions/recalls (sums of a few thousand float64 terms)
CURVE_TOL = 1e-9


def average_precision(precision: np.ndarray, recall: np.ndarray) -> float:
    """Non-interpolated step integral ``sum_k p_k (r_k - r_{k-1})`` with ``r_{-1} = 0``.

    Args:
        precision, recall: (T,) float64, one point per threshold, by decreasing threshold.
    Returns:
        The area; where recall decreases the (negative) step is integrated as it is, so a
        non-monotone curve gives a number instead of the official tool's assertion error.
    """
    precision, recall = _pair(precision, recall)
    if len(recall) == 0:
        return 0.0
    return float(np.dot(precision, np.diff(recall, prepend=0.0)))


def recall_is_monotone(recall: np.ndarray, tol: float = CURVE_TOL) -> bool:
    """True when recall never decreases along the curve (by more than ``tol``)."""
    r = np.asarray(recall, dtype=np.float64)
    return bool(len(r) < 2 or np.diff(r).min() >= -tol)


def best_f1(precision: np.ndarray, recall: np.ndarray) -> float:
    """Largest ``2 p r / (p + r)`` over the curve points (0 where p + r = 0)."""
    precision, recall = _pair(precision, recall)
    denom = precision + recall
    f1 = np.divide(2 * precision * recall, denom, out=np.zeros_like(denom), where=denom > 0)
    return float(f1.max(initial=0.0))


def recall_at_precision(precision: np.ndarray, recall: np.ndarray, min_precision: float) -> float:
    """Recall where the curve last holds precision >= ``min_precision``, no interpolation.

    Every maximal run of consecutive points with precision >= ``min_precision`` ends either where
    the next point drops below it or at the end of the curve; the result is the largest recall at
    such a run end. This is the official ``get_recall_at_precision``, except that the official code
    overlooks a final run that follows an earlier drop below the threshold (it then only counts
    the crossings). 0 when no point qualifies.
    """
    precision, recall = _pair(precision, recall)
    ok = precision >= min_precision - CURVE_TOL
    run_end = ok & ~np.append(ok[1:], False)
    return float(recall[run_end].max(initial=0.0))


def mean_curve(
    thresholds: Sequence[np.ndarray], precisions: Sequence[np.ndarray], recalls: Sequence[np.ndarray]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Macro-average per-scene curves over the union of their thresholds.

    At every threshold s of the union (descending), each scene contributes its point at its last
    threshold >= s; the mean is taken over scenes. Every scene curve must start at +inf. Computed
    without a loop over thresholds: each scene's curve is a step function whose jumps are added at
    their positions in the union, then summed cumulatively.

    Args:
        thresholds, precisions, recalls: per scene, (T_s,) float64 by decreasing threshold.
    Returns:
        (thresholds (U,), precision (U,), recall (U,)) float64, thresholds descending from +inf.
    """
    n = len(thresholds)
    if n == 0 or not (len(precisions) == len(recalls) == n):
        counts = f"{n}, {len(precisions)}, {len(recalls)}"
        raise ValueError(f"mean_curve needs the same positive number of curves, got {counts}")
    for t in thresholds:
        if len(t) == 0 or t[0] != np.inf:
            raise ValueError("every scene curve must start at threshold +inf")
    all_t = np.concatenate(thresholds)
    jump_p = np.concatenate([np.diff(np.asarray(p, np.float64), prepend=0.0) for p in precisions])
    jump_r = np.concatenate([np.diff(np.asarray(r, np.float64), prepend=0.0) for r in recalls])
    neg_sorted, position = np.unique(-all_t, return_inverse=True)  # ascending -t = descending t
    size = len(neg_sorted)
    mean_p = np.cumsum(np.bincount(position, weights=jump_p, minlength=size)) / n
    mean_r = np.cumsum(np.bincount(position, weights=jump_r, minlength=size)) / n
    return -neg_sorted, mean_p, mean_r


def _pair(precision: np.ndarray, recall: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(precision, dtype=np.float64).reshape(-1)
    r = np.asarray(recall, dtype=np.float64).reshape(-1)
    if p.shape != r.shape:
        raise ValueError(f"precision and recall differ in length: {len(p)} vs {len(r)}")
    return p, r
