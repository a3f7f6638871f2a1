"""Pose averaging for parameterizations with several predictions per object (docs/method.md#decoding).

DBSCAN in pose space with the symmetry-aware Brégier distance (the metric's formula in numpy,
:mod:`opnet.geometry.pose_numpy`: this module runs without PyTorch, for :mod:`opnet.deploy`), then one averaged pose per cluster: every
member is first aligned to the best-scored member through the symmetry group, translation =
score-weighted mean, rotation = score-weighted chordal mean (projected onto SO(3) by SVD; for
revolution objects the score-weighted mean axis), cluster score = max member score by default.
Everything after the clustering is vectorized over clusters.
"""

from __future__ import annotations

from dataclasses import dataclass

from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial import cKDTree

from opnet.geometry.pose_numpy import axis_rotation, closest_equivalent, pose_distance, project_to_so3
from opnet.metrics.records import HypothesisSet
from opnet.settings_schema import TRAINING, check_settings

if TYPE_CHECKING:
    from opnet.geometry.distance import PoseSpace

def dbscan_labels(distance: np.ndarray, eps: float, min_samples: int = 1) -> np.ndarray:
    """DBSCAN on a precomputed (N, N) distance matrix, labelled exactly as scikit-learn does.

    See :func:`dbscan_graph`; neighbours are the pairs with ``distance <= eps``.
    """
    i, j = np.nonzero(np.asarray(distance) <= eps)
    off_diagonal = i != j
    return dbscan_graph(len(distance), i[off_diagonal], j[off_diagonal], min_samples)


def dbscan_graph(n: int, i: np.ndarray, j: np.ndarray, min_samples: int = 1) -> np.ndarray:
    """DBSCAN on an eps-neighbour graph, labelled exactly as scikit-learn does.

    A point is core when at least ``min_samples`` points (itself included) are its neighbours.
    Clusters are the connected components of the core points' graph, numbered in the order of
    their smallest member index; a non-core point next to core points joins the lowest-numbered
    such cluster, and is noise (-1) otherwise. With ``min_samples = 1`` the clusters are simply the
    connected components (:func:`smallest_connected`).

    Args:
        n: number of points.
        i, j: (E,) int neighbour pairs, both directions listed, no self pairs.
        min_samples: >= 1.
    Returns:
        (n,) int64 labels, -1 for noise.
    """
    if min_samples < 1:
        raise ValueError(f"min_samples must be >= 1, got {min_samples}")
    if len(i) == 0:  # no neighbours at all: every point is its own cluster, or noise
        return np.arange(n, dtype=np.int64) if min_samples == 1 else np.full(n, -1, dtype=np.int64)
    labels = np.full(n, -1, dtype=np.int64)
    core = np.bincount(i, minlength=n) + 1 >= min_samples
    core_idx = np.flatnonzero(core)
    if len(core_idx) == 0:
        return labels
    both = core[i] & core[j]
    component = smallest_connected(n, i[both], j[both])
    # components numbered by their smallest member, which is the value smallest_connected gives
    labels[core_idx] = np.unique(component[core_idx], return_inverse=True)[1]
    to_core = ~core[i] & core[j]  # border point i next to core point j
    reach = np.full(n, n, dtype=np.int64)
    np.minimum.at(reach, i[to_core], labels[j[to_core]])
    border = reach < n
    labels[border] = reach[border]
    return labels


def smallest_connected(n: int, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Connected components of an undirected graph as the smallest node index of each component.

    Min-label propagation with pointer jumping: each round every node takes the smallest label
    among itself and its neighbours, then the label of that label. Labels only decrease and stay
    inside the component, so the fixpoint is the component minimum; the number of rounds grows
    with the logarithm of the component diameter. For the small graphs of one image (tens to a few
    hundred hypotheses) this beats building a scipy sparse graph by an order of magnitude.

    Args:
        n: number of nodes. i, j: (E,) int edges, both directions listed.
    Returns:
        (n,) int64, the smallest node index in each node's component.
    """
    label = np.arange(n, dtype=np.int64)
    while True:
        hooked = label.copy()
        np.minimum.at(hooked, i, label[j])
        hooked = hooked[hooked]
        if np.array_equal(hooked, label):
            return label
        label = hooked


@dataclass(frozen=True)
class PoseAveraging:
    """Cluster pose hypotheses of one image and average each cluster (docs/method.md#decoding).

    Attributes:
        space: the object's pose space (distance, symmetry group, δ).
        eps: DBSCAN radius as a fraction of δ (default 0.5 δ).
        min_samples: DBSCAN core-point threshold (1: clusters = connected components).
        cluster_score: "max" (default), "sum" or "mean" of the member scores (:data:`opnet.settings_schema.CLUSTER_SCORES`).
        keep_noise: keep DBSCAN noise points (only with min_samples > 1) as single hypotheses.
    """

    space: PoseSpace | Any  # or PoseSpaceArrays (deployment)
    eps: float = 0.5
    min_samples: int = 1
    cluster_score: str = "max"
    keep_noise: bool = False

    def __post_init__(self) -> None:
        check_settings({"averaging.eps": self.eps, "averaging.min_samples": self.min_samples,
                        "averaging.cluster_score": self.cluster_score}, TRAINING)

    def cluster(self, hyps: HypothesisSet) -> np.ndarray:
        """(N,) int64 DBSCAN labels of the hypotheses (-1 = noise).

        The pose distance is at least the translation distance, so only pairs whose translations
        lie within eps (a k-d tree query) need the full symmetry-aware distance: O(N log N).
        """
        eps = self.eps * self.space.delta
        pairs = cKDTree(hyps.t).query_pairs(eps, output_type="ndarray")  # (P, 2), i < j
        if len(pairs):
            a, b = pairs[:, 0], pairs[:, 1]
            pairs = pairs[pose_distance(self.space, hyps.R[a], hyps.t[a], hyps.R[b], hyps.t[b]) <= eps]
        i, j = (
            np.concatenate((pairs[:, 0], pairs[:, 1])),
            np.concatenate((pairs[:, 1], pairs[:, 0])),
        )
        return dbscan_graph(len(hyps), i, j, self.min_samples)

    def __call__(self, hyps: HypothesisSet) -> HypothesisSet:
        """Averaged hypotheses, one per cluster, ordered by cluster label (camera frame, metres)."""
        if len(hyps) <= 1:
            return hyps
        labels = self.cluster(hyps)
        if self.keep_noise:
            noise = labels < 0
            labels[noise] = labels.max() + 1 + np.arange(int(noise.sum()))
        keep = labels >= 0
        return self._average(hyps, labels[keep], keep)

    def _average(self, hyps: HypothesisSet, labels: np.ndarray, keep: np.ndarray) -> HypothesisSet:
        R, t, score = hyps.R[keep], hyps.t[keep], hyps.score[keep]  # (N, 3, 3), (N, 3), (N,)
        if len(labels) == 0:
            return HypothesisSet.empty()
        order = np.lexsort((-score, labels))  # by cluster, best score first
        sorted_labels = labels[order]
        start = np.flatnonzero(
            np.r_[True, sorted_labels[1:] != sorted_labels[:-1]]
        )  # (C,) first member
        counts = np.diff(np.r_[start, len(order)])  # (C,)
        best = order[start]  # (C,) best member of each cluster
        w = np.maximum(score[order], 1e-12)  # (N,) weights in sorted order
        w_sum = np.add.reduceat(w, start)  # (C,)
        t_mean = np.add.reduceat(w[:, None] * t[order], start, axis=0) / w_sum[:, None]
        R_mean = R[best].copy()  # singletons keep their rotation untouched
        several = counts > 1
        if several.any():
            member = np.repeat(several, counts)  # (N,) in a cluster of several
            first = np.r_[0, np.cumsum(counts[several])[:-1]]  # starts within the selected members
            R_mean[several] = self._mean_rotation(
                R[best][several], R[order][member], w[member], counts[several], first
            )
        vis = None
        if hyps.visibility is not None:
            vis = np.add.reduceat(w * hyps.visibility[keep][order], start) / w_sum
        return HypothesisSet(
            R_mean, t_mean, self._cluster_scores(score[order], start, best, score), vis
        )

    def _mean_rotation(
        self,
        R_best: np.ndarray,
        R: np.ndarray,
        w: np.ndarray,
        counts: np.ndarray,
        start: np.ndarray,
    ) -> np.ndarray:
        """Weighted mean rotation (C, 3, 3) of clusters given contiguously: R (N, 3, 3), w (N,)."""
        R_ref = np.repeat(R_best, counts, axis=0)  # (N, 3, 3)
        aligned = closest_equivalent(self.space, R_ref, R)
        if self.space.revolution:
            axes = np.add.reduceat(w[:, None] * aligned[:, :, 2], start, axis=0)  # (C, 3)
            return axis_rotation(axes / np.linalg.norm(axes, axis=-1, keepdims=True).clip(1e-12))
        return project_to_so3(np.add.reduceat(w[:, None, None] * aligned, start, axis=0))

    def _cluster_scores(
        self, sorted_score: np.ndarray, start: np.ndarray, best: np.ndarray, score: np.ndarray
    ) -> np.ndarray:
        if self.cluster_score == "max":
            return score[best]
        total = np.add.reduceat(sorted_score, start)
        if self.cluster_score == "sum":
            return total
        return total / np.diff(np.r_[start, len(sorted_score)])

