"""The spin-harmonic orientation channels (rotation=r6d_spin): one answer per pose of a cyclic part, no seam where
the 6-D channels' nearest-of-N column must jump, the 6-D codec kept exactly for every other part, and train.py
training and reading back a network with them."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from opnet.geometry.symmetry import Symmetry, dihedral_group
from opnet.parameterizations.rotation import SixDCodec
from opnet.parameterizations.spin_codec import SpinHarmonicCodec, cyclic_axis, spin_harmonic_codec

C5 = Symmetry("cyclic", order=5)
#: a half turn about the model's x axis (a plate turned over about its stem)
C2_X = Symmetry("finite", rotations=[np.eye(3).tolist(), np.diag([1.0, -1.0, -1.0]).tolist()])


def _turn_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _random_rotations(n: int, seed: int = 0) -> torch.Tensor:
    return torch.as_tensor(Rotation.random(n, random_state=seed).as_matrix())


def test_the_axis_and_order_of_cyclic_groups_and_none_for_the_others() -> None:
    order, axis = cyclic_axis(C5.group())
    assert order == 5 and np.allclose(axis, [0, 0, 1])
    order, axis = cyclic_axis(C2_X.group())
    assert order == 2 and np.allclose(np.abs(axis), [1, 0, 0])
    tilted = Rotation.from_euler("xy", [30, 50], degrees=True).as_matrix()  # C3 about a tilted axis
    order, axis = cyclic_axis(tilted @ Symmetry("cyclic", order=3).group() @ tilted.T)
    assert order == 3 and np.allclose(axis, tilted[:, 2])
    assert cyclic_axis(np.eye(3)[None]) is None
    assert cyclic_axis(dihedral_group(4)) is None  # turns about two axes: not cyclic


@pytest.mark.parametrize("symmetry", [C5, C2_X], ids=["C5 about z", "C2 about x"])
def test_every_symmetric_equivalent_has_the_same_channels_and_they_decode_to_one_of_them(symmetry: Symmetry) -> None:
    codec = spin_harmonic_codec(symmetry)
    assert isinstance(codec, SpinHarmonicCodec) and codec.num_channels == 5
    R = _random_rotations(500)
    G = torch.as_tensor(symmetry.group())
    each = torch.stack([codec.encode(R @ g) for g in G], 1)
    assert torch.allclose(each, each[:, :1].expand_as(each), atol=1e-9)
    assert torch.allclose(codec.equivalent_channels(R, G), each, atol=1e-9)
    ch = codec.encode(R)
    assert ch.min() >= 0 and ch.max() <= 1
    decoded = codec.decode(ch)
    nearest = (decoded[:, None] - R[:, None] @ G).flatten(2).norm(dim=-1).amin(1)
    assert nearest.max() < 1e-6  # the angle is read in float32
    assert torch.allclose(decoded.transpose(-1, -2) @ decoded, torch.eye(3, dtype=decoded.dtype).expand_as(decoded),
                          atol=1e-12)
    assert torch.allclose(torch.linalg.det(decoded), torch.ones(len(R), dtype=decoded.dtype))


def test_a_wheel_turning_once_round_has_channels_without_a_jump_where_the_six_d_targets_jump() -> None:
    """Seen end-on and turned through a full circle in small steps, the 6-D codec's target (its canonical column)
    jumps by a fifth of a turn somewhere; the harmonic's channels move by at most what the step moves them."""
    tilt = Rotation.from_euler("x", 20, degrees=True).as_matrix()
    steps = np.radians(np.arange(0.0, 360.0, 0.5))
    R = torch.as_tensor(np.stack([tilt @ _turn_z(a) for a in steps]))
    harmonic = spin_harmonic_codec(C5).encode(R)
    six_d = SixDCodec(C5).encode(R)
    h_step = (harmonic.diff(dim=0)).norm(dim=-1).max().item()
    six_step = (six_d.diff(dim=0)).norm(dim=-1).max().item()
    assert h_step < 0.01  # 0.5 degree: 2.5 degrees of the 5th harmonic on a circle of radius 0.1
    assert six_step > 0.2  # the canonical column's jump by 72 degrees


def test_a_channel_error_turns_the_part_as_far_as_in_the_six_d_channels() -> None:
    """The harmonic's radius 1/N: a small error e across the circle turns the decoded part by about 2e, as an error e
    across the 6-D x column does."""
    codec = spin_harmonic_codec(C5)
    R = torch.as_tensor(Rotation.from_euler("x", 10, degrees=True).as_matrix())[None]
    ch = codec.encode(R)
    spin = 2 * ch[0, 3:5] - 1
    tangent = torch.stack((-spin[1], spin[0])) / spin.norm()
    e = 1e-4
    moved = ch.clone()
    moved[0, 3:5] += e * tangent
    turned = codec.decode(moved)[0] @ codec.decode(ch)[0].T
    angle = math.acos(max(-1.0, min(1.0, (float(torch.trace(turned)) - 1) / 2)))
    assert angle == pytest.approx(2 * e, rel=0.02)
    assert SpinHarmonicCodec(C5, spin_radius=1.0).radius == 1.0


@pytest.mark.parametrize("symmetry", [Symmetry("none"), Symmetry("revolution"), Symmetry("cyclic", order=2)],
                         ids=["none", "revolution", "C2"])
def test_parts_without_a_cyclic_group_keep_the_six_d_codec(symmetry: Symmetry) -> None:
    codec = spin_harmonic_codec(symmetry)
    assert isinstance(codec, SixDCodec if symmetry.kind != "cyclic" else SpinHarmonicCodec)
    with pytest.raises(ValueError, match="cyclic symmetry about one axis"):
        SpinHarmonicCodec(Symmetry("none"))
    with pytest.raises(ValueError, match="spin_radius"):
        SpinHarmonicCodec(C5, spin_radius=0.0)


def test_train_py_trains_and_reads_back_a_network_with_the_harmonic(tiny_dataset: Path, tmp_path: Path) -> None:
    """A cyclic part (the built-in zbracket, C2 about z) trains with rotation=r6d_spin; its checkpoint rebuilds the
    codec, with the network's five orientation channels, the test split is scored and the ONNX export decodes
    through it."""
    from opnet.cli import train as train_cli
    from opnet.cli.build import load_checkpoint

    from conftest import tiny_train_cfg

    out = tmp_path / "run"
    result = train_cli.run(tiny_train_cfg(tiny_dataset, out, [
        "parameterization=eve", "rotation=r6d_spin", "trainer.precision=32"]))
    system, _ = load_checkpoint(result["checkpoint"])
    codec = system.parameterization.rotation
    assert isinstance(codec, SpinHarmonicCodec) and codec.order == 2
    assert system.parameterization.channel_layout()[-5:] == list(codec.channel_names)
    assert result["parameterization"] and 0.0 <= result["ap"] <= 1.0 and result["num_scenes"] > 0
    # the ONNX export carries the decoding: ONNX Runtime reads the angle as PyTorch does (its Atan is float32 only)
    from omegaconf import OmegaConf

    from opnet.cli import export as export_cli

    meta = export_cli.run(OmegaConf.create({"format": "onnx", "ckpt": result["checkpoint"],
                                            "out": str(tmp_path / "spin.onnx"), "check": True}))
    assert meta["rotation"] == "r6d_spin" and meta["max_abs_difference"]["rotation"] < 1e-4
