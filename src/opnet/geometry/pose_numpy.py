"""The pose-space operations of the hypothesis averaging in numpy (no PyTorch import).

The same formulas as :class:`opnet.geometry.distance.PoseSpace` (the metric's torch code; a unit
test checks both agree to 1e-12), for the averaging that runs on numpy hypothesis sets, in
training's evaluation and in the torch-free ONNX deployment (:mod:`opnet.deploy`).
Every function takes a ``space`` with the attributes of ``PoseSpace``: ``Lambda`` (3, 3),
``group`` (K, 3, 3), ``delta``, ``revolution``, ``lam`` (a ``PoseSpace`` or :class:`PoseSpaceArrays`).
Besides, the numpy rotations they and the refinement (:mod:`opnet.refine`) build on: quaternions,
the projection onto SO(3), turns about axes (Rodrigues) and the 24 turns mapping the axes onto one another.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass(frozen=True)
class PoseSpaceArrays:
    """The numbers of a pose space, without its torch methods (for deployment metadata)."""

    Lambda: np.ndarray = field(compare=False)
    group: np.ndarray = field(compare=False)
    delta: float
    revolution: bool = False
    lam: float = 0.0

    @classmethod
    def of(cls, space: Any) -> PoseSpaceArrays:
        return cls(np.asarray(space.Lambda, np.float64).reshape(3, 3), np.asarray(space.group, np.float64).reshape(-1, 3, 3),
                   float(space.delta), bool(space.revolution), float(space.lam))

    def to_dict(self) -> dict[str, Any]:
        return {"Lambda": self.Lambda.tolist(), "group": self.group.tolist(), "delta": self.delta,
                "revolution": self.revolution, "lam": self.lam}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PoseSpaceArrays:
        return cls(np.asarray(d["Lambda"], np.float64).reshape(3, 3), np.asarray(d["group"], np.float64).reshape(-1, 3, 3),
                   float(d["delta"]), bool(d["revolution"]), float(d["lam"]))


def representatives(space: Any, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(..., K, D) representatives of poses R (..., 3, 3), t (..., 3): D = 12 (finite group, the
    column-major R g Lambda and t) or 6 (revolution: lam R g e_z and t)."""
    G = np.asarray(space.group)
    K = len(G)
    if space.revolution:
        rot = space.lam * np.einsum("...ij,kj->...ki", R, G[:, :, 2])
    else:
        RGL = R[..., None, :, :] @ G @ np.asarray(space.Lambda)  # (..., K, 3, 3)
        rot = np.swapaxes(RGL, -1, -2).reshape(RGL.shape[:-2] + (9,))
    t_part = np.broadcast_to(t[..., None, :], t.shape[:-1] + (K, 3))
    return np.concatenate((rot, t_part), axis=-1)


def pose_distance(space: Any, R1: np.ndarray, t1: np.ndarray, R2: np.ndarray, t2: np.ndarray) -> np.ndarray:
    """Element-wise symmetry-aware pose distance (metres) of broadcastable batches -> (...)."""
    r1 = representatives(space, R1, t1)[..., 0, :]
    r2 = representatives(space, R2, t2)
    return np.linalg.norm(r2 - r1[..., None, :], axis=-1).min(axis=-1)


def closest_equivalent(space: Any, R_ref: np.ndarray, R: np.ndarray) -> np.ndarray:
    """The symmetric equivalent ``R g`` of R closest to R_ref (for revolution objects only the
    axis flip is chosen): (..., 3, 3) -> (..., 3, 3)."""
    cand = R[..., None, :, :] @ np.asarray(space.group)  # (..., K, 3, 3)
    if space.revolution:
        err = np.square(cand[..., :, 2] - R_ref[..., None, :, 2]).sum(-1)
    else:
        err = np.square((cand - R_ref[..., None, :, :]) @ np.asarray(space.Lambda)).sum((-1, -2))
    best = err.argmin(axis=-1)
    return np.take_along_axis(cand, best[..., None, None, None], axis=-3)[..., 0, :, :]


def rotation_change_deg(R_from: np.ndarray, R_to: np.ndarray, space: Any) -> float:
    """The symmetry-aware angle (degrees) between two rotations: the axis angle for revolution
    objects, else the angle to the closest symmetric equivalent."""
    R_eq = closest_equivalent(space, R_from[None], R_to[None])[0]
    if space.revolution:
        cos = float(np.clip(R_eq[:, 2] @ R_from[:, 2], -1, 1))
    else:
        cos = float(np.clip((np.trace(R_from.T @ R_eq) - 1) / 2, -1, 1))
    return float(np.degrees(np.arccos(cos)))


def quaternion_to_matrix(q: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) as (w, x, y, z), normalized first, to rotations (..., 3, 3) float64
    (the torch :func:`opnet.geometry.rotations.quaternion_to_matrix` in numpy)."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    entries = (
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    )  # fmt: skip
    return np.stack(entries, axis=-1).reshape(q.shape[:-1] + (3, 3))


def project_to_so3(M: np.ndarray) -> np.ndarray:
    """Nearest rotation (Frobenius norm) via SVD: (..., 3, 3) -> (..., 3, 3)."""
    U, _, Vh = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vh))
    D = np.zeros(d.shape + (3, 3))
    D[..., 0, 0] = D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    return U @ D @ Vh


def axis_rotation(axes: np.ndarray) -> np.ndarray:
    """The rotation ``Rz(a) Ry(b)`` whose z-axis is the unit axis: (N, 3) -> (N, 3, 3) float64.

    Revolution objects do not care about the spin about their axis; this is the spin-free (φ3 = 0)
    representative the parameterizations decode as well.
    """
    a = np.arctan2(axes[:, 1], axes[:, 0])
    b = np.arccos(np.clip(axes[:, 2], -1.0, 1.0))
    ca, sa, cb, sb = np.cos(a), np.sin(a), np.cos(b), np.sin(b)
    zero = np.zeros_like(a)
    return np.stack([
        np.stack([ca * cb, -sa, ca * sb], -1),
        np.stack([sa * cb, ca, sa * sb], -1),
        np.stack([-sb, zero, cb], -1),
    ], -2)  # fmt: skip


def turns(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations (T, 3, 3) by ``angles`` (T,) radians about the unit ``axis`` (3,) (Rodrigues)."""
    return rodrigues(axis, angles)


def skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrices (..., 3, 3) of vectors (..., 3): ``skew(v) @ x == np.cross(v, x)``."""
    v = np.asarray(v, np.float64)
    K = np.zeros((*v.shape, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return K


def rodrigues(axes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations (..., 3, 3) by ``angles`` (...) radians about unit ``axes`` (..., 3), broadcast together."""
    axes, angles = np.broadcast_arrays(np.asarray(axes, np.float64), np.asarray(angles, np.float64)[..., None])
    K = skew(axes)
    s, c = np.sin(angles[..., :1])[..., None], np.cos(angles[..., :1])[..., None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def axis_permutations() -> np.ndarray:
    """The 24 rotations that map the coordinate axes onto one another (signed permutations, det +1),
    the identity first."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            M = np.zeros((3, 3))
            M[range(3), perm] = signs
            if np.linalg.det(M) > 0:
                out.append(M)
    out.sort(key=lambda M: -np.trace(M))  # the identity (trace 3) first
    return np.array(out)
