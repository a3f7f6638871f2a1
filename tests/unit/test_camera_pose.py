"""opnet.synthesis.camera_pose: the generator settings that reproduce a rig, measured back from the
ground truth of flat-lying parts seen by a camera the generator itself placed."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from opnet.objects import builtin_object
from opnet.synthesis import SceneConfig
from opnet.synthesis.camera_pose import bop_camera_poses, estimate_pose, pose_from_w2c, thin_axis
from opnet.synthesis.layout import homogeneous, inverse_pose, make_rig, rotation_about


@pytest.mark.parametrize(("tilt", "azimuth", "height"), [(25.0, 40.0, 1.2), (12.0, -120.0, 0.9), (0.0, 0.0, 1.0)])
def test_flat_parts_give_back_the_tilt_azimuth_and_height(tilt: float, azimuth: float, height: float) -> None:
    plate = trimesh.creation.box(extents=(0.12, 0.08, 0.004))
    axis, thickness = thin_axis(np.asarray(plate.vertices))
    assert abs(axis[2]) == pytest.approx(1.0) and thickness == pytest.approx(0.004)
    rig = make_rig(builtin_object("bracket"), 10, 1, SceneConfig(resolution=128, camera_height=height,
                                                                 camera_tilt_deg=tilt, camera_azimuth_deg=azimuth))
    T_cam_world = inverse_pose(rig.T_world_cam)
    rng = np.random.default_rng(0)
    poses = []
    for _ in range(6):  # flat on the floor (z = 0), any yaw, either face up
        flip = rotation_about(np.array([1.0, 0.0, 0.0]), math.pi * rng.integers(2))
        R = rotation_about(np.array([0.0, 0.0, 1.0]), rng.uniform(0, 2 * math.pi)) @ flip
        T = T_cam_world @ homogeneous(R, np.array([*rng.uniform(-0.1, 0.1, 2), thickness / 2]))
        poses.append(T)
    poses = np.array(poses)
    pose = estimate_pose(poses[:, :3, :3], poses[:, :3, 3], axis, thickness)
    assert pose.camera_tilt_deg == pytest.approx(tilt, abs=1e-6)
    if tilt:
        assert (pose.camera_azimuth_deg - azimuth + 180) % 360 - 180 == pytest.approx(0.0, abs=1e-6)
    assert pose.camera_height == pytest.approx(height, abs=1e-6) and pose.normal_spread_deg < 1e-6
    with pytest.raises(ValueError, match="no parts"):
        estimate_pose(np.zeros((0, 3, 3)), np.zeros((0, 3)), axis, thickness)


@pytest.mark.parametrize(("tilt", "azimuth", "height"), [(25.0, 40.0, 1.2), (19.86, -30.26, 1.7748), (0.0, 0.0, 1.5)])
def test_a_world_to_camera_pose_gives_back_the_generator_settings(tilt: float, azimuth: float, height: float,
                                                                   tmp_path) -> None:
    import json

    rig = make_rig(builtin_object("bracket"), 10, 1, SceneConfig(resolution=128, camera_height=height,
                                                                 camera_tilt_deg=tilt, camera_azimuth_deg=azimuth))
    T_cam_world = inverse_pose(rig.T_world_cam)  # the generator's world: z up, the floor top at z = 0
    pose = pose_from_w2c(T_cam_world[:3, :3], T_cam_world[:3, 3])
    assert pose.camera_tilt_deg == pytest.approx(tilt, abs=1e-6)
    if tilt:
        assert (pose.camera_azimuth_deg - azimuth + 180) % 360 - 180 == pytest.approx(0.0, abs=1e-6)
    assert pose.camera_height == pytest.approx(height, abs=1e-6)
    # as a BOP split writes it (millimetres), and an identity entry (world = camera) is no pose
    scene = tmp_path / "000001"
    scene.mkdir()
    entry = {"cam_K": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_R_w2c": T_cam_world[:3, :3].ravel().tolist(),
             "cam_t_w2c": (1000 * T_cam_world[:3, 3]).tolist()}
    (scene / "scene_camera.json").write_text(json.dumps({"0": entry, "1": {**entry, "cam_R_w2c": np.eye(3).ravel().tolist()}}))
    (R, t), = bop_camera_poses(tmp_path)
    assert pose_from_w2c(R, t).camera_height == pytest.approx(height, abs=1e-6)
    with pytest.raises(ValueError, match="does not look down"):
        pose_from_w2c(np.diag([1.0, -1.0, -1.0]) @ T_cam_world[:3, :3], T_cam_world[:3, 3])
