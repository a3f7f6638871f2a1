"""Depth-agreement search around a pose hypothesis: the refinement ICP cannot do (issue 26).

Point-to-plane ICP fits a surface, so it cannot tell a flat part from the part turned about its
normal or slid along its plane: on the real IPD frames (steel T-plates on an expanded-metal basket)
the network's hypotheses lie within a centimetre of the plates but often with the T pointing the
wrong way, and ICP keeps them there. What does tell them apart is the depth image itself: at the
right pose the sensor measures the part's surface where the model says it is; at a turned pose
part of the model lies over the basket's holes, where the sensor sees *through* the model.

Per hypothesis (:func:`search_pose`):

1. the model points facing the camera, turned about the part's axis (``axis``: ``auto`` = the
   principal axis of least spread of the model's points, the normal of a flat part) through the
   pose's origin in steps of ``turn_step_deg`` all the way round, and shifted across that axis on a
   square grid of ``± shift`` (× diameter) in steps of ``shift_step``;
2. each candidate scored by its **agreement** with the depth image (:func:`agreement`): the
   fraction of its points whose measured depth lies within ``tolerance`` (× diameter) of the
   model's, minus ``see_through_weight`` × the fraction the sensor measures *behind* the model
   (free space the part would fill); points the sensor misses or sees occluded count neither way;
3. the best candidate is returned with its agreement (:class:`opnet.geometry.icp.Refiner` then
   polishes it by ICP, with ``score: agreement`` ranks the hypotheses by it, and drops those that
   ended within ``suppress`` × δ of a better one: duplicates).

The search deliberately visits poses that are *not* symmetric twins of the hypothesis: it is a
verification against the measured depth, not a local fit (ICP's guard still holds for ICP).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

SCORES = ("agreement", "network", "product")
AXES = ("auto", "x", "y", "z")


@dataclass(frozen=True)
class SearchSettings:
    """Settings of the search; lengths in units of the object's diameter (module docstring).

    Attributes:
        axis: the model axis the part is turned about: auto (least spread of its points) | x | y | z.
        turn_step_deg: step of the turns (all the way round).
        shift: largest shift across the axis, each way.
        shift_step: step of the shift grid.
        tolerance: a measured depth within this of the model's agrees.
        see_through_weight: weight of the points the sensor sees through (measured behind the model).
        score: the refined hypothesis's score: agreement | network (the network's, unchanged) |
            product (network × max(agreement, 0)).
        suppress: after the search, a hypothesis within this many δ (the metric's threshold, pose
            distance, symmetry-aware) of a better-scored one is dropped: searches from nearby
            hypotheses end on the same pose, and the copy could only count as a false positive
            (0: keep all).
        coarse: 1 searches the whole grid; N > 1 first a grid N times coarser, then the fine grid
            around its three best turns (about N² times fewer candidates).
    """

    axis: str = "auto"
    turn_step_deg: float = 5.0
    shift: float = 0.1
    shift_step: float = 0.02
    tolerance: float = 0.04
    see_through_weight: float = 1.0
    score: str = "agreement"
    suppress: float = 1.0
    coarse: int = 3

    def __post_init__(self) -> None:
        if self.axis not in AXES:
            raise ValueError(f"search.axis must be one of {', '.join(AXES)}, got {self.axis!r}")
        if self.score not in SCORES:
            raise ValueError(f"search.score must be one of {', '.join(SCORES)}, got {self.score!r}")
        for key in ("turn_step_deg", "shift_step", "tolerance"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or value <= 0:
                raise ValueError(f"search.{key} must be a positive number, got {value!r}")
        for key in ("shift", "see_through_weight", "suppress"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or value < 0:
                raise ValueError(f"search.{key} must be a number >= 0, got {value!r}")
        if isinstance(self.coarse, bool) or not isinstance(self.coarse, int) or self.coarse < 1:
            raise ValueError(f"search.coarse must be a positive integer, got {self.coarse!r}")
        if self.turn_step_deg > 360:
            raise ValueError(f"search.turn_step_deg must be at most 360, got {self.turn_step_deg!r}")
        if self.shift / self.shift_step > 50:
            raise ValueError(f"search: shift / shift_step = {self.shift / self.shift_step:g} makes a grid of more "
                             "than 101 x 101 shifts; take a larger shift_step")  # fmt: skip

    @classmethod
    def from_config(cls, cfg: Any) -> SearchSettings:
        """From a mapping (a config group); unknown keys are an error naming them."""
        cfg = dict(cfg or {})
        unknown = set(cfg) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"search: unknown keys {sorted(unknown)}; expected {', '.join(cls.__dataclass_fields__)}")
        return cls(**cfg)


def model_axis(points: np.ndarray, axis: str = "auto") -> np.ndarray:
    """The unit axis (3,) of the model frame the search turns about: a named axis, or (``auto``) the
    principal axis of least spread of ``points`` (P, 3) (the normal of a flat part)."""
    if axis != "auto":
        return np.eye(3)[AXES.index(axis) - 1]
    centred = points - points.mean(0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    return vectors[:, 0]


def agreement(points: np.ndarray, valid: np.ndarray, depth: np.ndarray, camera: Any, tolerance: float,
              see_through_weight: float) -> np.ndarray:  # fmt: skip
    """Agreement of posed model points (..., K, 3) (camera frame, metres; ``valid`` (..., K) marks
    those that count, e.g. facing the camera) with a z-depth image (H, W) (NaN: missing): per pose,
    (points measured within ``tolerance`` - ``see_through_weight`` x points measured behind the model
    by more) / valid points."""
    z = points[..., 2]
    safe = np.where(z > 0, z, np.inf)
    u = np.floor(points[..., 0] * camera.fx / safe + camera.cx + 0.5)
    v = np.floor(points[..., 1] * camera.fy / safe + camera.cy + 0.5)
    h, w = depth.shape
    inside = valid & (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    measured = depth[np.where(inside, v, 0).astype(np.intp), np.where(inside, u, 0).astype(np.intp)]
    r = np.where(inside, measured - z, np.nan)
    agree = np.sum(np.abs(r) <= tolerance, -1)  # NaN compares False: missing depth counts neither way
    through = np.sum(r > tolerance, -1)
    return (agree - see_through_weight * through) / np.maximum(np.sum(valid, -1), 1)


def turns(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations (T, 3, 3) by ``angles`` (T,) radians about the unit ``axis`` (Rodrigues)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    s, c = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _best_of(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any, n: np.ndarray,
             angles: np.ndarray, offsets: np.ndarray, frame: tuple[np.ndarray, np.ndarray], settings: SearchSettings,
             keep: int = 1) -> list[tuple[float, np.ndarray, np.ndarray, float]]:  # fmt: skip
    """The ``keep`` best (agreement, R, t, angle) among the turns ``angles`` (radians) of R about
    ``n`` through t and the shifts ``offsets[i] e1 + offsets[j] e2`` (metres); the best turn of each
    angle only, best first (ties: the earlier angle, the smaller shift)."""
    e1, e2 = frame
    shifts = (offsets[:, None, None] * e1 + offsets[None, :, None] * e2).reshape(-1, 3)  # (M, 3), row-major (i, j)
    D, found = model.diameter, []
    for angle, Rk in zip(angles, turns(n, angles) @ R, strict=True):  # one turn at a time: (M, K, 3) stays small
        posed, facing = model.posed(Rk, t)
        pts = posed[facing]
        scores = agreement(pts[None] + shifts[:, None], np.ones((len(shifts), len(pts)), bool), depth, camera,
                           settings.tolerance * D, settings.see_through_weight)  # fmt: skip
        m = int(np.argmax(scores))
        found.append((float(scores[m]), Rk, t + shifts[m], float(angle)))
    found.sort(key=lambda f: -f[0])  # stable: ties keep the earlier angle
    return found[:keep]


def search_pose(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any, axis: np.ndarray,
                settings: SearchSettings) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """The best pose among the turns and shifts of (R, t) (module docstring) and its agreement.

    With ``coarse`` > 1 the grid is first searched at ``coarse`` times its steps, then at its own
    steps around the three best coarse turns (± one coarse step of turn and shift each way).

    Args:
        R (3, 3), t (3,): the pose (camera frame, metres). model: a :class:`opnet.geometry.icp.ModelCloud`.
        depth: (H, W) z-depth (metres, NaN missing) seen by ``camera`` (fx, fy, cx, cy).
        axis: the model-frame axis to turn about (:func:`model_axis`).
    Returns:
        (R, t, agreement) of the best candidate (the first of equals: no turn, no shift, if it ties).
    """
    D, s = model.diameter, settings
    n = R @ axis  # the axis in the camera frame, through the origin t
    helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    frame = (e1, np.cross(n, e1))

    def offsets(step: float, reach: float) -> np.ndarray:
        k = int(np.floor(reach / step + 1e-9))
        values = np.arange(-k, k + 1) * step
        return values[np.argsort(np.abs(values), kind="stable")]  # no shift first: it wins ties

    if s.coarse <= 1:
        angles = np.radians(np.arange(0.0, 360.0 - 1e-9, s.turn_step_deg))
        best = _best_of(R, t, model, depth, camera, n, angles, offsets(s.shift_step * D, s.shift * D), frame, s)[0]
        return best[1], best[2], best[0]
    turn, step = s.turn_step_deg * s.coarse, s.shift_step * s.coarse
    angles = np.radians(np.arange(0.0, 360.0 - 1e-9, turn))
    coarse = _best_of(R, t, model, depth, camera, n, angles, offsets(step * D, s.shift * D), frame, s, keep=3)
    best = None
    for _, _, t_c, angle in coarse:
        fine = np.radians(np.arange(-turn, turn + 1e-9, s.turn_step_deg)) + angle
        fine = fine[np.argsort(np.abs(fine - angle), kind="stable")]  # the coarse turn first: it wins ties
        found = _best_of(R, t_c, model, depth, camera, n, fine, offsets(s.shift_step * D, step * D), frame, s)[0]
        if best is None or found[0] > best[0]:
            best = found
    return best[1], best[2], best[0]


def pose_agreement(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any,
                   settings: SearchSettings) -> float:  # fmt: skip
    """:func:`agreement` of one pose (its model points facing the camera)."""
    posed, facing = model.posed(R, t)
    return float(agreement(posed[None], facing[None], depth, camera, settings.tolerance * model.diameter,
                           settings.see_through_weight)[0])  # fmt: skip


__all__ = ["AXES", "SCORES", "SearchSettings", "agreement", "model_axis", "pose_agreement", "search_pose", "turns"]
