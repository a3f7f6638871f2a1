"""Why instances are missed: error diagnostics next to the AP (what a user acts on when a part
scores low).

With every hypothesis in (the lowest threshold of the curve), each instance that must be found is
either matched (a true positive of the Brégier protocol, docs/method.md#matching-and-scores) or missed for
one of four reasons, decided on the hypothesis nearest to it in pose distance:

- ``no_hypothesis``: no hypothesis has its origin within ``near`` (half the object diameter) of the
  instance's: the network did not see the part at all (presence), or placed it far away;
- ``position``: the nearest hypothesis is farther than δ from the instance and its origin alone is
  more than δ away (position error > δ);
- ``orientation``: the origin is within δ but the symmetry-aware pose distance is not: the
  orientation is wrong (rotation error > δ in the metric's units);
- ``conflict``: a hypothesis lies within δ, but the mutual-nearest-neighbour matching gave it to
  another instance (or another hypothesis of this instance is nearer but wrong).

Hypotheses are counted as ``duplicates`` (within δ of an instance that another hypothesis matched)
and ``false_positives`` (farther than δ from every instance); ``confident`` counts only those with a
score of at least ``confident_score``. For matched pairs the translation error (mm) and the
symmetry-aware rotation error (degrees; the axis angle for revolution objects) are summarised by
percentiles.

:func:`orientation_misses` looks closer at the ``orientation`` misses: the turn that takes each truth
(its closest symmetric equivalent) to its pose-nearest hypothesis, in the part's own frame. A pile of
them near 180° about one axis says the network confuses two faces of the part (a near-symmetry the
part's declared group does not have); errors spread below 60° say it is merely imprecise.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch

from opnet.geometry.distance import PoseSpace
from opnet.metrics.bregier import instances_to_find, pose_distances_per_scene
from opnet.metrics.records import GroundTruthSet, HypothesisSet

MISS_REASONS = ("no_hypothesis", "position", "orientation", "conflict")


@dataclass(frozen=True)
class ErrorDiagnostics:
    """Counts and error percentiles over a set of scenes (see the module docstring).

    Attributes:
        to_find: instances that must be found; matched: of those, found (every hypothesis in).
        no_hypothesis, position, orientation, conflict: missed instances by reason.
        hypotheses: all hypotheses; duplicates, false_positives: of those;
        confident_duplicates, confident_false_positives: with score >= ``confident_score``.
        t_err_mm_p50, t_err_mm_p90, r_err_deg_p50, r_err_deg_p90: matched pairs (NaN if none).
        confident_score: the score of a "confident" hypothesis.
    """

    to_find: int
    matched: int
    no_hypothesis: int
    position: int
    orientation: int
    conflict: int
    hypotheses: int
    duplicates: int
    false_positives: int
    confident_duplicates: int
    confident_false_positives: int
    t_err_mm_p50: float
    t_err_mm_p90: float
    r_err_deg_p50: float
    r_err_deg_p90: float
    confident_score: float

    def to_dict(self) -> dict[str, float | int]:
        return asdict(self)

    def table(self) -> str:
        """A few readable lines (fractions of the instances to find)."""
        n = max(self.to_find, 1)
        misses = ", ".join(f"{r.replace('_', ' ')} {getattr(self, r)} ({getattr(self, r) / n:.1%})" for r in MISS_REASONS)
        return "\n".join([
            f"Error diagnostics (every hypothesis in): {self.matched} of {self.to_find} instances found "
            f"({self.matched / n:.1%})",
            f"  missed: {misses}",
            f"  hypotheses {self.hypotheses}: duplicates {self.duplicates}, false positives "
            f"{self.false_positives}; with score >= {self.confident_score:g}: duplicates "
            f"{self.confident_duplicates}, false positives {self.confident_false_positives}",
            f"  matched pairs: translation error p50 {self.t_err_mm_p50:.1f} mm, p90 {self.t_err_mm_p90:.1f} mm; "
            f"rotation error p50 {self.r_err_deg_p50:.1f} deg, p90 {self.r_err_deg_p90:.1f} deg",
        ])  # fmt: skip


def rotation_errors_deg(R_hat: np.ndarray, R: np.ndarray, space: PoseSpace) -> np.ndarray:
    """Symmetry-aware rotation error in degrees of pairs (N, 3, 3): the angle between ``R_hat``
    and the closest symmetric equivalent of ``R`` (the axis angle for revolution objects): the angle
    of :func:`part_frame_turns`."""
    return np.degrees(np.linalg.norm(part_frame_turns(R_hat, R, space), axis=-1))


def part_frame_turns(R_hat: np.ndarray, R: np.ndarray, space: PoseSpace) -> np.ndarray:
    """Rotation vectors (N, 3), part frame, of the turns ``Q = R_eq^T R_hat`` that take the closest
    symmetric equivalent ``R_eq`` of each truth ``R`` to its hypothesis ``R_hat``; the angle (the
    vector's norm) is in [0, pi]. For revolution objects the spin about the axis is left out."""
    from scipy.spatial.transform import Rotation

    if len(R) == 0:
        return np.zeros((0, 3))
    R_hat64 = np.asarray(R_hat, np.float64)
    R_eq = space.closest_equivalent(torch.from_numpy(R_hat64), torch.from_numpy(np.asarray(R, np.float64))).numpy()
    Q = np.swapaxes(R_eq, -1, -2) @ R_hat64
    if space.revolution:  # the shortest turn that takes the axis z to the hypothesis' axis
        z = np.einsum("nij,j->ni", Q, [0.0, 0.0, 1.0])
        axis = np.cross([0.0, 0.0, 1.0], z)
        sin, cos = np.linalg.norm(axis, axis=-1), np.clip(z[:, 2], -1, 1)
        angle = np.arctan2(sin, cos)
        unit = np.where(sin[:, None] > 1e-9, axis / np.maximum(sin, 1e-12)[:, None], [[1.0, 0.0, 0.0]])
        return unit * angle[:, None]
    return Rotation.from_matrix(Q).as_rotvec()


@dataclass(frozen=True)
class SceneOutcome:
    """What happened to every instance and hypothesis of one scene (module docstring).

    Attributes:
        hypotheses: the scene's hypotheses.
        find: (N,) bool, the instance must be found.
        outcome: (N,) str per instance: "matched" or one of :data:`MISS_REASONS` (decided for every
            instance, also those that need not be found).
        duplicate, false_positive: (M,) bool per hypothesis.
        t_err_mm, r_err_deg: errors of the matched instances (in instance order).
        nearest: (N,) int per instance, its pose-nearest hypothesis (-1 in a scene without any).
    """

    hypotheses: HypothesisSet
    find: np.ndarray
    outcome: np.ndarray
    duplicate: np.ndarray
    false_positive: np.ndarray
    t_err_mm: np.ndarray
    r_err_deg: np.ndarray
    nearest: np.ndarray


def scene_outcomes(
    scenes: Mapping[str, tuple[GroundTruthSet, HypothesisSet]],
    space: PoseSpace,
    diameter: float,
    max_occlusion: float = 0.5,
    min_occlusion: float = -0.1,
) -> list[SceneOutcome]:
    """Per-instance outcomes of each scene, in the order of ``scenes`` (see :func:`diagnose`)."""
    delta, near = space.delta, diameter / 2
    out = []
    pairs = [(h, gt) for gt, h in scenes.values()]
    for (h, gt), D in zip(pairs, pose_distances_per_scene(pairs, space), strict=True):
        find = instances_to_find(gt, max_occlusion, min_occlusion)
        outcome = np.full(len(gt), "no_hypothesis", dtype=object)
        duplicate = np.zeros(len(h), bool)
        false_positive = np.ones(len(h), bool)  # every hypothesis of a scene without instances
        none = np.zeros(0)
        if len(h) == 0 or len(gt) == 0:
            out.append(SceneOutcome(h, find, outcome, duplicate, false_positive, none, none,
                                    np.full(len(gt), -1)))
            continue
        nearest_gt = D.argmin(1)  # (M,)
        nearest_hyp = D.argmin(0)  # (N,)
        d_min = D[nearest_hyp, np.arange(len(gt))]  # (N,)
        matched = (nearest_gt[nearest_hyp] == np.arange(len(gt))) & (d_min <= delta)
        # misses by reason, from the pose-nearest hypothesis of each missed instance
        t_dist = np.linalg.norm(h.t[:, None] - gt.t[None], axis=-1)  # (M, N)
        t_near = t_dist[nearest_hyp, np.arange(len(gt))]
        rest = ~matched & (t_dist.min(0) <= near)
        outcome[matched] = "matched"
        outcome[rest & (d_min <= delta)] = "conflict"
        outcome[rest & (d_min > delta) & (t_near > delta)] = "position"
        outcome[rest & (d_min > delta) & (t_near <= delta)] = "orientation"
        # hypotheses: true positives are the matched instances' nearest hypotheses
        is_tp = np.zeros(len(h), bool)
        is_tp[nearest_hyp[matched]] = True
        close = D.min(1) <= delta
        pairs_j = np.flatnonzero(matched)
        pairs_i = nearest_hyp[pairs_j]
        out.append(SceneOutcome(
            h, find, outcome, close & ~is_tp, ~close,
            1000 * np.linalg.norm(h.t[pairs_i] - gt.t[pairs_j], axis=-1),
            rotation_errors_deg(h.R[pairs_i], gt.R[pairs_j], space), nearest_hyp,
        ))  # fmt: skip
    return out


def diagnose(
    scenes: Mapping[str, tuple[GroundTruthSet, HypothesisSet]],
    space: PoseSpace,
    diameter: float,
    max_occlusion: float = 0.5,
    min_occlusion: float = -0.1,
    confident_score: float = 0.5,
) -> ErrorDiagnostics:
    """Diagnose the misses and false positives of a set of scenes (module docstring).

    Args:
        scenes: scene name -> (ground truth, hypotheses), one common frame, metres.
        space: the object's pose space (distance, δ).
        diameter: the object's diameter, metres (``near`` = diameter / 2).
        max_occlusion, min_occlusion: which instances must be found (as the evaluation).
        confident_score: hypotheses with at least this score count as confident.
    """
    counts = dict.fromkeys((*MISS_REASONS, "to_find", "matched", "hypotheses", "duplicates", "false_positives",
                            "confident_duplicates", "confident_false_positives"), 0)  # fmt: skip
    t_err: list[np.ndarray] = []
    r_err: list[np.ndarray] = []
    for scene in scene_outcomes(scenes, space, diameter, max_occlusion, min_occlusion):
        h, find = scene.hypotheses, scene.find
        counts["to_find"] += int(find.sum())
        counts["matched"] += int((find & (scene.outcome == "matched")).sum())
        for reason in MISS_REASONS:
            counts[reason] += int((find & (scene.outcome == reason)).sum())
        counts["hypotheses"] += len(h)
        confident = h.score >= confident_score
        counts["duplicates"] += int(scene.duplicate.sum())
        counts["false_positives"] += int(scene.false_positive.sum())
        counts["confident_duplicates"] += int((scene.duplicate & confident).sum())
        counts["confident_false_positives"] += int((scene.false_positive & confident).sum())
        t_err.append(scene.t_err_mm)
        r_err.append(scene.r_err_deg)
    t_all = np.concatenate(t_err) if t_err else np.zeros(0)
    r_all = np.concatenate(r_err) if r_err else np.zeros(0)

    def pct(x: np.ndarray, q: float) -> float:
        return float(np.percentile(x, q)) if len(x) else float("nan")

    return ErrorDiagnostics(
        **counts,
        t_err_mm_p50=pct(t_all, 50), t_err_mm_p90=pct(t_all, 90),
        r_err_deg_p50=pct(r_all, 50), r_err_deg_p90=pct(r_all, 90),
        confident_score=float(confident_score),
    )  # fmt: skip


#: the most turns clustered into modes (beyond, an even subsample of them)
MAX_CLUSTERED = 3000
#: edges (degrees) of the histogram of :class:`OrientationMisses`
TURN_BINS = (0, 30, 60, 90, 120, 150, 180)


@dataclass(frozen=True)
class TurnMode:
    """A cluster of orientation misses whose turns (truth -> hypothesis, part frame) lie within the
    clustering radius of one another: its centre's angle (degrees) and unit axis (part frame), the
    axis' angle to the part's z axis (its main or symmetry axis, degrees in [0, 90]) and the share
    of the orientation misses in it."""

    angle_deg: float
    axis: tuple[float, float, float]
    tilt_deg: float
    share: float

    def text(self) -> str:
        ax = ", ".join(f"{a:+.2f}" for a in self.axis)
        return f"{self.share:.0%} a {self.angle_deg:.0f}° turn about ({ax}), {self.tilt_deg:.0f}° from the part's z"


@dataclass(frozen=True)
class OrientationMisses:
    """The orientation misses of a set of scenes, looked at closer (module docstring).

    Attributes:
        count: orientation misses (instances that must be found).
        histogram: their counts per turn angle, bins :data:`TURN_BINS` (degrees).
        turned_over: share with a turn of more than 150°.
        modes: the largest clusters of turns (:class:`TurnMode`), largest first.
        radius_deg: the clustering radius.
    """

    count: int
    histogram: tuple[int, ...]
    turned_over: float
    modes: tuple[TurnMode, ...]
    radius_deg: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def table(self) -> str:
        """A few readable lines."""
        if not self.count:
            return "Orientation misses: none"
        n = self.count
        bins = ", ".join(f"{a}-{b}° {c / n:.0%}" for a, b, c in zip(TURN_BINS, TURN_BINS[1:], self.histogram))
        modes = "; ".join(m.text() for m in self.modes) or "none"
        return "\n".join([
            f"Orientation misses ({n}), turn from the truth to the nearest hypothesis in the part's frame: {bins}",
            f"  turned over (> 150°): {self.turned_over:.0%}; largest clusters (within {self.radius_deg:g}°): {modes}",
        ])  # fmt: skip


def _turn_distances(v: np.ndarray) -> np.ndarray:
    """Pairwise angles (radians) between the rotations of rotation vectors ``v`` (N, 3)."""
    from scipy.spatial.transform import Rotation

    q = Rotation.from_rotvec(v).as_quat()
    return 2 * np.arccos(np.clip(np.abs(q @ q.T), 0, 1))


def orientation_misses(
    scenes: Mapping[str, tuple[GroundTruthSet, HypothesisSet]],
    space: PoseSpace,
    diameter: float,
    max_occlusion: float = 0.5,
    min_occlusion: float = -0.1,
    radius_deg: float = 20.0,
    top: int = 3,
    min_share: float = 0.05,
) -> OrientationMisses:
    """The turns of the orientation misses (module docstring): their histogram, the share turned over
    and the ``top`` largest clusters of at least ``min_share`` of them (greedy: the turn with the most
    others within ``radius_deg`` is a centre, it and its neighbours are taken out, and again)."""
    R_hat, R = [], []
    outcomes = scene_outcomes(scenes, space, diameter, max_occlusion, min_occlusion)
    for (gt, _), scene in zip(scenes.values(), outcomes, strict=True):
        miss = scene.find & (scene.outcome == "orientation")
        R_hat.append(scene.hypotheses.R[scene.nearest[miss]])
        R.append(gt.R[miss])
    v = part_frame_turns(np.concatenate(R_hat), np.concatenate(R), space) if R else np.zeros((0, 3))
    angle = np.degrees(np.linalg.norm(v, axis=-1))
    histogram = tuple(int(c) for c in np.histogram(angle, bins=TURN_BINS)[0])
    modes: list[TurnMode] = []
    if len(v):
        # the clusters of at most MAX_CLUSTERED turns (an even subsample beyond: the pairwise table is N x N)
        w = v[np.linspace(0, len(v) - 1, MAX_CLUSTERED).astype(int)] if len(v) > MAX_CLUSTERED else v
        near = _turn_distances(w) <= np.radians(radius_deg)
        left = np.ones(len(w), bool)
        while len(modes) < top and left.any():
            counts = (near & left[None] & left[:, None]).sum(1)
            centre = int(counts.argmax())
            if counts[centre] < max(min_share * len(w), 1):
                break
            members = near[centre] & left
            left &= ~members
            turn = float(np.degrees(np.linalg.norm(w[centre])))
            a = w[centre] / max(np.linalg.norm(w[centre]), 1e-12)
            a = -a if turn > 179.5 and a[np.abs(a).argmax()] < 0 else a  # a half turn: one sign of its axis
            modes.append(TurnMode(turn, (float(a[0]), float(a[1]), float(a[2])),
                                  float(np.degrees(np.arccos(min(abs(a[2]), 1.0)))), float(members.sum() / len(w))))
    return OrientationMisses(len(v), histogram, float((angle > 150).mean()) if len(v) else 0.0, tuple(modes),
                             float(radius_deg))


__all__ = ["MISS_REASONS", "TURN_BINS", "ErrorDiagnostics", "OrientationMisses", "SceneOutcome", "TurnMode",
           "diagnose", "orientation_misses", "part_frame_turns", "rotation_errors_deg", "scene_outcomes"]
