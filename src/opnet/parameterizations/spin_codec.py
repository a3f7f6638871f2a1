"""Orientation channels without a seam for a part with a cyclic symmetry (``rotation=r6d_spin``).

The 6-D channels (:class:`opnet.parameterizations.rotation.SixDCodec`) hold the part's axis and one
more column of its rotation; for a part that a turn of 360°/N about an axis maps onto itself
(cyclic order N: a wheel with five spokes, a sprocket, a plate turned over about its stem) the loss
takes the nearest of the N equivalent columns. Yet no continuous function of the image can hand out
one of N columns: as the part turns by 360°/N its image comes back, its column does not, so
somewhere the network's answer must jump by 360°/N, and near that seam it averages two answers
into a wrong one.

Here the turn about the symmetry axis is written as the angle's N-th harmonic instead:
``[axis (3), cos Nθ, sin Nθ]``, ``θ`` the turn of a column perpendicular to the axis measured from
a reference direction in the camera frame (:data:`SPIN_REFERENCE`, almost the image's x axis,
projected onto the plane perpendicular to the axis). All N equivalents give the same five channels
and every turn about the axis gives different ones: one answer per pose, no seam wherever the axis
points except at the two directions along the reference (a part lying side-on with its axis along
the image's x axis, where its turn is seldom seen; there the reference is undefined). The
harmonic's circle has radius ``1/N`` of the channels' half range by default, so that a channel
error buys the same turn as in the 6-D channels (their column turns by the error, the harmonic by N
times it).

A part with no symmetry, a revolution part, or a finite group that is not cyclic about one axis
keeps the 6-D codec (:func:`spin_harmonic_codec`): its channels and training are those of
``rotation=r6d``.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from opnet.geometry.symmetry import Symmetry
from opnet.parameterizations.rotation import RotationCodec, SixDCodec

#: the direction in the camera frame from which the turn about a part's axis is measured (almost the
#: image's x axis; generic, so that the reference is undefined only for axes along it)
SPIN_REFERENCE = (1.0, 0.0234, 0.0147)
_FALLBACK_REFERENCE = (0.0147, 1.0, 0.0234)


def cyclic_axis(group: np.ndarray, tol: float = 1e-6) -> tuple[int, np.ndarray] | None:
    """The order N and unit axis of a group (K, 3, 3) of turns about one axis, or None.

    None for the trivial group and for a group whose turns do not share one axis (e.g. a
    dihedral one). The axis's sign is that of the turn by ``+360°/N`` (its right-hand axis).
    """
    G = np.asarray(group, dtype=np.float64)
    others = [g for g in G if np.abs(g - np.eye(3)).max() > tol]
    if not others:
        return None
    axes = []
    for g in others:
        w = np.array([g[2, 1] - g[1, 2], g[0, 2] - g[2, 0], g[1, 0] - g[0, 1]])
        if np.linalg.norm(w) < 1e-9:  # a half turn: its axis from the symmetric part g + I
            m = g + np.eye(3)
            w = m[:, int(np.argmax(np.linalg.norm(m, axis=0)))]
        axes.append(w / np.linalg.norm(w))
    a = axes[0]
    if any(abs(abs(float(b @ a)) - 1.0) > 1e-6 for b in axes[1:]):
        return None
    order = len(G)
    # the turn by +360/N about a (right-handed) must be in the group, else the group is not cyclic about a
    c, s = math.cos(2 * math.pi / order), math.sin(2 * math.pi / order)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    turn = np.eye(3) + s * K + (1 - c) * (K @ K)
    if min(np.abs(g - turn).max() for g in G) > 1e-5:
        return None
    return order, a


def _frame(axis: np.ndarray) -> np.ndarray:
    """A rotation F (model frame) whose z column is ``axis`` (its x column a generic perpendicular)."""
    a = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    b = helper - (helper @ a) * a
    b /= np.linalg.norm(b)
    return np.stack((b, np.cross(a, b), a), axis=1)


class SpinHarmonicCodec(RotationCodec):
    """The symmetry axis and the N-th harmonic of the turn about it: 5 channels in [0, 1].

    Args:
        symmetry: the part's symmetry; its group must be cyclic about one axis (order N >= 2).
        spin_radius: the harmonic's radius in the channels' half range (``0.5 + 0.5 r (cos, sin)``);
            None: ``1/N`` (a channel error turns the part as much as in the 6-D channels).
    Raises:
        ValueError: the group is not cyclic about one axis, or ``spin_radius`` is not in (0, 1].
    """

    def __init__(self, symmetry: Symmetry, spin_radius: float | None = None) -> None:
        found = cyclic_axis(symmetry.group()) if not symmetry.is_revolution else None
        if found is None:
            raise ValueError("the spin-harmonic channels need a cyclic symmetry about one axis, "
                             f"got {symmetry.to_spec()}")
        self.order, axis = found
        if spin_radius is not None and not 0.0 < float(spin_radius) <= 1.0:
            raise ValueError(f"rotation.spin_radius must lie in (0, 1], got {spin_radius!r}")
        self.radius = 1.0 / self.order if spin_radius is None else float(spin_radius)
        self.name = "r6d_spin"
        self.revolution = False
        self.num_channels = 5
        self.channel_names = ("axis_x", "axis_y", "axis_z", "spin_cos", "spin_sin")
        self._F = torch.as_tensor(_frame(axis), dtype=torch.float64)  # model frame: the symmetry axis onto z

    def _reference(self, z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """The unit directions u, v = z x u (..., 3) perpendicular to the unit axes z (..., 3)."""
        out = []
        for ref in (SPIN_REFERENCE, _FALLBACK_REFERENCE):
            p = z.new_tensor(ref)
            p = p / p.norm()
            out.append(p - (z * p).sum(-1, keepdim=True) * z)
        u_main, u_fallback = out
        n_main = u_main.norm(dim=-1, keepdim=True)
        u = torch.where(n_main > 1e-9, u_main, u_fallback)
        u = u / u.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        return u, torch.linalg.cross(z, u, dim=-1)

    def encode(self, R: torch.Tensor) -> torch.Tensor:
        Rf = R.to(torch.float64) @ self._F.to(R.device)  # columns: the perpendicular, ..., the symmetry axis
        z, x = Rf[..., 2], Rf[..., 0]
        u, v = self._reference(z)
        theta = torch.atan2((x * v).sum(-1), (x * u).sum(-1))
        spin = torch.stack((torch.cos(self.order * theta), torch.sin(self.order * theta)), -1)
        return torch.cat((0.5 + 0.5 * z, 0.5 + 0.5 * self.radius * spin), -1).clamp(0.0, 1.0)

    def equivalent_channels(self, R: torch.Tensor, group: torch.Tensor) -> torch.Tensor:
        """Every symmetric equivalent has the same channels: (M, K, 5) of the encoded ``R``."""
        return self.encode(R).unsqueeze(1).expand(len(R), len(group), self.num_channels)

    def axis(self, channels: torch.Tensor) -> torch.Tensor:
        """The symmetry axis in the camera frame (..., 3), unnormalized, the channels hold."""
        return 2.0 * channels[..., :3] - 1.0

    def decode(self, channels: torch.Tensor) -> torch.Tensor:
        eps = torch.finfo(channels.dtype).eps
        z_raw = self.axis(channels)
        z = z_raw / z_raw.norm(dim=-1, keepdim=True).clamp_min(eps)
        h = 2.0 * channels[..., 3:5] - 1.0
        defined = h.norm(dim=-1) > eps
        safe = torch.where(defined[..., None], h, torch.ones_like(h))
        # the angle in float32 (1e-7 rad), which ONNX Runtime's Atan computes (it has no float64 kernel)
        angle = torch.atan2(safe[..., 1].float(), safe[..., 0].float()).to(h.dtype)
        phi = torch.where(defined, angle, torch.zeros_like(angle)) / self.order
        u, v = self._reference(z)
        x = torch.cos(phi)[..., None] * u + torch.sin(phi)[..., None] * v
        Rf = torch.stack((x, torch.linalg.cross(z, x, dim=-1), z), dim=-1)
        return Rf @ self._F.to(device=channels.device, dtype=channels.dtype).T


def spin_harmonic_codec(symmetry: Symmetry, spin_radius: float | None = None) -> RotationCodec:
    """The spin-harmonic codec for a part with a cyclic symmetry about one axis, the 6-D codec otherwise."""
    if symmetry.is_revolution or cyclic_axis(symmetry.group()) is None:
        return SixDCodec(symmetry)
    return SpinHarmonicCodec(symmetry, spin_radius)


__all__ = ["SPIN_REFERENCE", "SpinHarmonicCodec", "cyclic_axis", "spin_harmonic_codec"]
