"""The in-plane rotation augmentation is exact: the turned record is what the renderer draws for
the turned camera (principal point moved, non-square pixels), with the labels turned."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from opnet.data.augment import DepthAugmenter
from opnet.data.rotate import rotate_record, rotation_about_axis
from opnet.datasets.record import SceneRecord
from opnet.geometry.camera import Camera
from opnet.objects import builtin_object
from opnet.synthesis.layout import homogeneous, random_rotation
from opnet.synthesis.rendering import SceneRenderer

# non-square pixels and an off-centre principal point, as real cameras have
CAMERA = Camera(fx=380.0, fy=340.0, cx=140.3, cy=105.8, width=320, height=240, clip_start=0.4, clip_end=0.9)


def _render(camera: Camera, T_cam_obj: np.ndarray) -> SceneRecord:
    obj = builtin_object("bracket")
    renderer = SceneRenderer(obj.mesh, camera)
    try:
        out = renderer.render(T_cam_obj)
    finally:
        renderer.close()
    n = len(T_cam_obj)
    return SceneRecord("s", out.depth, camera, out.segmentation, T_cam_obj[:, :3, :3].copy(), T_cam_obj[:, :3, 3].copy(),
                       out.visibility, np.arange(1, n + 1), "bracket")


@pytest.fixture(scope="module")
def scene() -> SceneRecord:
    rng = np.random.default_rng(4)
    poses = [homogeneous(random_rotation(rng), np.array([x, y, z]))
             for x, y, z in [(-0.05, -0.03, 0.62), (0.04, 0.02, 0.66), (0.0, 0.05, 0.7), (0.11, -0.06, 0.64), (0.25, -0.1, 0.64)]]
    return _render(CAMERA, np.stack(poses))


@pytest.mark.parametrize("degrees", [30.0, -75.0, 180.0])
def test_turned_record_is_what_the_turned_camera_renders(scene: SceneRecord, degrees: float) -> None:
    turned = rotate_record(scene, degrees)
    Q = rotation_about_axis(math.radians(degrees))
    T = np.tile(np.eye(4), (scene.num_objects, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = Q @ scene.R_cam_obj, scene.t_cam_obj @ Q.T
    truth = _render(turned.camera, T)  # an independent render with the turned camera
    np.testing.assert_allclose(turned.R_cam_obj, truth.R_cam_obj, atol=1e-12)
    np.testing.assert_allclose(turned.t_cam_obj, truth.t_cam_obj, atol=1e-12)
    both = np.isfinite(turned.depth) & np.isfinite(truth.depth)
    # nearest-neighbour resampling: the same surface up to half a pixel's slope (a pixel is 1.7 mm
    # wide here) everywhere but on a pixel-wide band at the edges
    err = np.abs(turned.depth[both] - truth.depth[both])
    assert np.median(err) < 1e-3 and np.mean(err < 5e-3) > 0.95
    assert np.mean(turned.segmentation == truth.segmentation) > 0.97
    if degrees == 180.0:
        np.testing.assert_allclose(turned.depth[both], truth.depth[both], atol=1e-5)  # float rasterization
    np.testing.assert_allclose(turned.visibility, truth.visibility, atol=0.06)


def test_turns_compose_and_undo(scene: SceneRecord) -> None:
    back = rotate_record(rotate_record(scene, 180.0), 180.0)
    np.testing.assert_array_equal(back.depth, scene.depth)
    np.testing.assert_array_equal(back.segmentation, scene.segmentation)
    assert math.isclose(back.camera.cx, scene.camera.cx, abs_tol=1e-9)
    there = rotate_record(scene, 40.0)
    again = rotate_record(there, -40.0)
    np.testing.assert_allclose(again.R_cam_obj, scene.R_cam_obj, atol=1e-12)
    assert math.isclose(again.camera.cy, scene.camera.cy, abs_tol=1e-9)
    assert rotate_record(scene, 360.0) is scene


def test_a_part_turned_out_of_the_image_loses_visibility(scene: SceneRecord) -> None:
    turned = rotate_record(scene, 90.0)  # a 320 x 240 image turned a quarter: its sides leave the view
    assert (turned.visibility <= scene.visibility + 0.03).all()
    assert (turned.visibility < scene.visibility - 0.05).any()


def test_scene_without_segmentation_turns_only_exactly(scene: SceneRecord) -> None:
    bare = dataclasses.replace(scene, segmentation=None)
    assert rotate_record(bare, 180.0).segmentation is None
    with pytest.raises(ValueError, match="rotate_deg"):
        rotate_record(bare, 30.0)


def test_augmenter_draws_nothing_without_rotation(scene: SceneRecord) -> None:
    rng_a, rng_b = np.random.default_rng(1), np.random.default_rng(1)
    assert DepthAugmenter(p_rotate=0.0).turn(scene, rng_a) is scene
    assert rng_a.random() == rng_b.random()
    turned = DepthAugmenter(p_rotate=1.0, rotate_deg=(90.0, 90.0)).turn(scene, np.random.default_rng(0))
    np.testing.assert_allclose(turned.R_cam_obj, rotation_about_axis(math.pi / 2) @ scene.R_cam_obj)
    with pytest.raises(ValueError, match="p_rotate"):
        DepthAugmenter(p_rotate=1.5)
