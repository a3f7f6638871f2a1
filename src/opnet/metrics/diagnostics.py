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
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass

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
    and the closest symmetric equivalent of ``R`` (the axis angle for revolution objects)."""
    if len(R) == 0:
        return np.zeros(0)
    R_hat_t, R_t = torch.from_numpy(np.asarray(R_hat, np.float64)), torch.from_numpy(np.asarray(R, np.float64))
    R_eq = space.closest_equivalent(R_hat_t, R_t).numpy()
    if space.revolution:
        chord = np.linalg.norm(R_eq[:, :, 2] - R_hat[:, :, 2], axis=-1)
    else:
        chord = np.linalg.norm(R_eq - R_hat, axis=(1, 2)) / np.sqrt(2)
    return np.degrees(2 * np.arcsin(np.clip(chord / 2, 0, 1)))


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
    """

    hypotheses: HypothesisSet
    find: np.ndarray
    outcome: np.ndarray
    duplicate: np.ndarray
    false_positive: np.ndarray
    t_err_mm: np.ndarray
    r_err_deg: np.ndarray


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
            out.append(SceneOutcome(h, find, outcome, duplicate, false_positive, none, none))
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
            rotation_errors_deg(h.R[pairs_i], gt.R[pairs_j], space),
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


__all__ = ["MISS_REASONS", "ErrorDiagnostics", "SceneOutcome", "diagnose", "rotation_errors_deg", "scene_outcomes"]
