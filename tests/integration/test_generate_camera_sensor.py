"""Generation with a user's camera (any intrinsics, off-centre principal point) and a sensor
model: the images have the camera's size and intrinsics, the ground truth stays exact, the sensor
damages only the depth, everything is deterministic and recorded for resume."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import compose_cfg
from opnet.cli.generate import run
from opnet.datasets.ipa import IPADataset
from opnet.geometry.camera import Camera

CAMERA_YAML = "fx: 150.0\nfy: 152.0\ncx: 55.3\ncy: 50.8\nwidth: 160\nheight: 120\nclip_start: 0.3\nclip_end: 2.0\n"


def _generate(tmp_path: Path, name: str, *extra: str) -> Path:
    cam = tmp_path / "camera.yaml"
    cam.write_text(CAMERA_YAML)
    out = tmp_path / name
    run(compose_cfg("generate", ["object=pin", "scene.collision=convex_hull", "cycles=1", "drops=6", f"out={out}",
                                 "progress=false", "previews=0", f"scene.camera_file={cam}", *extra]))
    return out


def test_camera_file_and_sensor_reach_the_written_dataset(tmp_path: Path) -> None:
    ideal = _generate(tmp_path, "ideal")
    sl = _generate(tmp_path, "sl", "sensor=structured_light")
    a, b = IPADataset(ideal), IPADataset(sl)
    assert a.camera == Camera(150.0, 152.0, 55.3, 50.8, 160, 120, a.camera.clip_start, a.camera.clip_end)
    last_a, last_b = a[len(a) - 1], b[len(b) - 1]
    assert last_a.depth.shape == (120, 160)
    # same physics and ground truth: the sensor changes the depth only
    assert np.array_equal(last_a.t_cam_obj, last_b.t_cam_obj) and np.array_equal(last_a.segmentation, last_b.segmentation)
    assert np.isnan(last_a.depth).mean() == 0.0
    assert 0.01 < np.isnan(last_b.depth).mean() < 0.6
    both = np.isfinite(last_b.depth)
    assert 0 < np.median(np.abs(last_b.depth[both] - last_a.depth[both])) < 0.01  # noise of millimetres
    gen = json.loads((sl / "generation.json").read_text())
    assert gen["sensor"]["name"] == "structured_light" and gen["scene"]["camera_file"].endswith("camera.yaml")
    assert "sensor" not in json.loads((ideal / "generation.json").read_text())
    # deterministic for a seed
    again = _generate(tmp_path, "sl_again", "sensor=structured_light")
    assert np.array_equal(IPADataset(again)[len(b) - 1].depth, last_b.depth, equal_nan=True)
    # a resumed run with another sensor is refused, naming the differing key
    with pytest.raises(ValueError, match=r"generation\.json.*\['sensor'\]"):
        _generate(tmp_path, "sl", "sensor=tof")


def test_bad_camera_file_stops_generation_before_anything_is_written(tmp_path: Path) -> None:
    cam = tmp_path / "camera.yaml"
    cam.write_text(CAMERA_YAML.replace("height: 120\n", ""))
    with pytest.raises(ValueError, match=r"camera\.yaml: missing camera key\(s\) \['height'\]"):
        run(compose_cfg("generate", ["object=pin", f"scene.camera_file={cam}", f"out={tmp_path / 'ds'}", "progress=false"]))
    assert not (tmp_path / "ds").exists()


def test_outside_clip_clamp_writes_what_a_real_frame_shows_beyond_the_working_volume(tmp_path: Path) -> None:
    # the file's clip planes end above the bin floor: the floor and the ground lie beyond the far plane
    near_far = ("scene.clip=camera", "scene.camera_height=0.5")
    cam = tmp_path / "camera.yaml"
    cam.write_text(CAMERA_YAML.replace("clip_start: 0.3", "clip_start: 0.35").replace("clip_end: 2.0", "clip_end: 0.49"))
    runs = {}
    for mode in ("missing", "clamp"):
        out = tmp_path / mode
        run(compose_cfg("generate", ["object=pin", "scene.collision=convex_hull", "cycles=1", "drops=6", f"out={out}",
                                     "progress=false", "previews=0", f"scene.camera_file={cam}", *near_far,
                                     f"scene.outside_clip={mode}"]))
        runs[mode] = IPADataset(out)[len(IPADataset(out)) - 1]
    missing, clamp = runs["missing"].depth, runs["clamp"].depth
    assert np.array_equal(runs["missing"].t_cam_obj, runs["clamp"].t_cam_obj)  # same scene, only the depth differs
    beyond = np.isnan(missing)
    assert beyond.mean() > 0.3  # the floor is past the far plane: missing by default (as datasets always were)
    assert np.isfinite(clamp).all()  # ideal sensor: every pixel has a surface, held at the plane it crosses
    assert np.allclose(clamp[beyond], 0.49, atol=1e-4)
    assert np.allclose(clamp[~beyond], missing[~beyond])
    # the network input sees the same far plane as it sees a real frame's depth beyond it
    from opnet.data.preprocess import to_network_input

    real_like = np.where(beyond, 0.9, missing).astype(np.float32)  # a measured ground 0.4 m past the plane
    a, _ = to_network_input(clamp, runs["clamp"].camera, 32)
    b, _ = to_network_input(real_like, runs["clamp"].camera, 32)
    assert np.allclose(a, b, atol=1e-3)
    with pytest.raises(ValueError, match="outside_clip"):
        run(compose_cfg("generate", ["object=pin", f"scene.outside_clip=zero", f"out={tmp_path / 'bad'}", "progress=false"]))


def test_camera_scale_renders_half_the_file_s_pixels_with_the_sensor_scaled(tmp_path: Path) -> None:
    cam = tmp_path / "camera.yaml"
    cam.write_text(CAMERA_YAML)
    out = tmp_path / "half"
    run(compose_cfg("generate", ["object=pin", "scene.collision=convex_hull", "cycles=1", "drops=1", f"out={out}",
                                 "progress=false", "previews=0", f"scene.camera_file={cam}", "scene.camera_scale=0.5",
                                 "sensor=structured_light"]))  # fmt: skip
    ds = IPADataset(out)
    assert ds.camera == Camera(75.0, 76.0, 27.4, 25.15, 80, 60, ds.camera.clip_start, ds.camera.clip_end)
    assert ds[len(ds) - 1].depth.shape == (60, 80)
    assert json.loads((out / "parameter.json").read_text())["opnet_intrinsics"] == pytest.approx([75.0, 76.0, 27.4, 25.15])
    gen = json.loads((out / "generation.json").read_text())
    assert gen["scene"]["camera_scale"] == 0.5
    # the sensor applied, at the rendered pixels: structured_light's 0.8, 2, 0.125 and 12 px halved
    assert {k: gen["sensor"][k] for k in ("lateral_px", "edge_missing_px", "disparity_step_px", "blob_scale_px")} == {
        "lateral_px": 0.4, "edge_missing_px": 1, "disparity_step_px": 0.0625, "blob_scale_px": 6.0}
