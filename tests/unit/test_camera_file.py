"""A user's camera for generation: camera files of three kinds, exact intrinsics in parameter.json
for any camera, an off-centre principal point in the set-up, and clear errors for bad files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from opnet.datasets.camera_file import read_camera_file
from opnet.datasets.ipa_params import IPAParameters, read_parameters, write_parameters
from opnet.geometry.camera import Camera
from opnet.objects import builtin_object
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.layout import inverse_pose, make_rig

# Siléane's real camera: principal point far off centre and off the half-pixel grid
SILEANE_LIKE = Camera(4507.08, 4507.08, 399.557, 556.6, 1296, 1024, 0.76295, 0.929367)
YAML = "fx: 300.5\nfy: 302.0\ncx: 100.3\ncy: 70.8\nwidth: 240\nheight: 160\nclip_start: 0.4\nclip_end: 1.2\n"


def _sileane_file(path: Path, cam: Camera) -> Path:
    path.write_text(
        f"width\t{cam.width}\nheight\t{cam.height}\nfu\t{cam.fx}\nfv\t{cam.fy}\ncu\t{cam.cx}\ncv\t{cam.cy}\n"
        f"clip_start\t{cam.clip_start}\nclip_end\t{cam.clip_end}\nlocation\t0\t0\t0\nrotation\t1\t0\t0\t0\n"
    )
    return path


def test_three_kinds_of_camera_file(tmp_path: Path) -> None:
    assert read_camera_file(_sileane_file(tmp_path / "camera_params.txt", SILEANE_LIKE)) == SILEANE_LIKE
    (tmp_path / "cam.yaml").write_text(YAML)
    assert read_camera_file(tmp_path / "cam.yaml") == Camera(300.5, 302.0, 100.3, 70.8, 240, 160, 0.4, 1.2)
    write_parameters(tmp_path / "ipa", IPAParameters.for_any_camera(SILEANE_LIKE, 3, 10))
    assert read_camera_file(tmp_path / "ipa" / "parameter.json") == SILEANE_LIKE
    assert read_camera_file(tmp_path / "ipa") == SILEANE_LIKE  # a dataset folder


def test_parameter_json_keeps_any_camera_exactly_and_the_nearest_ipa_camera(tmp_path: Path) -> None:
    params = IPAParameters.for_any_camera(SILEANE_LIKE, 1, 20)
    write_parameters(tmp_path, params)
    doc = json.loads((tmp_path / "parameter.json").read_text())
    assert doc["opnet_intrinsics"] == [4507.08, 4507.08, 399.557, 556.6]
    back = read_parameters(tmp_path)
    assert back.camera() == SILEANE_LIKE
    # the IPA fields alone describe the nearest IPA camera (principal point within half a pixel)
    ipa_only = IPAParameters(**{**back.__dict__, "intrinsics": None}).camera()
    assert abs(ipa_only.cx - 399.557) <= 0.5 and abs(ipa_only.cy - 556.6) <= 0.5
    assert ipa_only.fx == pytest.approx(4507.08, rel=1e-9)
    # an IPA-expressible camera gets no extra key (files as before)
    centred = Camera(400.0, 400.0, 127.5, 127.5, 256, 256, 0.5, 1.0)
    assert IPAParameters.for_any_camera(centred, 1, 1).intrinsics is None


@pytest.mark.parametrize(("text", "message"), [
    (YAML.replace("cy: 70.8\n", ""), "missing camera key(s) ['cy']"),
    (YAML.replace("cx: 100.3", "cx: 260.0"), "principal point (260, 70.8) lies outside the 240x160 image"),
    (YAML.replace("cy: 70.8", "cy: -3"), "principal point (100.3, -3) lies outside"),
    (YAML.replace("width: 240", "width: 240.5"), "width=240.5 must be a positive whole number"),
    (YAML.replace("fx: 300.5", "fx: abc"), "camera.fx='abc' is not a number"),
    (YAML + "k1: 0.1\n", "unknown camera key(s) ['k1']"),
    (YAML.replace("clip_end: 1.2", "clip_end: 1200"), "clip_end = 1200 m is implausible"),
    ("[1, 2]", "a camera YAML holds a mapping"),
])
def test_bad_camera_yaml_names_the_file_and_the_problem(text: str, message: str, tmp_path: Path) -> None:
    path = tmp_path / "cam.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=r"cam\.yaml") as info:
        read_camera_file(path)
    assert message in str(info.value)


def test_bad_sileane_camera_file_names_the_key(tmp_path: Path) -> None:
    path = _sileane_file(tmp_path / "camera_params.txt", SILEANE_LIKE)
    path.write_text(path.read_text().replace("cv\t556.6\n", ""))
    with pytest.raises(ValueError, match=r"camera_params\.txt: missing key\(s\) \['cv'\]"):
        read_camera_file(path)
    _sileane_file(path, Camera(4507.08, 4507.08, 1500.0, 556.6, 1296, 1024, 0.76, 0.93))
    with pytest.raises(ValueError, match=r"camera_params\.txt: principal point \(1500, 556\.6\) lies outside"):
        read_camera_file(path)
    (tmp_path / "other.cfg").write_text("x")
    with pytest.raises(ValueError, match=r"other\.cfg: unknown camera file"):
        read_camera_file(tmp_path / "other.cfg")
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match=r"empty: no camera_params\.txt or parameter\.json"):
        read_camera_file(tmp_path / "empty")


def test_off_centre_camera_still_sees_the_whole_bin(tmp_path: Path) -> None:
    """The rig of a camera file: exact intrinsics, and the image centre (not the optical axis) on
    the bin, so a principal point 250 px left of centre still frames the whole bin."""
    cam_file = _sileane_file(tmp_path / "camera_params.txt", SILEANE_LIKE)
    cfg = SceneConfig(camera_file=str(cam_file), camera_jitter_m=0.0, camera_jitter_deg=0.0)
    rig = make_rig(builtin_object("shaft"), 15, 1, cfg)
    cam = rig.camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (4507.08, 4507.08, 399.557, 556.6, 1296, 1024)
    T_cam_world = inverse_pose(rig.T_world_cam)
    a, t, h = rig.bin.outer / 2, rig.bin.thickness, rig.bin.wall_height
    corners = np.array([[sx * a, sy * a, z] for sx in (-1, 1) for sy in (-1, 1) for z in (h, -t)])
    p = corners @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    uv = cam.project(p)
    assert (uv >= 0).all() and (uv[:, 0] <= cam.width - 1).all() and (uv[:, 1] <= cam.height - 1).all()
    # centred in the image: the bin centre projects to the image centre
    centre = cam.project((T_cam_world[:3, :3] @ np.zeros(3) + T_cam_world[:3, 3])[None])[0]
    assert np.allclose(centre, [(cam.width - 1) / 2, (cam.height - 1) / 2], atol=1.0)
    assert cam.clip_start < p[:, 2].min() and p[:, 2].max() < cam.clip_end  # derived clip planes
    with_file_clip = make_rig(builtin_object("shaft"), 15, 1, SceneConfig(camera_file=str(cam_file), clip="camera"))
    assert (with_file_clip.camera.clip_start, with_file_clip.camera.clip_end) == (0.76295, 0.929367)


def test_scene_settings_of_before_keep_their_generation_record() -> None:
    """Datasets made before camera files existed keep matching their generation.json."""
    assert "camera_file" not in SceneConfig().to_dict()
    assert SceneConfig(camera_file="x.yaml").to_dict()["camera_file"] == "x.yaml"
    recorded = SceneConfig(camera_file="x.yaml", clip="camera").to_dict()
    assert recorded["camera_file_clip"] is True and SceneConfig.from_dict(recorded).clip == ("camera", "camera")


@pytest.mark.parametrize("name", ["scene_camera.json", "scene_camera.yaml"])
def test_a_bop_scene_camera_file_is_named_as_such(name: str, tmp_path: Path) -> None:
    """A BOP scene_camera.json given as the camera: the generator blamed it for lacking perspectiveAngle,
    predict.py's camera.file for its unknown keys '0', '1'; it is one scene's cameras, per image."""
    from opnet.datasets.depth_inputs import given_camera

    doc = {str(i): {"cam_K": [600.0, 0.0, 320.0, 0.0, 600.0, 240.0, 0.0, 0.0, 1.0], "depth_scale": 0.1} for i in range(3)}
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    expected = rf"^{path}: a BOP scene_camera.json \(a cam_K for each of 3 image\(s\)\), not a camera file; read its split"
    if name.endswith(".json"):
        with pytest.raises(ValueError, match=expected):
            read_camera_file(path)
    with pytest.raises(ValueError, match=expected):
        given_camera({"file": str(path)})
