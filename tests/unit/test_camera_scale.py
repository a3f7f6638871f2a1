"""``scene.camera_scale``: a camera file rendered at a fraction of its pixels (the same field of view and
pose), the sensor model's pixel-unit settings scaled with it, old datasets' settings unchanged."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from opnet.geometry.camera import Camera
from opnet.objects import builtin_object
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.layout import make_rig
from opnet.synthesis.sensor import SensorModel

CAMERA_YAML = "fx: 150.0\nfy: 152.0\ncx: 55.3\ncy: 50.8\nwidth: 160\nheight: 120\nclip_start: 0.3\nclip_end: 2.0\n"
PHOTONEO = Camera(2320.26, 2320.15, 1053.13, 805.064, 2064, 1544, 1.5399, 2.8501)


def test_scaled_intrinsics_by_hand() -> None:
    # 160 x 120 at 0.5: 80 x 60; fx 150 * 80/160, fy 152 * 60/120, cx (55.3 + 0.5) * 0.5 - 0.5, cy (50.8 + 0.5) * 0.5 - 0.5
    half = Camera(150.0, 152.0, 55.3, 50.8, 160, 120, 0.3, 2.0).scaled(0.5)
    assert half == Camera(75.0, 76.0, 27.4, 25.15, 80, 60, 0.3, 2.0)
    # the Photoneo at 0.3: round(619.2) = 619, round(463.2) = 463; fx 2320.26 * 619 / 2064 = 1436240.94 / 2064,
    # fy 2320.15 * 463 / 1544 = 1074229.45 / 1544, cx 1053.63 * 619 / 2064 - 0.5, cy 805.564 * 463 / 1544 - 0.5
    cam = PHOTONEO.scaled(0.3)
    assert (cam.width, cam.height) == (619, 463)
    assert (cam.fx, cam.fy, cam.cx, cam.cy) == pytest.approx((695.8531686, 695.7444624, 315.4869041, 241.0648523), abs=1e-6)
    assert (cam.clip_start, cam.clip_end) == (PHOTONEO.clip_start, PHOTONEO.clip_end)
    assert PHOTONEO.scaled(1.0) == PHOTONEO


@pytest.mark.parametrize("value", [0, 0.0, -0.5, 5, 4.5, "0.5", True, float("nan")])
def test_scene_config_refuses_a_scale_out_of_range_or_not_a_number(value: object) -> None:
    with pytest.raises(ValueError, match=r"scene config: camera_scale=") as e:
        SceneConfig(camera_file="camera.yaml", camera_scale=value)
    assert "camera_scale" in str(e.value)


def test_scene_config_refuses_a_scale_without_a_camera_file() -> None:
    with pytest.raises(ValueError, match=r"camera_scale=0\.5, expected 1 without scene\.camera_file"):
        SceneConfig(camera_scale=0.5)
    assert SceneConfig(camera_scale=1).camera_scale == 1
    assert SceneConfig(camera_file="camera.yaml", camera_scale=4).camera_scale == 4


def test_old_datasets_settings_have_no_camera_scale() -> None:
    assert "camera_scale" not in SceneConfig().to_dict()
    assert "camera_scale" not in SceneConfig(camera_file="camera.yaml").to_dict()
    scaled = SceneConfig(camera_file="camera.yaml", camera_scale=0.5)
    assert scaled.to_dict()["camera_scale"] == 0.5
    assert SceneConfig.from_dict(scaled.to_dict()) == scaled


def test_the_sensor_scales_its_pixel_unit_settings() -> None:
    sl = SensorModel(name="sl", baseline_m=0.075, disparity_step_px=0.125, lateral_px=0.8, edge_missing_px=2,
                     blob_rate=0.02, blob_scale_px=12.0, noise_a_m=0.001)  # fmt: skip
    half = sl.scaled(0.5)
    assert (half.lateral_px, half.edge_missing_px, half.blob_scale_px, half.disparity_step_px) == (0.4, 1, 6.0, 0.0625)
    assert (half.name, half.baseline_m, half.noise_a_m, half.blob_rate) == (sl.name, sl.baseline_m, sl.noise_a_m, sl.blob_rate)
    assert sl.scaled(0.1).edge_missing_px == 1  # an edge band keeps at least a pixel
    assert SensorModel(lateral_px=0.5).scaled(0.5).edge_missing_px == 0  # none stays none
    assert sl.scaled(2.0).edge_missing_px == 4 and sl.scaled(1.0) is sl
    assert SensorModel().scaled(0.5) == SensorModel() and SensorModel().scaled(0.5).is_ideal
    with pytest.raises(ValueError, match=r"sensor\.blob_scale_px=.*scene\.camera_scale=0\.05"):
        sl.scaled(0.05)  # blobs below a pixel


def test_scaled_disparity_steps_keep_their_depth_steps() -> None:
    z = np.repeat(np.linspace(1.0, 1.5, 48)[:, None], 64, axis=1)  # depth varies along the rows: no shadows
    sl = SensorModel(baseline_m=0.075, disparity_step_px=1.0)  # steps of z^2 / 45 m at fx 600: 22 mm at 1 m
    full, rng = Camera(600.0, 600.0, 31.5, 23.5, 64, 48, 0.5, 2.0), np.random.default_rng(0)
    a, b = sl.apply(z, full, rng), sl.scaled(0.5).apply(z, full.scaled(0.5), rng)
    assert np.allclose(a, b, rtol=1e-12) and 10 < len(np.unique(a)) < 48
    unscaled = sl.apply(z, full.scaled(0.5), rng)  # the full camera's step at half its pixels: twice the depth step
    assert len(np.unique(unscaled)) < 0.6 * len(np.unique(a))


def test_make_rig_renders_the_file_at_half_its_pixels_from_the_same_pose(tmp_path: Path) -> None:
    cam = tmp_path / "camera.yaml"
    cam.write_text(CAMERA_YAML)
    obj = builtin_object("pin")
    full = make_rig(obj, 3, 1, SceneConfig(camera_file=str(cam)))
    half = make_rig(obj, 3, 1, SceneConfig(camera_file=str(cam), camera_scale=0.5))
    c = half.camera
    assert (c.width, c.height) == (80, 60)
    assert (c.fx, c.fy, c.cx, c.cy) == pytest.approx((75.0, 76.0, 27.4, 25.15), abs=1e-9)
    assert (c.clip_start, c.clip_end) == pytest.approx((full.camera.clip_start, full.camera.clip_end), rel=1e-9)
    assert np.allclose(half.T_world_cam, full.T_world_cam, atol=1e-9)
    assert half.params.camera() == c  # what parameter.json says
    clipped = make_rig(obj, 3, 1, SceneConfig(camera_file=str(cam), clip="camera", camera_height=1.0,
                                              camera_scale=0.5))  # fmt: skip
    assert (clipped.camera.clip_start, clipped.camera.clip_end) == (0.3, 2.0)


def test_make_rig_names_the_file_and_the_scale_of_an_image_without_pixels(tmp_path: Path) -> None:
    cam = tmp_path / "camera.yaml"
    cam.write_text(CAMERA_YAML)
    with pytest.raises(ValueError, match=r"camera\.yaml at scene\.camera_scale=0\.001: 160x120 pixels at 0\.001 x leave none"):
        make_rig(builtin_object("pin"), 3, 1, SceneConfig(camera_file=str(cam), camera_scale=0.001))
