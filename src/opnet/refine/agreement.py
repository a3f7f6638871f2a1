"""The depth agreement of posed model points: how well a depth image confirms a pose (module docstring
of :mod:`opnet.refine.search`). The search scores its candidates by it, the refinement ranks its poses
by it, and the batched ICP takes its camera-facing model points from :func:`facing_points`."""

from __future__ import annotations

from typing import Any

import numpy as np

from opnet.refine.settings import SearchSettings


def agreement(points: np.ndarray, valid: np.ndarray, depth: np.ndarray, camera: Any, tolerance: float,
              see_through_weight: float) -> np.ndarray:  # fmt: skip
    """Agreement of posed model points (..., K, 3) (camera frame, metres; ``valid`` (..., K) marks
    those that count, e.g. facing the camera) with a z-depth image (H, W) (NaN: missing): per pose,
    (points measured within ``tolerance`` - ``see_through_weight`` x points measured behind the model
    by more) / valid points."""
    return agreement_xyz(points[..., 0], points[..., 1], points[..., 2], valid, depth, camera, tolerance,
                         see_through_weight)  # fmt: skip


def agreement_xyz(x: np.ndarray, y: np.ndarray, z: np.ndarray, valid: np.ndarray, depth: np.ndarray, camera: Any,
                  tolerance: float, see_through_weight: float) -> np.ndarray:  # fmt: skip
    """:func:`agreement` of points given by their coordinates x, y, z (..., K) each."""
    inv = np.divide(1.0, z, out=np.zeros_like(z), where=z > 0)  # behind the camera: never inside
    u = x * (camera.fx * inv) + (camera.cx + 0.5)  # the pixel is floor(u); u >= 0 makes the cast a floor
    v = y * (camera.fy * inv) + (camera.cy + 0.5)
    h, w = depth.shape
    inside = valid & (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    index = np.where(inside, v, 0).astype(np.intp) * w + np.where(inside, u, 0).astype(np.intp)  # no cast of inf
    r = depth.ravel()[index] - z
    r[~inside] = np.nan
    agree = np.count_nonzero(np.abs(r) <= tolerance, -1)  # NaN compares False: missing depth counts neither way
    through = np.count_nonzero(r > tolerance, -1)
    return (agree - see_through_weight * through) / np.maximum(np.count_nonzero(valid, -1), 1)


def posed_xyz(R: np.ndarray, t: np.ndarray, model: Any, dtype: Any = np.float64,
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """All the model points at poses (N, 3, 3), (N, 3), camera frame: x, y, z (N, P) each of ``dtype`` (one
    matrix product per coordinate), and which face the camera (N, P)."""
    R, t = np.asarray(R, np.float64), np.asarray(t, np.float64)
    points = model.points.T.astype(dtype)
    x, y, z = (R[:, k].astype(dtype) @ points + t[:, k : k + 1].astype(dtype) for k in range(3))
    # (R n) . (R p + t) = n . p + n . (R^T t): one (N, P) product, no turned normals
    local_t = np.einsum("nji,nj->ni", R, t)
    facing = local_t @ model.normals.T + np.sum(model.normals * model.points, 1) < 0
    return x, y, z, facing


def facing_xyz(R: np.ndarray, t: np.ndarray, model: Any, dtype: Any = np.float64,
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The model points facing the camera at poses (N, 3, 3), (N, 3), packed: x, y, z (N, K) each of ``dtype``,
    and which of them are real (N, K) (K: the most any pose has; the rest pad with point 0, masked out).
    Agreement counts only these, at half the work of all the points."""
    x, y, z, facing = posed_xyz(R, t, model, dtype)
    N, P = facing.shape
    count = facing.sum(1)
    K = int(count.max(initial=0))
    rows, cols = np.nonzero(facing)  # row-major: each pose's facing points in model order
    slot = np.arange(len(rows)) - np.repeat(np.cumsum(count) - count, count)
    chosen = np.zeros((N, K), np.intp)
    chosen[rows, slot] = cols
    chosen += (np.arange(N) * P)[:, None]  # flat indices: one gather per coordinate
    return (*(c.ravel()[chosen] for c in (x, y, z)), np.arange(K) < count[:, None])


def _dtype(depth: np.ndarray) -> Any:
    """The float type points are scored in against ``depth``: its own (float32 halves the memory traffic:
    millimetre tolerances at metres lose nothing in it)."""
    return depth.dtype if depth.dtype in (np.float32, np.float64) else np.float64


def score_poses(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any,
                settings: SearchSettings) -> np.ndarray:  # fmt: skip
    """Agreement of poses (N, 3, 3), (N, 3) (their model points facing the camera), in one batch."""
    x, y, z, facing = facing_xyz(R, t, model, _dtype(depth))
    return agreement_xyz(x, y, z, facing, depth, camera, settings.tolerance * model.diameter,
                         settings.see_through_weight)  # fmt: skip


def facing_points(R: np.ndarray, t: np.ndarray, model: Any) -> tuple[np.ndarray, np.ndarray]:
    """:func:`facing_xyz` as points: (N, K, 3) and which of them are real (N, K)."""
    x, y, z, valid = facing_xyz(R, t, model)
    return np.stack((x, y, z), -1), valid


def pose_agreement(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any,
                   settings: SearchSettings) -> float:  # fmt: skip
    """:func:`agreement` of one pose (its model points facing the camera)."""
    return float(score_poses(np.asarray(R)[None], np.asarray(t)[None], model, depth, camera, settings)[0])


__all__ = [
    "agreement",
    "agreement_xyz",
    "facing_points",
    "facing_xyz",
    "pose_agreement",
    "posed_xyz",
    "score_poses",
]
