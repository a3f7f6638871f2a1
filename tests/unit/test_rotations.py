"""Rotations and Euler conventions against scipy (an external reference)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from opnet.geometry import rotations as rot

CONVENTIONS = ["ZYZ", "ZXZ", "XYX", "XZX", "YXY", "YZY", "XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX"]


@pytest.fixture(scope="module")
def random_rotations() -> Rotation:
    return Rotation.random(500, random_state=1)


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_euler_matches_scipy(random_rotations: Rotation, convention: str) -> None:
    R = random_rotations.as_matrix()
    ours = rot.matrix_to_euler(R, convention)
    ref = random_rotations.as_euler(convention)  # scipy: uppercase = intrinsic
    np.testing.assert_allclose(np.angle(np.exp(1j * (ours - ref))), 0, atol=1e-9)
    np.testing.assert_allclose(rot.euler_to_matrix(ours, convention), R, atol=1e-12)
    np.testing.assert_allclose(Rotation.from_euler(convention, ours).as_matrix(), R, atol=1e-12)


def test_zyz_is_rz_ry_rz() -> None:
    a, b, c = 0.3, 1.1, -2.0
    expected = rot.axis_angle_rotation("Z", np.array(a)) @ rot.axis_angle_rotation("Y", np.array(b)) @ rot.axis_angle_rotation("Z", np.array(c))
    np.testing.assert_allclose(rot.euler_to_matrix(np.array([a, b, c])), expected, atol=1e-15)
    assert rot.DEFAULT_EULER == "ZYZ"


@pytest.mark.parametrize("convention", ["ZYZ", "XYZ", "ZYX"])
@pytest.mark.parametrize("middle", [0.0, np.pi, np.pi / 2, -np.pi / 2])
def test_gimbal_lock_round_trip(convention: str, middle: float) -> None:
    angles = np.array([0.7, middle, -0.4])
    R = rot.euler_to_matrix(angles, convention)
    back = rot.matrix_to_euler(R, convention)
    assert np.all(np.isfinite(back))
    np.testing.assert_allclose(rot.euler_to_matrix(back, convention), R, atol=1e-12)


def test_quaternions_match_scipy(random_rotations: Rotation) -> None:
    R = random_rotations.as_matrix()
    q = rot.matrix_to_quaternion(R)
    ref = random_rotations.as_quat(scalar_first=True)
    ref = ref * np.sign(ref[:, :1])
    np.testing.assert_allclose(q, ref, atol=1e-12)
    np.testing.assert_allclose(rot.quaternion_to_matrix(q), R, atol=1e-12)
    assert np.all(q[:, 0] >= 0)


def test_quaternion_near_180_degrees_is_stable() -> None:
    R = Rotation.from_rotvec([[np.pi - 1e-9, 0, 0], [0, 0, np.pi]]).as_matrix()
    np.testing.assert_allclose(rot.quaternion_to_matrix(rot.matrix_to_quaternion(R)), R, atol=1e-9)


def test_torch_batched_and_differentiable() -> None:
    angles = torch.rand(4, 5, 3, dtype=torch.float64, requires_grad=True)
    R = rot.euler_to_matrix(angles)
    assert R.shape == (4, 5, 3, 3)
    R.sum().backward()
    assert angles.grad is not None and torch.isfinite(angles.grad).all()
    np.testing.assert_allclose(rot.orthonormality_error(R.detach()).max().item(), 0, atol=1e-12)


def test_numpy_in_numpy_out_float_dtype() -> None:
    out = rot.euler_to_matrix(np.zeros(3))
    assert isinstance(out, np.ndarray) and out.dtype == np.float64


def test_project_to_so3_and_angle() -> None:
    R = Rotation.random(10, random_state=3).as_matrix()
    noisy = R + 1e-3 * np.random.default_rng(0).standard_normal(R.shape)
    P = rot.project_to_so3(noisy)
    assert rot.orthonormality_error(P).max() < 1e-12
    np.testing.assert_allclose(rot.rotation_angle(P.transpose(0, 2, 1) @ R), 0, atol=5e-3)
    np.testing.assert_allclose(rot.rotation_angle(rot.axis_angle_rotation("X", np.array(0.5))), 0.5)


def test_bad_convention_is_refused() -> None:
    with pytest.raises(ValueError, match="Euler convention"):
        rot.euler_to_matrix(np.zeros(3), "ZZY")
