"""Orientation codecs: the continuous 6-D representation and the Gram-Schmidt / axis helpers."""

from __future__ import annotations

import math

import hydra.utils
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from omegaconf import OmegaConf

from opnet.geometry import Symmetry, axis_angle_rotation, orthonormality_error, quaternion_to_matrix
from opnet.geometry.rotations import rotation_from_6d, rotation_from_axis
from opnet.parameterizations.rotation import SixDCodec, canonical_equivalent
from opnet.paths import config_dir

SYMMETRIES = {
    "none": Symmetry("none"),
    "cyclic2": Symmetry("cyclic", order=2),
    "cyclic5": Symmetry("cyclic", order=5),
    "revolution": Symmetry("revolution"),
    "revolution_flip": Symmetry("revolution", rotoreflection=True),
}


def rotations(n: int, seed: int) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return quaternion_to_matrix(torch.randn(n, 4, generator=gen, dtype=torch.float64))


def test_gram_schmidt_recovers_rotations_from_scaled_and_skewed_columns():
    R = rotations(200, 0)
    z_raw = 2.5 * R[..., 2]
    x_raw = 0.3 * R[..., 0] + 0.9 * R[..., 2]  # not orthogonal to z: Gram-Schmidt removes it
    torch.testing.assert_close(rotation_from_6d(z_raw, x_raw), R, atol=1e-12, rtol=0)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.lists(st.floats(-1, 1, allow_nan=False), min_size=6, max_size=6))
def test_any_6d_vector_decodes_to_a_proper_rotation(values):
    v = torch.tensor(values, dtype=torch.float64)
    if v[:3].norm() < 1e-3 or torch.linalg.cross(v[:3], v[3:]).norm() < 1e-3:
        return  # (near) degenerate input: no direction to normalize
    R = rotation_from_6d(v[:3], v[3:])
    assert orthonormality_error(R).item() < 1e-12


def test_axis_rotation_has_the_axis_as_z_column_and_finite_gradients():
    R = rotations(100, 1)
    axes = torch.cat((R[..., 2], torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]], dtype=torch.float64)))
    axes.requires_grad_(True)
    Ra = rotation_from_axis(3.0 * axes)
    torch.testing.assert_close(Ra[..., 2], axes.detach(), atol=1e-12, rtol=0)
    assert orthonormality_error(Ra.detach()).max() < 1e-12
    Ra.sum().backward()
    assert torch.isfinite(axes.grad).all()


@pytest.mark.parametrize("name", sorted(SYMMETRIES))
def test_r6d_round_trip_up_to_symmetry_and_identical_channels_for_equivalents(name: str):
    sym = SYMMETRIES[name]
    codec = SixDCodec(sym)
    assert codec.num_channels == (3 if sym.is_revolution else 6)
    R = rotations(300, 2)
    channels = codec.encode(R)
    assert channels.shape == (300, codec.num_channels)
    assert channels.min() >= 0 and channels.max() <= 1
    decoded = codec.decode(channels)
    assert orthonormality_error(decoded).max() < 1e-12
    G = torch.as_tensor(sym.group())
    if sym.is_revolution:  # the axis, up to the flip
        cos = (decoded[..., 2] * R[..., 2]).sum(-1)
        expected = cos.abs() if sym.rotoreflection else cos
        torch.testing.assert_close(expected, torch.ones_like(cos), atol=1e-12, rtol=0)
        spin = axis_angle_rotation("Z", torch.linspace(0, 6, 300, dtype=torch.float64))
        equivalent = R @ spin @ G[torch.arange(300) % len(G)]
    else:  # one of the symmetric equivalents, exactly
        err = (decoded[:, None] - R[:, None] @ G[None]).abs().amax((-1, -2)).amin(-1)
        assert err.max() < 1e-12
        equivalent = R @ G[torch.arange(300) % len(G)]
    torch.testing.assert_close(codec.encode(equivalent), channels, atol=1e-9, rtol=0)


def test_canonical_equivalent_is_a_group_member_and_idempotent():
    G = torch.as_tensor(Symmetry("cyclic", order=4).group())
    R = rotations(50, 3)
    C = canonical_equivalent(R, G)
    rel = R.transpose(-1, -2) @ C  # must be in G
    assert ((rel[:, None] - G[None]).abs().amax((-1, -2)).amin(-1) < 1e-12).all()
    torch.testing.assert_close(canonical_equivalent(C, G), C)


def test_rotation_configs_build_codecs_with_the_object_symmetry():
    names = sorted(p.stem for p in (config_dir() / "rotation").glob("*.yaml"))
    assert {"euler_zyz", "r6d"} <= set(names)
    for name in names:
        make = hydra.utils.instantiate(OmegaConf.load(config_dir() / "rotation" / f"{name}.yaml"), _partial_=True)
        codec = make(symmetry=Symmetry("none"))
        # r6d_spin: a part without a cyclic group keeps the 6-D codec
        assert codec.name == ("r6d" if name == "r6d_spin" else name)
        R = rotations(20, 4)
        back = codec.decode(codec.encode(R))
        np.testing.assert_allclose(back.numpy(), R.numpy(), atol=1e-6)
    assert math.isclose(float(SixDCodec(Symmetry("none")).encode(torch.eye(3)[None].double())[0, 2]), 1.0)
