"""Where a pose goes wrong, split along what a depth image shows of a flat or spinning part.

:mod:`opnet.metrics.diagnostics` decides why each instance is missed (no hypothesis, position,
orientation). For a flat, thin or spinning part that is not enough to act on: an orientation miss may
be the part's normal tilted (what the visible plane shows) or a spin about it (what only the outline
or a few features show), and a position miss may lie across the image or along the viewing ray. This
module splits both, instance by instance, on the pose-nearest hypothesis of each instance:

- the translation error into its *lateral* part (across the image, camera x and y) and its *depth*
  part (camera z);
- the rotation into its *tilt* (the swing that takes the truth's main axis onto the hypothesis') and
  its *spin* (the turn about the main axis that is left), on the closest symmetric equivalent of the
  truth. The *main axis* is the principal axis of the surface whose spread stands farthest from the
  other two: a flat part's normal, a rod's axis, a ring's or a rim's axis; the revolution axis of a
  revolution part (whose spin the metric ignores).

Each miss that has a hypothesis near it is then put down to the largest of the four shares of its
squared Brégier distance: lateral, depth, tilt (the distance of the swing alone) or spin (of the turn
about the axis alone). A part missed mostly on spin is one whose turn about its axis the network did
not see; mostly on tilt, one whose plane it did not measure.

The instances are also counted by how the camera sees the truth's main axis (:data:`VIEWS`): *end-on* (the
axis within 30° of the line of sight: a plate seen face-on, a wheel seen from its hub), *oblique*, or
*side-on* (the axis within 30° of the image plane: a plate seen edge-on, a wheel lying on its tread). A spin
about an axis seen side-on moves the surface mostly along the line of sight or behind it, and a part whose
spin-telling features (spokes, holes, teeth) sit inside or under it may show nothing of its spin at all: found
shares that fall from end-on to side-on say so.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch

from opnet.geometry.distance import PoseSpace
from opnet.metrics.diagnostics import scene_outcomes
from opnet.metrics.records import GroundTruthSet, HypothesisSet

#: the components a miss is put down to (the largest share of its squared distance)
COMPONENTS = ("lateral", "depth", "tilt", "spin")
#: how the camera sees the truth's main axis: its angle to the line of sight below 30°, 30-60°, above 60°
VIEWS = ("end_on", "oblique", "side_on")
VIEW_EDGES_DEG = (30.0, 60.0)


def axis_angle(R: np.ndarray, t: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(N,) degrees in [0, 90] between the main ``axis`` (part frame; its sign does not matter) of parts at poses
    ``R`` (N, 3, 3), ``t`` (N, 3) (camera frame) and the line of sight through their origins."""
    a = np.asarray(R, np.float64) @ np.asarray(axis, np.float64)
    ray = np.asarray(t, np.float64) / np.linalg.norm(t, axis=-1, keepdims=True).clip(1e-12)
    return np.degrees(np.arccos(np.clip(np.abs((a * ray).sum(-1)), 0.0, 1.0)))


def view_of_axis(R: np.ndarray, t: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(N,) index into :data:`VIEWS` of parts at poses ``R`` (N, 3, 3), ``t`` (N, 3) (camera frame), by
    :func:`axis_angle`."""
    return np.searchsorted(np.asarray(VIEW_EDGES_DEG), axis_angle(R, t, axis), side="right")


def main_axis(space: PoseSpace) -> np.ndarray:
    """The part's main axis (unit, mesh frame): z for a revolution part, else the principal axis of Λ
    whose spread stands farthest (in ratio) from the other two (a flat part's normal, a rod's axis)."""
    if space.revolution:
        return np.array([0.0, 0.0, 1.0])
    M = space.Lambda @ space.Lambda.T  # Λ is symmetric: its square's axes are Λ's
    w, V = np.linalg.eigh(0.5 * (M + M.T))
    s = np.log(np.sqrt(np.maximum(w, 1e-18)))
    apart = [min(abs(s[i] - s[j]) for j in range(3) if j != i) for i in range(3)]
    return V[:, int(np.argmax(apart))]


def swing_twist(Q: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split rotations ``Q`` (N, 3, 3) into ``Q = swing @ twist``: ``twist`` a turn about ``axis``,
    ``swing`` the shortest turn taking ``axis`` onto ``Q axis``. Returns (swing, twist), each (N, 3, 3)."""
    from scipy.spatial.transform import Rotation

    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    b = Q @ a  # (N, 3) where the axis goes
    cross = np.cross(a, b)
    sin = np.linalg.norm(cross, axis=-1)
    cos = np.clip(b @ a, -1.0, 1.0)
    angle = np.arctan2(sin, cos)
    # a half turn: any axis across a (the swing is then ambiguous; pick one perpendicular to it)
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    across = np.cross(a, helper) / np.linalg.norm(np.cross(a, helper))
    unit = np.where(sin[:, None] > 1e-12, cross / np.maximum(sin, 1e-12)[:, None], across)
    swing = Rotation.from_rotvec(unit * angle[:, None]).as_matrix().reshape(-1, 3, 3)
    twist = np.swapaxes(swing, -1, -2) @ Q
    return swing, twist


@dataclass(frozen=True)
class ErrorBreakdown:
    """The errors of a set of scenes split along the part's main axis (module docstring).

    Attributes:
        to_find: instances that must be found; matched: found; no_hypothesis: missed with no
            hypothesis within half the diameter.
        missed_lateral, missed_depth, missed_tilt, missed_spin: the other misses, by the largest share
            of their squared distance.
        near: instances to find with a hypothesis within half the diameter (the error percentiles'
            population, matched or not).
        lateral_mm_p50, depth_mm_p50, tilt_deg_p50, spin_deg_p50 (and p90): over ``near``.
        axis: the main axis (mesh frame).
        to_find_by_view, matched_by_view: the instances to find and those found, by how the camera sees their
            main axis (:data:`VIEWS`: end-on, oblique, side-on).
    """

    to_find: int
    matched: int
    no_hypothesis: int
    missed_lateral: int
    missed_depth: int
    missed_tilt: int
    missed_spin: int
    near: int
    lateral_mm_p50: float
    lateral_mm_p90: float
    depth_mm_p50: float
    depth_mm_p90: float
    tilt_deg_p50: float
    tilt_deg_p90: float
    spin_deg_p50: float
    spin_deg_p90: float
    axis: tuple[float, float, float]
    to_find_by_view: tuple[int, int, int] = (0, 0, 0)
    matched_by_view: tuple[int, int, int] = (0, 0, 0)

    def found_by_view(self) -> dict[str, float]:
        """The share found of the instances to find seen each way (:data:`VIEWS`); NaN where none is."""
        return {v: m / n if n else float("nan")
                for v, n, m in zip(VIEWS, self.to_find_by_view, self.matched_by_view, strict=True)}

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def shares(self) -> dict[str, float]:
        """The outcomes as shares of the instances to find."""
        n = max(self.to_find, 1)
        keys = ("matched", "no_hypothesis", *(f"missed_{c}" for c in COMPONENTS))
        return {k: getattr(self, k) / n for k in keys}

    def table(self) -> str:
        """Two readable lines."""
        s = self.shares()
        ax = ", ".join(f"{a:+.2f}" for a in self.axis)
        misses = ", ".join(f"{c} {s[f'missed_{c}']:.1%}" for c in COMPONENTS)
        return "\n".join([
            f"Errors along the main axis ({ax}): found {s['matched']:.1%}; no hypothesis {s['no_hypothesis']:.1%}; "
            f"missed mostly on {misses}",
            f"  nearest hypotheses ({self.near}): lateral p50 {self.lateral_mm_p50:.1f} mm, depth p50 "
            f"{self.depth_mm_p50:.1f} mm, tilt p50 {self.tilt_deg_p50:.1f} deg, spin p50 {self.spin_deg_p50:.1f} deg",
            "  found by how the main axis is seen: " + ", ".join(
                f"{v.replace('_', '-')} {f:.0%} of {n}" if n else f"{v.replace('_', '-')} none"
                for (v, f), n in zip(self.found_by_view().items(), self.to_find_by_view, strict=True)),
        ])  # fmt: skip


def view_shares(breakdown: Mapping[str, Any]) -> dict[str, float | str]:
    """From a breakdown as a summary stores it (:meth:`ErrorBreakdown.to_dict`): ``found_end_on`` and
    ``found_side_on`` (the share found of the parts to find seen so) and ``side_on`` (the share of them seen side-on),
    each an empty string where nothing was seen so; all empty for a breakdown made before the count by view."""
    n, found = breakdown.get("to_find_by_view"), breakdown.get("matched_by_view")
    if not n or not sum(n):
        return {"found_end_on": "", "found_side_on": "", "side_on": ""}
    return {"found_end_on": found[0] / n[0] if n[0] else "", "found_side_on": found[2] / n[2] if n[2] else "",
            "side_on": n[2] / sum(n)}


def _rotation_sq(space: PoseSpace, Q: np.ndarray) -> np.ndarray:
    """Squared Brégier rotation distance (m²) of turns ``Q`` (N, 3, 3) in the part's frame from the identity."""
    if space.revolution:
        z = Q[:, :, 2]
        return space.lam**2 * ((z - np.array([0.0, 0.0, 1.0])) ** 2).sum(-1)
    diff = (Q - np.eye(3)) @ space.Lambda
    return (diff**2).sum((-1, -2))


def tilt_and_spin(space: PoseSpace, axis: np.ndarray, R_hat: np.ndarray,
                  R_true: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The rotation error of hypotheses ``R_hat`` (N, 3, 3) against truths ``R_true`` (N, 3, 3), on the symmetric
    equivalent of each truth nearest its hypothesis, split along the main ``axis`` (part frame): (tilt, spin) in
    degrees and the (swing, twist) turns (N, 3, 3) behind them. The spin of a revolution part is 0 (the metric
    ignores it)."""
    R_hat = np.asarray(R_hat, np.float64)
    R_eq = space.closest_equivalent(torch.from_numpy(R_hat), torch.from_numpy(np.asarray(R_true, np.float64))).numpy()
    Q = np.swapaxes(R_eq, -1, -2) @ R_hat  # truth -> hypothesis, part frame
    swing, twist = swing_twist(Q, axis)
    tilt = np.degrees(np.arccos(np.clip((swing @ axis) @ axis, -1, 1)))
    twist_vec = np.stack([twist[:, 2, 1] - twist[:, 1, 2], twist[:, 0, 2] - twist[:, 2, 0],
                          twist[:, 1, 0] - twist[:, 0, 1]], -1) @ axis  # fmt: skip
    spin = np.degrees(np.abs(np.arctan2(0.5 * twist_vec, 0.5 * (np.trace(twist, axis1=1, axis2=2) - 1))))
    if space.revolution:
        spin = np.zeros_like(spin)
    return tilt, spin, swing, twist


def error_breakdown(
    scenes: Mapping[str, tuple[GroundTruthSet, HypothesisSet]],
    space: PoseSpace,
    diameter: float,
    max_occlusion: float = 0.5,
    min_occlusion: float = -0.1,
) -> ErrorBreakdown:
    """Split the errors of every instance to find along the part's main axis (module docstring).

    Args:
        scenes: scene name -> (ground truth, hypotheses), camera frame, metres.
        space: the object's pose space; diameter: metres (a hypothesis is near within half of it).
        max_occlusion, min_occlusion: which instances must be found (as the evaluation).
    """
    axis = main_axis(space)
    counts = dict.fromkeys(("to_find", "matched", "no_hypothesis", *(f"missed_{c}" for c in COMPONENTS)), 0)
    lateral, depth, tilt, spin = [], [], [], []
    by_view = np.zeros((2, len(VIEWS)), dtype=np.int64)  # to find, found
    for (gt, _), scene in zip(scenes.values(), scene_outcomes(scenes, space, diameter, max_occlusion, min_occlusion),
                              strict=True):  # fmt: skip
        find = scene.find
        counts["to_find"] += int(find.sum())
        counts["matched"] += int((find & (scene.outcome == "matched")).sum())
        if find.any():
            view = view_of_axis(gt.R[find], gt.t[find], axis)
            by_view[0] += np.bincount(view, minlength=len(VIEWS))
            by_view[1] += np.bincount(view[scene.outcome[find] == "matched"], minlength=len(VIEWS))
        near = find & (scene.nearest >= 0) & (scene.outcome != "no_hypothesis")
        counts["no_hypothesis"] += int((find & ~near).sum())
        if not near.any():
            continue
        h = scene.hypotheses
        idx = scene.nearest[near]
        dt = np.asarray(h.t[idx], np.float64) - np.asarray(gt.t[near], np.float64)
        tilt_angle, spin_angle, swing, twist = tilt_and_spin(space, axis, h.R[idx], gt.R[near])
        lateral.append(1000 * np.linalg.norm(dt[:, :2], axis=-1))
        depth.append(1000 * np.abs(dt[:, 2]))
        tilt.append(tilt_angle)
        spin.append(spin_angle)
        shares = np.stack([(dt[:, :2] ** 2).sum(-1), dt[:, 2] ** 2, _rotation_sq(space, swing),
                           np.zeros(len(idx)) if space.revolution else _rotation_sq(space, twist)], -1)  # fmt: skip
        missed = scene.outcome[near] != "matched"
        for k, c in enumerate(COMPONENTS):
            counts[f"missed_{c}"] += int((missed & (shares.argmax(-1) == k)).sum())

    def pct(parts: list[np.ndarray], q: float) -> float:
        x = np.concatenate(parts) if parts else np.zeros(0)
        return float(np.percentile(x, q)) if len(x) else float("nan")

    n_near = int(sum(len(x) for x in lateral))
    return ErrorBreakdown(
        **counts, near=n_near,
        lateral_mm_p50=pct(lateral, 50), lateral_mm_p90=pct(lateral, 90),
        depth_mm_p50=pct(depth, 50), depth_mm_p90=pct(depth, 90),
        tilt_deg_p50=pct(tilt, 50), tilt_deg_p90=pct(tilt, 90),
        spin_deg_p50=pct(spin, 50), spin_deg_p90=pct(spin, 90),
        axis=(float(axis[0]), float(axis[1]), float(axis[2])),
        to_find_by_view=tuple(int(x) for x in by_view[0]), matched_by_view=tuple(int(x) for x in by_view[1]),
    )  # fmt: skip


__all__ = ["COMPONENTS", "VIEWS", "ErrorBreakdown", "axis_angle", "error_breakdown", "main_axis", "swing_twist",
           "tilt_and_spin", "view_of_axis", "view_shares"]
