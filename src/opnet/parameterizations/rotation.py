"""Orientation channels: the protocol, and the continuous 6-D representation (conf/rotation/).

Every parameterization writes an object's rotation into ``num_channels`` channels in [0, 1] with
a :class:`RotationCodec` and reads it back. Two families exist:

- :class:`opnet.parameterizations.euler_codec.EulerCodec`: the paper's bounded Euler angles
  (``rotation=euler_zyz``, the default of ``loss=paper``; other conventions selectable).
- :class:`SixDCodec`: the continuous representation of Zhou et al. (CVPR 2019, "On the Continuity
  of Rotation Representations in Neural Networks"): two columns of the rotation matrix, turned
  into a rotation by Gram-Schmidt. Euler angles (like every 3-D representation) have
  discontinuities: the wrap of φ1 and φ3 at 2π and the gimbal lock at φ2 = 0, π, where poses a
  hair apart have targets half the channel range apart and an L2 regression averages them into a
  pose far from both. The 6-D representation has none. Its loss is symmetry-aware
  (``loss.orientation=sym_rotation``: the Brégier rotation term minimised over the symmetry group),
  so the symmetric equivalents of a pose need no canonical choice either. This goes beyond the
  paper, which names other orientation parameterizations as future work.

For objects with a revolution symmetry only the axis is defined: :class:`SixDCodec` then writes the
axis alone (3 channels) and decodes the spin-free representative ``Rz(a) Ry(b)``, the same one the
Euler codec decodes with φ3 dropped.
"""

from __future__ import annotations

import abc

import torch

from opnet.geometry.rotations import rotation_from_6d, rotation_from_axis
from opnet.geometry.symmetry import Symmetry

# generic directions used to pick one of several symmetric equivalents for the channel targets
# (z: almost the camera's viewing axis; x: almost the image's x axis)
AXIS_PREFERENCE = (0.0123, 0.0321, 1.0)
_X_PREFERENCE = (1.0, 0.0234, 0.0147)


class RotationCodec(abc.ABC):
    """Rotation <-> orientation channels in [0, 1] of one object.

    Attributes:
        name: the config name (e.g. "euler_zyz", "r6d").
        num_channels: orientation channels per cell and slot.
        channel_names: their names (for channel layouts and logs).
        revolution: the object has a revolution symmetry (only its axis is encoded).
    """

    name: str
    num_channels: int
    channel_names: tuple[str, ...]
    revolution: bool

    @abc.abstractmethod
    def encode(self, R: torch.Tensor) -> torch.Tensor:
        """Rotations (M, 3, 3), object -> camera, to (M, num_channels) float64 in [0, 1]."""

    @abc.abstractmethod
    def decode(self, channels: torch.Tensor) -> torch.Tensor:
        """Channels (..., num_channels) to proper rotations (..., 3, 3) (differentiable)."""

    def equivalent_channels(self, R: torch.Tensor, group: torch.Tensor) -> torch.Tensor:
        """The channels of every symmetric equivalent ``R g`` (for a loss minimised over them).

        Args:
            R: (M, 3, 3) rotations. group: (K, 3, 3) the object's finite symmetry group.
        Returns:
            (M, K, num_channels). This default encodes each equivalent (a codec that
            canonicalizes then returns K equal rows).
        """
        cand = R.unsqueeze(1) @ group.to(R)  # (M, K, 3, 3)
        return self.encode(cand.reshape(-1, 3, 3)).reshape(len(R), len(group), -1)


def canonical_equivalent(R: torch.Tensor, group: torch.Tensor, by_x: bool = True) -> torch.Tensor:
    """One symmetric equivalent ``R g`` per rotation, chosen by fixed generic preferences.

    The equivalent whose z-axis points most along :data:`AXIS_PREFERENCE` wins; among equivalents
    with the same z-axis (turns about z) the one whose x-axis points most along a generic image
    direction (``by_x``). Deterministic, so symmetric equivalents get identical channels; the
    choice has seams (unavoidable for any canonical choice), which is why the 6-D codec's loss is
    the minimum over the group instead.

    Args:
        R: (M, 3, 3) rotations. group: (K, 3, 3) the object's finite symmetry group.
    Returns:
        (M, 3, 3).
    """
    if len(group) == 1:
        return R
    G = group.to(R)
    cand = R.unsqueeze(1) @ G  # (M, K, 3, 3)
    pref_z = torch.tensor(AXIS_PREFERENCE, dtype=R.dtype, device=R.device)
    score = torch.round(cand[..., 2] @ pref_z, decimals=9)
    if by_x:
        pref_x = torch.tensor(_X_PREFERENCE, dtype=R.dtype, device=R.device)
        score = score + 1e-6 * (cand[..., 0] @ pref_x)
    best = score.argmax(-1)
    return cand[torch.arange(len(R), device=R.device), best]


class SixDCodec(RotationCodec):
    """Continuous 6-D orientation channels (Zhou et al. 2019): the z and x columns of R.

    Channels ``0.5 + 0.5 [R e_z, R e_x]`` (6), or ``0.5 + 0.5 R e_z`` (3) for revolution objects.
    Decoding maps them back to [-1, 1] and orthonormalizes (z first, exact). Equivalents under the
    finite symmetry group are canonicalized for the targets (:func:`canonical_equivalent`); the
    symmetry-aware loss does not depend on that choice.

    Args:
        symmetry: the object's symmetry.
    """

    def __init__(self, symmetry: Symmetry) -> None:
        self.name = "r6d"
        self.revolution = symmetry.is_revolution
        self.num_channels = 3 if self.revolution else 6
        self.channel_names = (
            ("axis_x", "axis_y", "axis_z")
            if self.revolution
            else ("rz_x", "rz_y", "rz_z", "rx_x", "rx_y", "rx_z")
        )
        self._group = torch.as_tensor(symmetry.group(), dtype=torch.float64)

    def _channels(self, R: torch.Tensor) -> torch.Tensor:
        """``0.5 + 0.5`` times the z column (and the x column) of ``R`` as it is."""
        cols = R[..., 2] if self.revolution else torch.cat((R[..., 2], R[..., 0]), -1)
        return 0.5 + 0.5 * cols

    def encode(self, R: torch.Tensor) -> torch.Tensor:
        R = canonical_equivalent(R.to(torch.float64), self._group, by_x=not self.revolution)
        return self._channels(R).clamp(0.0, 1.0)

    def equivalent_channels(self, R: torch.Tensor, group: torch.Tensor) -> torch.Tensor:
        """Channels of every ``R g`` as they are (no canonical choice): (M, K, num_channels)."""
        return self._channels(R.to(torch.float64).unsqueeze(1) @ group.to(device=R.device, dtype=torch.float64))

    def axis(self, channels: torch.Tensor) -> torch.Tensor:
        """The z column (..., 3) the channels (..., num_channels) hold: the part's axis in the camera frame."""
        return 2.0 * channels[..., :3] - 1.0

    def with_spin_of(self, channels: torch.Tensor, other: torch.Tensor) -> torch.Tensor:
        """``channels`` (..., 6) with their x column replaced by ``other``'s (channels broadcastable to them) made
        perpendicular to their z column and of unit length: the same axis, turned about it to the spin ``other``
        has (their own x column where ``other``'s lies along the axis)."""
        z, x = self.axis(channels), 2.0 * channels[..., 3:6] - 1.0
        x_other = (2.0 * other[..., 3:6] - 1.0).expand_as(z)
        x_free = x_other - (x_other * z).sum(-1, keepdim=True) * z
        norm = x_free.norm(dim=-1, keepdim=True)
        x_free = torch.where(norm > 1e-6, x_free / norm.clamp_min(1e-6), x)
        return torch.cat((channels[..., :3], 0.5 + 0.5 * x_free), -1)

    def decode(self, channels: torch.Tensor) -> torch.Tensor:
        v = 2.0 * channels - 1.0
        if self.revolution:
            return rotation_from_axis(v[..., :3])
        return rotation_from_6d(v[..., :3], v[..., 3:6])


__all__ = ["AXIS_PREFERENCE", "RotationCodec", "SixDCodec", "canonical_equivalent"]
