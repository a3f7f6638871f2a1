"""Bounded Euler-angle channels with symmetry canonicalization (docs/method.md#orientation, paper §Loss).

A rotation is written with intrinsic Euler angles ``R = R_i(φ1) R_j(φ2) R_z(φ3)`` (default Z-Y-Z)
and each angle is mapped linearly to ``[0, 1)``: ``φ1 / 2π``, ``φ2 / π`` (proper conventions, φ2 in
[0, π]; Tait-Bryan conventions map φ2 in [-π/2, π/2] by ``φ2 / π + 1/2``), ``(φ3 mod P) / P`` with
``P = 2π / k`` for a cyclic symmetry of order k about z. Objects with a revolution symmetry drop
φ3. Before encoding, the finite part of the symmetry group that moves the z-axis (the half-turn of
a rotoreflection, the flips of a dihedral group) is resolved by choosing the equivalent whose
z-axis points most along a fixed, generic camera direction, so symmetric equivalents of a pose
always give identical channels.
"""

from __future__ import annotations

import math

import torch

from opnet.geometry.rotations import euler_to_matrix, matrix_to_euler
from opnet.geometry.symmetry import Symmetry
from opnet.parameterizations.rotation import AXIS_PREFERENCE, RotationCodec
# |sin φ2| below this counts as gimbal lock (same tolerance as matrix_to_euler)
_GIMBAL_EPS = 1e-7


class EulerCodec(RotationCodec):
    """Rotation <-> normalized Euler channels of one object (the paper's orientation channels).

    Args:
        symmetry: the object's symmetry.
        convention: intrinsic Euler convention (``rotation.convention``), e.g. "ZYZ" (default,
            docs/method.md#orientation); the third axis must be Z for symmetric objects.

    Attributes:
        convention: e.g. "ZYZ".
        num_angles: 3, or 2 for revolution objects (φ3 dropped).
        period3: period of φ3 in radians (2π / k), None for revolution objects.
    """

    def __init__(self, symmetry: Symmetry, convention: str = "ZYZ") -> None:
        conv = str(convention).upper()
        try:
            euler_to_matrix(torch.zeros(3, dtype=torch.float64), conv)  # validates the string
        except ValueError as e:
            raise ValueError(f"rotation.convention: {e}") from None
        if symmetry.kind != "none" and conv[2] != "Z":
            raise ValueError(
                f"rotation.convention={convention!r} does not fit an object with {symmetry.kind} "
                "symmetry: its third axis must be Z (the symmetry axis), e.g. 'ZYZ' "
                "(or use rotation=r6d)"
            )
        self.name = f"euler_{conv.lower()}"
        self.convention = conv
        self.proper = conv[0] == conv[2]
        self.revolution = symmetry.is_revolution
        self.num_angles = 2 if self.revolution else 3
        self.num_channels = self.num_angles
        self.channel_names = ("phi1", "phi2", "phi3")[: self.num_angles]
        self.period3 = symmetry.euler3_period
        group = torch.as_tensor(symmetry.group(), dtype=torch.float64)  # (K, 3, 3)
        moves_axis = (
            group[:, :, 2] - torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
        ).abs().amax(-1) > 1e-9
        # only group elements that move the z-axis need an explicit choice; turns about z are
        # absorbed by φ3 mod P (or by dropping φ3)
        self._axis_group = group if bool(moves_axis.any()) else None

    def encode(self, R: torch.Tensor) -> torch.Tensor:
        """Rotations to normalized angle channels.

        Args:
            R: (M, 3, 3) rotation matrices, object -> camera.
        Returns:
            (M, num_angles) float64 in [0, 1].
        """
        R = self._choose_axis(R.to(torch.float64))
        angles = matrix_to_euler(R, self.convention)  # (M, 3)
        a, b, c = angles.unbind(-1)
        locked = (torch.sin(b) if self.proper else torch.cos(b)).abs() < _GIMBAL_EPS
        if self.revolution:  # at gimbal lock the axis does not depend on φ1 either
            a = torch.where(locked, torch.zeros_like(a), a)
        else:
            a, c = self._canonical_spin(a, b, c, locked)
        first = _unit_interval(a / (2 * math.pi))
        second = b / math.pi if self.proper else b / math.pi + 0.5
        if self.revolution:
            return torch.stack((first, second), -1)
        return torch.stack((first, second, _unit_interval(c / self.period3)), -1)

    def decode(self, channels: torch.Tensor) -> torch.Tensor:
        """Normalized angle channels to rotations (differentiable).

        Args:
            channels: (..., num_angles) in [0, 1].
        Returns:
            (..., 3, 3) rotation matrices (φ3 = 0 for revolution objects), dtype of ``channels``.
        """
        a = channels[..., 0] * (2 * math.pi)
        b = channels[..., 1] * math.pi
        if not self.proper:
            b = b - 0.5 * math.pi
        c = torch.zeros_like(a) if self.revolution else channels[..., 2] * self.period3
        return euler_to_matrix(torch.stack((a, b, c), -1), self.convention)

    def _choose_axis(self, R: torch.Tensor) -> torch.Tensor:
        if self._axis_group is None:
            return R
        G = self._axis_group.to(R.device)
        pref = torch.tensor(AXIS_PREFERENCE, dtype=R.dtype, device=R.device)
        axes = torch.einsum("mij,kj->mki", R, G[:, :, 2])  # (M, K, 3): R g e_z
        best = (axes @ pref).argmax(-1)  # (M,)
        return R @ G[best]

    def _canonical_spin(
        self, a: torch.Tensor, b: torch.Tensor, c: torch.Tensor, locked: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """φ3 mod P; at gimbal lock a proper convention only fixes φ1 ± φ3, reduced mod P into φ3.

        (Tait-Bryan conventions keep φ1 at gimbal lock: symmetric equivalents of such measure-zero
        poses may then encode differently.)
        """
        period = self.period3
        assert period is not None
        c_mod = torch.remainder(c, period)
        if not self.proper:
            return a, c_mod
        # at gimbal lock the whole turn goes to φ3 (φ1 = 0), whose channel wraps with period P:
        # b = 0: R = Rz(a + c) = Rz(0) Rz(a + c);  b = π: R = Rz(a - c) R_j(π) = R_j(π) Rz(c - a)
        spin = torch.where(b < 1.0, a + c, c - a)
        a_new = torch.where(locked, torch.zeros_like(a), a)
        c_new = torch.where(locked, torch.remainder(spin, period), c_mod)
        return a_new, c_new


def _unit_interval(x: torch.Tensor) -> torch.Tensor:
    """Wrap to [0, 1) (a remainder of a tiny negative number rounds to exactly 1)."""
    x = torch.remainder(x, 1.0)
    return torch.where(x >= 1.0, torch.zeros_like(x), x)
