"""Tilted cameras in generation: the camera looks at the bin floor's centre from
``camera_tilt_deg`` off vertical, the clip planes hold the whole scene, and the written ground
truth reprojects onto the rendered segmentation."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
from conftest import small_builtin_dataset

from opnet.datasets import open_dataset
from opnet.objects import builtin_object
from opnet.synthesis import SceneConfig
from opnet.synthesis.layout import make_rig


@pytest.mark.parametrize(("tilt", "azimuth"), [(25.0, 0.0), (40.0, 135.0)])
def test_the_tilted_camera_looks_at_the_bin_centre_from_its_tilt(tilt: float, azimuth: float) -> None:
    obj = builtin_object("bracket")
    straight = make_rig(obj, 10, 1, SceneConfig(resolution=128))
    rig = make_rig(obj, 10, 1, SceneConfig(resolution=128, camera_tilt_deg=tilt, camera_azimuth_deg=azimuth))
    axis = rig.T_world_cam[:3, 2]  # the optical axis in the world
    assert math.degrees(math.acos(-axis[2])) == pytest.approx(tilt)
    centre = rig.T_world_cam[:3, 3]
    assert np.linalg.norm(centre) == pytest.approx(np.linalg.norm(straight.T_world_cam[:3, 3]))  # same distance
    assert np.linalg.norm(np.cross(axis, -centre / np.linalg.norm(centre))) < 1e-9  # looking at the origin
    toward = np.array([math.cos(math.radians(azimuth)), math.sin(math.radians(azimuth))])
    assert centre[:2] @ toward > 0  # displaced towards the azimuth
    assert rig.camera.clip_end > straight.camera.clip_end  # the far side of the ground lies farther


def test_untilted_rigs_are_unchanged_and_bad_tilts_are_one_line() -> None:
    obj = builtin_object("bracket")
    assert SceneConfig().to_dict() == SceneConfig(camera_tilt_deg=0.0).to_dict()  # datasets made before match
    assert "camera_tilt_deg" not in SceneConfig().to_dict()
    with pytest.raises(ValueError, match=r"camera_tilt_deg=95\.0, expected degrees in \[0, 90\)"):
        SceneConfig(camera_tilt_deg=95.0)
    with pytest.raises(ValueError, match="the image.s corner reaches above the horizon; this camera takes a tilt below"):
        make_rig(obj, 10, 1, SceneConfig(resolution=128, fov_deg=100.0, camera_tilt_deg=60.0))


def test_tilted_ground_truth_reprojects_onto_the_segmentation(tmp_path: Path) -> None:
    root = small_builtin_dataset(tmp_path / "tilted", "bracket", 1, 6, 0, camera_tilt_deg=25.0,
                                 camera_azimuth_deg=30.0)  # fmt: skip
    mesh = builtin_object("bracket").mesh
    surface = trimesh.sample.sample_surface_even(mesh, 400, seed=0)[0]  # points all over the part
    dataset = open_dataset(root)
    shares = []
    for i in range(len(dataset)):
        rec = dataset[i]
        for R, t, vis, k in zip(rec.R_cam_obj, rec.t_cam_obj, rec.visibility, rec.instance_id, strict=True):
            if vis < 0.95:
                continue
            uv = rec.camera.project(surface @ R.T + t)
            px = np.round(uv).astype(int)
            inside = (px[:, 0] >= 0) & (px[:, 0] < rec.camera.width) & (px[:, 1] >= 0) & (px[:, 1] < rec.camera.height)
            assert inside.all()
            on_part = rec.segmentation[px[:, 1], px[:, 0]] == k
            shifted = np.clip(px + [3, 3], 0, [rec.camera.width - 1, rec.camera.height - 1])
            off = rec.segmentation[shifted[:, 1], shifted[:, 0]] == k  # the same 3 px off: a wrong pose
            shares.append((on_part.mean(), off.mean()))
    shares = np.array(shares)
    assert len(shares) >= 3
    assert shares[:, 0].min() > 0.85 and shares[:, 0].mean() > 0.9  # all but the silhouette's rim
    assert shares[:, 1].mean() < shares[:, 0].mean() - 0.2
