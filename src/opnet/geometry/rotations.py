"""Rotation matrices, unit quaternions and Euler angles, batched in torch, usable from numpy.

Conventions:
- A rotation matrix ``R`` maps object coordinates to camera/world coordinates: ``x' = R x``.
- Quaternions are ``(w, x, y, z)``, scalar first (the Siléane ``camera_params.txt`` convention).
- Euler angles are *intrinsic*; a convention string names the axes in order, e.g. ``"ZYZ"`` means
  ``R = Rz(a) @ Ry(b) @ Rz(c)``. The project default is Z-Y-Z (docs/method.md#orientation): the third angle then
  turns about the object's symmetry axis z.
"""

from __future__ import annotations

import math

import torch

from opnet.geometry._array import numpy_compatible

DEFAULT_EULER = "ZYZ"
_AXIS_INDEX = {"X": 0, "Y": 1, "Z": 2}
_GIMBAL_EPS = 1e-7


@numpy_compatible
def axis_angle_rotation(axis: str, angle: torch.Tensor) -> torch.Tensor:
    """Rotation about a coordinate axis.

    Args:
        axis: "X", "Y" or "Z".
        angle: (...) radians.
    Returns:
        (..., 3, 3) rotation matrices.
    """
    angle = torch.as_tensor(angle)
    if not angle.is_floating_point():
        angle = angle.double()
    c, s = torch.cos(angle), torch.sin(angle)
    one, zero = torch.ones_like(angle), torch.zeros_like(angle)
    if axis == "X":
        rows = (one, zero, zero, zero, c, -s, zero, s, c)
    elif axis == "Y":
        rows = (c, zero, s, zero, one, zero, -s, zero, c)
    elif axis == "Z":
        rows = (c, -s, zero, s, c, zero, zero, zero, one)
    else:
        raise ValueError(f"axis must be 'X', 'Y' or 'Z', got {axis!r}")
    return torch.stack(rows, dim=-1).reshape(angle.shape + (3, 3))


def _check_convention(convention: str) -> tuple[int, int, int]:
    conv = convention.upper()
    if len(conv) != 3 or any(a not in _AXIS_INDEX for a in conv) or conv[0] == conv[1] or conv[1] == conv[2]:
        raise ValueError(
            f"Euler convention must be three axes from XYZ with no axis repeated consecutively "
            f"(e.g. 'ZYZ', 'XYZ'), got {convention!r}"
        )
    return tuple(_AXIS_INDEX[a] for a in conv)  # type: ignore[return-value]


@numpy_compatible
def euler_to_matrix(angles: torch.Tensor, convention: str = DEFAULT_EULER) -> torch.Tensor:
    """Intrinsic Euler angles to rotation matrices.

    Args:
        angles: (..., 3) radians, in the order of ``convention``.
        convention: e.g. "ZYZ" (default) for ``Rz(a) Ry(b) Rz(c)``.
    Returns:
        (..., 3, 3).
    """
    _check_convention(convention)
    conv = convention.upper()
    mats = [axis_angle_rotation(conv[i], angles[..., i]) for i in range(3)]
    return mats[0] @ mats[1] @ mats[2]


@numpy_compatible
def matrix_to_euler(R: torch.Tensor, convention: str = DEFAULT_EULER) -> torch.Tensor:
    """Rotation matrices to intrinsic Euler angles.

    Ranges: first and third angle in (-pi, pi]; the middle angle in [0, pi] for proper Euler
    conventions (e.g. ZYZ) and [-pi/2, pi/2] for Tait-Bryan ones (e.g. XYZ). At gimbal lock the
    third angle is set to 0 and the whole turn is given to the first.

    Args:
        R: (..., 3, 3).
    Returns:
        (..., 3) radians.
    """
    i, j, k_or_i = _check_convention(convention)
    proper = i == k_or_i
    k = 3 - i - j  # the axis not among the first two
    # parity +1 when (i, j, k) is a cyclic permutation of (0, 1, 2)
    s = 1.0 if (j - i) % 3 == 1 else -1.0
    # the middle angle from atan2 of (sin, cos): acos/asin lose precision near gimbal lock
    if proper:
        sin_b = torch.hypot(R[..., i, j], R[..., i, k])
        b = torch.atan2(sin_b, R[..., i, i])
        a = torch.atan2(R[..., j, i], -s * R[..., k, i])
        c = torch.atan2(R[..., i, j], s * R[..., i, k])
    else:
        k = k_or_i
        sin_b = torch.hypot(R[..., i, i], R[..., i, j])  # cos(b): degenerate when it vanishes
        b = torch.atan2(s * R[..., i, k], sin_b)
        a = torch.atan2(-s * R[..., j, k], R[..., k, k])
        c = torch.atan2(-s * R[..., i, j], R[..., i, i])
    # Gimbal lock: with c = 0, R = R_i(a) R_j(b), so R e_j = R_i(a) e_j.
    locked = sin_b.abs() < _GIMBAL_EPS
    if bool(locked.any()):
        a_locked = torch.atan2(s * R[..., k, j], R[..., j, j])
        a = torch.where(locked, a_locked, a)
        c = torch.where(locked, torch.zeros_like(c), c)
    return torch.stack((a, b, c), dim=-1)


@numpy_compatible
def quaternion_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """Unit quaternions (w, x, y, z) to rotation matrices; the input is normalized first.

    Args:
        q: (..., 4).
    Returns:
        (..., 3, 3).
    """
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    entries = (
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    )  # fmt: skip
    return torch.stack(entries, dim=-1).reshape(q.shape[:-1] + (3, 3))


@numpy_compatible
def matrix_to_quaternion(R: torch.Tensor) -> torch.Tensor:
    """Rotation matrices to unit quaternions (w, x, y, z) with w >= 0.

    Uses the numerically best of the four Shepperd candidates per matrix.

    Args:
        R: (..., 3, 3).
    Returns:
        (..., 4).
    """
    m = R
    tr = m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]
    # four candidates, each stable where its leading term is large: (..., 4 candidates, 4 comps)
    cand = torch.stack(
        (
            torch.stack((1 + tr, m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]), -1),
            torch.stack((m[..., 2, 1] - m[..., 1, 2], 1 + 2 * m[..., 0, 0] - tr, m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0]), -1),
            torch.stack((m[..., 0, 2] - m[..., 2, 0], m[..., 0, 1] + m[..., 1, 0], 1 + 2 * m[..., 1, 1] - tr, m[..., 1, 2] + m[..., 2, 1]), -1),
            torch.stack((m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0], m[..., 1, 2] + m[..., 2, 1], 1 + 2 * m[..., 2, 2] - tr), -1),
        ),
        dim=-2,
    )  # fmt: skip
    lead = torch.stack((1 + tr, 1 + 2 * m[..., 0, 0] - tr, 1 + 2 * m[..., 1, 1] - tr, 1 + 2 * m[..., 2, 2] - tr), -1)
    best = lead.argmax(dim=-1, keepdim=True)  # (..., 1)
    q = torch.gather(cand, -2, best.unsqueeze(-1).expand(best.shape[:-1] + (1, 4))).squeeze(-2)
    q = q / q.norm(dim=-1, keepdim=True)
    return torch.where(q[..., :1] < 0, -q, q)


@numpy_compatible
def euler_to_quaternion(angles: torch.Tensor, convention: str = DEFAULT_EULER) -> torch.Tensor:
    """Intrinsic Euler angles (..., 3) to quaternions (..., 4), (w, x, y, z)."""
    return matrix_to_quaternion(euler_to_matrix(angles, convention))


@numpy_compatible
def quaternion_to_euler(q: torch.Tensor, convention: str = DEFAULT_EULER) -> torch.Tensor:
    """Quaternions (..., 4), (w, x, y, z), to intrinsic Euler angles (..., 3)."""
    return matrix_to_euler(quaternion_to_matrix(q), convention)


@numpy_compatible
def orthonormality_error(R: torch.Tensor) -> torch.Tensor:
    """Max |R^T R - I| per matrix plus |det R - 1|: (..., 3, 3) -> (...)."""
    eye = torch.eye(3, dtype=R.dtype, device=R.device)
    err = (R.transpose(-1, -2) @ R - eye).abs().amax(dim=(-1, -2))
    return err + (torch.linalg.det(R) - 1).abs()


@numpy_compatible
def project_to_so3(R: torch.Tensor) -> torch.Tensor:
    """Nearest rotation matrix (Frobenius norm) via SVD: (..., 3, 3) -> (..., 3, 3)."""
    U, _, Vh = torch.linalg.svd(R)
    d = torch.sign(torch.linalg.det(U @ Vh))
    D = torch.diag_embed(torch.stack((torch.ones_like(d), torch.ones_like(d), d), -1))
    return U @ D @ Vh


@numpy_compatible
def rotation_angle(R: torch.Tensor) -> torch.Tensor:
    """Angle (radians, [0, pi]) of rotation matrices: (..., 3, 3) -> (...)."""
    tr = R[..., 0, 0] + R[..., 1, 1] + R[..., 2, 2]
    return torch.acos(((tr - 1) / 2).clamp(-1.0, 1.0))


@numpy_compatible
def rotation_from_6d(z_raw: torch.Tensor, x_raw: torch.Tensor) -> torch.Tensor:
    """Rotation from two unnormalized 3-vectors by Gram-Schmidt (Zhou et al., CVPR 2019).

    The z column comes first (it is exact: ``z = z_raw / |z_raw|``), so that the symmetry axis of
    a symmetric object (its model z-axis, docs/data.md#objects) never depends on the x column. Continuous
    and differentiable wherever ``z_raw`` and ``x_raw`` are not parallel.

    Args:
        z_raw, x_raw: (..., 3) unnormalized third and first columns.
    Returns:
        (..., 3, 3) proper rotations ``[x, z × x, z]``.
    """
    eps = torch.finfo(z_raw.dtype).eps
    z = z_raw / z_raw.norm(dim=-1, keepdim=True).clamp_min(eps)
    x = x_raw - (x_raw * z).sum(-1, keepdim=True) * z
    x = x / x.norm(dim=-1, keepdim=True).clamp_min(eps)
    y = torch.linalg.cross(z, x, dim=-1)
    return torch.stack((x, y, z), dim=-1)


@numpy_compatible
def rotation_from_axis(axis: torch.Tensor) -> torch.Tensor:
    """The spin-free rotation ``Rz(a) Ry(b)`` whose z column is the normalized ``axis``.

    The representative of a revolution object's pose with the third Z-Y-Z angle 0 (what the
    parameterizations decode). Finite gradients everywhere (the z column is the normalized axis;
    along the optical axis, where ``a`` is undefined, ``a = 0``).

    Args:
        axis: (..., 3) unnormalized axis.
    Returns:
        (..., 3, 3) proper rotations.
    """
    eps = torch.finfo(axis.dtype).eps
    z = axis / axis.norm(dim=-1, keepdim=True).clamp_min(eps)
    rho2 = z[..., 0] ** 2 + z[..., 1] ** 2
    on_axis = rho2 < eps**2
    rho = torch.sqrt(rho2.clamp_min(eps**2))
    cos_a = torch.where(on_axis, torch.ones_like(rho), z[..., 0] / rho)
    sin_a = torch.where(on_axis, torch.zeros_like(rho), z[..., 1] / rho)
    sin_b = torch.where(on_axis, torch.zeros_like(rho), rho)
    cos_b = z[..., 2]
    x = torch.stack((cos_b * cos_a, cos_b * sin_a, -sin_b), -1)
    y = torch.stack((-sin_a, cos_a, torch.zeros_like(sin_a)), -1)
    return torch.stack((x, y, z), dim=-1)


def wrap_angle(angle: torch.Tensor, period: float = 2 * math.pi) -> torch.Tensor:
    """Map angles to [0, period)."""
    return torch.remainder(angle, period)
