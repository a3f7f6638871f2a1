"""Camera model and dataset frame conversions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from opnet.geometry import Camera, camera_to_ipa, camera_to_world, ipa_to_camera, world_to_camera


@pytest.fixture
def camera() -> Camera:
    return Camera(fx=600.0, fy=610.0, cx=250.3, cy=190.7, width=506, height=474, clip_start=0.8, clip_end=1.7)


def test_project_backproject_round_trip(camera: Camera) -> None:
    rng = np.random.default_rng(0)
    pts = np.c_[rng.uniform(-0.2, 0.2, (50, 2)), rng.uniform(0.9, 1.6, 50)]
    uv = camera.project(pts)
    np.testing.assert_allclose(camera.backproject(uv[:, 0], uv[:, 1], pts[:, 2]), pts, atol=1e-12)


def test_opencv_convention(camera: Camera) -> None:
    # a point right of and below the optical axis lands right of and below the principal point
    u, v = camera.project(np.array([0.1, 0.05, 1.0]))
    assert u == pytest.approx(250.3 + 60.0) and v == pytest.approx(190.7 + 30.5)


def test_resized_keeps_pixel_centres(camera: Camera) -> None:
    small = camera.resized(253, 237)
    pt = np.array([0.05, -0.03, 1.2])
    u, v = camera.project(pt)
    us, vs = small.project(pt)
    # pixel-centre aligned scaling: (u + 0.5) * s - 0.5
    assert us == pytest.approx((u + 0.5) * 0.5 - 0.5) and vs == pytest.approx((v + 0.5) * 0.5 - 0.5)


def test_cropped_shifts_principal_point(camera: Camera) -> None:
    crop = camera.cropped(10, -5, 300, 300)
    pt = np.array([0.05, -0.03, 1.2])
    np.testing.assert_allclose(crop.project(pt), camera.project(pt) - np.array([10, -5]))


def test_depth_normalization(camera: Camera) -> None:
    assert camera.normalize_depth(0.8) == 0 and camera.normalize_depth(1.7) == pytest.approx(1)
    assert camera.denormalize_depth(camera.normalize_depth(1.234)) == pytest.approx(1.234)


def test_invalid_camera_is_refused() -> None:
    with pytest.raises(ValueError, match="clip"):
        Camera(500, 500, 10, 10, 20, 20, clip_start=1.0, clip_end=0.5)
    with pytest.raises(ValueError, match="focal"):
        Camera(-1, 500, 10, 10, 20, 20, 0.5, 1.0)
    with pytest.raises(ValueError, match="finite"):
        Camera(float("nan"), 500, 10, 10, 20, 20, 0.5, 1.0)


def test_ipa_frame_negates_x_and_y() -> None:
    R = Rotation.random(random_state=2).as_matrix()
    t = np.array([0.1, -0.2, 1.0])
    R_ipa, t_ipa = camera_to_ipa(R, t)
    np.testing.assert_allclose(t_ipa, [-0.1, 0.2, 1.0])
    # a model point seen in both frames differs by the x/y flip
    p = np.array([0.01, 0.02, 0.03])
    np.testing.assert_allclose(R_ipa @ p + t_ipa, np.diag([-1, -1, 1]) @ (R @ p + t))
    R2, t2 = ipa_to_camera(R_ipa, t_ipa)
    np.testing.assert_allclose(R2, R) and np.testing.assert_allclose(t2, t)


def test_world_camera_round_trip() -> None:
    rng = np.random.default_rng(1)
    R_wc = Rotation.from_quat([1.0, 0, 0, 0], scalar_first=False).as_matrix()  # 180 deg about x
    t_wc = np.array([-0.1, 0.0, 1.5])
    R_w = Rotation.random(5, random_state=4).as_matrix()
    t_w = rng.uniform(-0.3, 0.3, (5, 3))
    R_c, t_c = world_to_camera(R_w, t_w, R_wc, t_wc)
    # camera looking down from 1.5 m: an object on the floor (z_w ~ 0) is ~1.5 m deep
    np.testing.assert_allclose(t_c[:, 2], 1.5 - t_w[:, 2])
    R_b, t_b = camera_to_world(R_c, t_c, R_wc, t_wc)
    np.testing.assert_allclose(R_b, R_w, atol=1e-12) and np.testing.assert_allclose(t_b, t_w, atol=1e-12)
