"""opnet-cell on the command line: the cell file and its picture, train.py experiment=cell reading every measured
key from it, and each bad input refused in one line naming the file, exit 2, nothing written."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from omegaconf import open_dict

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from opnet.cli.cell import main  # noqa: E402
from opnet.cli.cell_train import state_cell  # noqa: E402

CAMERA_YAML = "fx: 300\nfy: 300\ncx: 159.5\ncy: 119.5\nwidth: 320\nheight: 240\nclip_start: 0.5\nclip_end: 3.0\n"


@pytest.fixture(scope="module")
def pile(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """A generated pile of a known cell (its depth PNGs are the frames) and its camera file."""
    from opnet.objects.library import builtin_object
    from opnet.synthesis.config import SceneConfig
    from opnet.synthesis.generate import generate_dataset

    base = tmp_path_factory.mktemp("cell_cli")
    camera = base / "camera.yaml"
    camera.write_text(CAMERA_YAML)
    scene = SceneConfig(camera_file=str(camera), clip="camera", camera_height=1.2, camera_tilt_deg=15.0,
                        camera_azimuth_deg=40.0, bin_inner=0.3, bin_inner_y=0.45, bin_wall_height=0.12,
                        bin_wall_thickness=0.004, bin_clearance=0.2, camera_jitter_m=0.0, camera_jitter_deg=0.0,
                        outside_clip="clamp")
    generate_dataset(builtin_object("zbracket"), base / "pile", cycles=1, drops=1, workers=1, seed=0, scene=scene,
                     progress=False, previews=0)
    return base / "pile", camera


def _cell_file(pile: tuple[Path, Path], folder: Path, *extra: str) -> tuple[int, Path]:
    root, camera = pile
    out = folder / "cell" / "mine.yaml"
    return main([str(root), "--camera", str(camera), "--out", str(out), "--sensor", "structured_light", *extra]), out


def test_the_cell_file_holds_every_measured_key_and_train_reads_them(pile, tmp_path, capsys) -> None:
    from conftest import compose_cfg

    from opnet.cell.cellfile import MEASURED_KEYS
    from opnet.objects.library import builtin_object
    from opnet.synthesis.config import SceneConfig
    from opnet.synthesis.layout import make_rig

    rc, out = _cell_file(pile, tmp_path)
    assert rc == 0, capsys.readouterr().err
    printed = capsys.readouterr().out
    assert "tilt 15.00 " in printed and "bin inner 0.300 " in printed and " x 0.450 " in printed, printed
    assert out.with_suffix(".png").is_file() and cv2.imread(str(out.with_suffix(".png"))) is not None
    doc = yaml.safe_load(out.read_text())
    assert doc["defaults"] == [{"override /sensor": "structured_light"}]
    assert abs(doc["scene"]["camera_height"] - 1.2) < 0.003 and abs(doc["scene"]["camera_tilt_deg"] - 15) < 0.2
    cfg = compose_cfg("train", ["experiment=cell", "cell=mine", "object=zbracket",
                                f"hydra.searchpath=[file://{tmp_path}]"])
    assert cfg.sensor.name == "structured_light"
    for key in MEASURED_KEYS:
        section, name = key.split(".")
        written = doc[section][name]
        assert (cfg[section][name] == written) or str(cfg[section][name]).endswith(Path(str(written)).name), key
    lines = state_cell(cfg)
    assert lines[0].startswith("cell mine: camera") and "sensor structured_light" in lines[1]
    assert Path(cfg.data.root).name.startswith(f"cell_{cfg.cell.tag}_zbracket") and cfg.cell.tag.startswith("mine_")
    scene = SceneConfig.from_dict(json.loads(json.dumps(dict(cfg.data.generate.scene), default=list)))
    rig = make_rig(builtin_object("zbracket"), 10, 1, scene)  # the generator takes the cell as it is
    assert (rig.camera.clip_start, rig.camera.clip_end) == tuple(doc["scene"]["clip"])
    # a re-measured value is another cell: another data folder
    tag = cfg.cell.tag
    cfg.scene.camera_height = 1.25
    state_cell(cfg)
    assert cfg.cell.tag != tag


def test_without_a_cell_file_each_measured_key_is_mandatory() -> None:
    from conftest import compose_cfg

    cfg = compose_cfg("train", ["experiment=cell", "object=zbracket"])
    with pytest.raises(ValueError, match=r"scene\.camera_file is not set \(give cell=<name>"):
        state_cell(cfg)
    cfg = compose_cfg("train", ["experiment=cell", "object=zbracket", "scene.camera_file=c.yaml",
                                "scene.camera_height=1.5", "scene.camera_tilt_deg=0", "scene.camera_azimuth_deg=0"])
    with pytest.raises(ValueError, match=r"scene\.clip is not set"):
        state_cell(cfg)
    # a cell file of an earlier opnet-cell spelt the working volume scene.clip_start / clip_end: named, with what to write
    with open_dict(cfg.scene):
        cfg.scene.clip_start, cfg.scene.clip_end = 1.4, 2.1
    with pytest.raises(ValueError, match=r"sets scene\.clip_start and scene\.clip_end, an earlier spelling: write "
                                         r"clip: \[1\.4, 2\.1\] under scene"):
        state_cell(cfg)


def test_an_existing_cell_file_is_kept_without_force(pile, tmp_path, capsys) -> None:
    rc, out = _cell_file(pile, tmp_path)
    assert rc == 0
    before = out.read_text()
    rc, _ = _cell_file(pile, tmp_path, "--area=-0.1,-0.1,0.1,0.1")
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and str(out) in err[0] and "--force" in err[0]
    assert out.read_text() == before
    rc, _ = _cell_file(pile, tmp_path, "--area=-0.1,-0.1,0.1,0.1", "--force")
    assert rc == 0 and "bin_area: [-0.1, -0.1, 0.1, 0.1]" in out.read_text()


# ------------------------------------------------------------------------------------------- bad input


def _npy(path: Path, depth: np.ndarray) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, depth.astype(np.float32))
    return path


def _bin_frame(shape: tuple[int, int] = (240, 320)) -> np.ndarray:
    """A flat floor 1.2 m away (a table without walls)."""
    return np.full(shape, 1.2, np.float32)


def _refused(capsys, argv: list[str], out: Path, *needles: str) -> None:
    rc = main([*argv, "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2, err
    assert len(err) == 1 and err[0].startswith("error: "), err
    for needle in needles:
        assert needle in err[0], err[0]
    assert not out.exists() and not out.with_suffix(".png").exists()


def _bop_split(root: Path, cameras: list[list[float]], depth_mm: np.ndarray) -> Path:
    scene = root / "000000"
    (scene / "depth").mkdir(parents=True)
    entries = {}
    for i, K in enumerate(cameras):
        cv2.imwrite(str(scene / "depth" / f"{i:06d}.png"), (depth_mm * 10).astype(np.uint16))
        entries[str(i)] = {"cam_K": K, "depth_scale": 0.1}
    (scene / "scene_camera.json").write_text(json.dumps(entries))
    return root


def test_bad_inputs_are_one_line_naming_the_file_exit_2_nothing_written(tmp_path, capsys) -> None:
    camera = tmp_path / "camera.yaml"
    camera.write_text(CAMERA_YAML)
    out = tmp_path / "conf" / "cell" / "c.yaml"
    cam = ["--camera", str(camera)]
    # frames of different sizes
    sizes = tmp_path / "sizes"
    _npy(sizes / "a.npy", _bin_frame())
    _npy(sizes / "b.npy", _bin_frame((200, 320)))
    _refused(capsys, [str(sizes), *cam], out, "b.npy", "320 x 200", "one size")
    # frames of different cameras (a BOP split whose images give two cam_K)
    K = [300.0, 0.0, 159.5, 0.0, 300.0, 119.5, 0.0, 0.0, 1.0]
    other = [310.0, 0.0, 159.5, 0.0, 310.0, 119.5, 0.0, 0.0, 1.0]
    split = _bop_split(tmp_path / "two_cameras", [K, other], _bin_frame() * 1000)
    _refused(capsys, [str(split), *cam], out, "000001.png", "is not that of")
    # a camera file that does not fit the frames: another image size, other intrinsics, other clip planes
    small = tmp_path / "small.yaml"
    small.write_text(CAMERA_YAML.replace("width: 320", "width: 640").replace("cx: 159.5", "cx: 319.5"))
    _refused(capsys, [str(sizes / "a.npy"), "--camera", str(small)], out, "a.npy", "640 x 240", str(small))
    split_other = _bop_split(tmp_path / "other_camera", [other], _bin_frame() * 1000)
    _refused(capsys, [str(split_other), *cam], out, "000000.png", "not the camera file", str(camera))
    far = tmp_path / "far.yaml"
    far.write_text(CAMERA_YAML.replace("clip_start: 0.5", "clip_start: 5").replace("clip_end: 3.0", "clip_end: 8"))
    _refused(capsys, [str(sizes / "a.npy"), "--camera", str(far)], out, "a.npy", "between the clip planes", str(far))
    # all-zero depth
    _refused(capsys, [str(_npy(tmp_path / "zero.npy", np.zeros((240, 320)))), *cam], out, "zero.npy", "no depth")
    # no plane: depth without any surface (noise over the working range)
    noise = np.random.default_rng(0).uniform(0.6, 2.9, (240, 320))
    _refused(capsys, [str(_npy(tmp_path / "noise.npy", noise)), *cam], out, "noise.npy", "no plane")
    # no bin: a plane without walls
    _refused(capsys, [str(_npy(tmp_path / "table.npy", _bin_frame())), *cam], out, "table.npy", "no bin")
    # an extrinsics matrix that is not a rigid transform
    scaled = tmp_path / "scaled.yaml"
    scaled.write_text("T_base_cam: [[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 1.5], [0, 0, 0, 1]]\n")
    _refused(capsys, [str(sizes / "a.npy"), *cam, "--extrinsics", str(scaled)], out, str(scaled), "not a rigid")
    shear = tmp_path / "shear.yaml"
    shear.write_text("T_base_cam: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1.5], [0, 0.1, 0, 1]]\n")
    _refused(capsys, [str(sizes / "a.npy"), *cam, "--extrinsics", str(shear)], out, str(shear), "last row")
    # integer frames without their depth scale, a name that is no file name
    ints = tmp_path / "mm.npy"
    np.save(ints, np.full((240, 320), 1200, np.uint16))
    _refused(capsys, [str(ints), *cam], out, "mm.npy", "--depth-scale")
    assert main([str(ints), *cam, "--name", "../x"]) == 2
    assert "--name" in capsys.readouterr().err


def test_a_calibration_gives_the_pose_and_the_frames_check_it(pile, tmp_path, capsys) -> None:
    """--extrinsics: the tilt from the base's z axis; a calibration the frames contradict is refused."""
    from opnet.synthesis.layout import R_WORLD_CAM_DOWN, homogeneous, tilted

    root, camera = pile
    T = tilted(homogeneous(R_WORLD_CAM_DOWN, np.array([0.3, -0.2, 1.4])), 15.0, 40.0)  # the generator's own pose
    good = tmp_path / "good.yaml"
    good.write_text(yaml.safe_dump({"T_base_cam": T.tolist()}))
    out = tmp_path / "cell" / "cal.yaml"
    assert main([str(root), "--camera", str(camera), "--extrinsics", str(good), "--out", str(out)]) == 0
    assert "from the calibration" in capsys.readouterr().out
    doc = yaml.safe_load(out.read_text())
    assert abs(doc["scene"]["camera_tilt_deg"] - 15.0) < 0.01 and abs(doc["scene"]["camera_azimuth_deg"] - 40.0) < 0.01
    assert np.allclose(doc["cell"]["T_base_cam"], T, atol=1e-6)
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"T_base_cam": tilted(homogeneous(R_WORLD_CAM_DOWN, np.zeros(3)), 25.0, 40.0).tolist()}))
    _refused(capsys, [str(root), "--camera", str(camera), "--extrinsics", str(bad)], tmp_path / "cell" / "bad_cal.yaml",
             str(bad), "degrees from the floor's normal")


def test_the_sim_versus_real_check_of_a_cell_against_its_own_frames(pile, tmp_path, capsys, monkeypatch) -> None:
    """Frames the generator made (ideal depth) checked against piles of the cell measured from them: the
    empty bin rendered where their bin stood puts its floor at their floor's depth, the bin is found in every
    frame, and of the sensor presets the ideal one is the closest; with the bin's yaw measured the wrong way
    round, the floor residual shows it."""
    from opnet.cell import rig
    from opnet.cli.cell_check import check_main

    rc, cell = _cell_file(pile, tmp_path)
    assert rc == 0
    out = tmp_path / "check"
    argv = [str(cell), str(pile[0]), "--object", "zbracket", "--piles", "1", "--drops", "3", "--scale", "1",
            "--out", str(out)]
    assert check_main(argv) == 0, capsys.readouterr().err
    numbers = json.loads((out / "check.json").read_text())
    assert numbers["real"]["found"] == numbers["real"]["frames"] == 2
    assert numbers["generated"]["found"] == numbers["generated"]["frames"]
    assert abs(numbers["floor_residual_mm"]["median"]) < 1.0 and numbers["floor_residual_mm"]["p90_abs"] < 3.0
    assert numbers["closest_preset"] == "ideal"
    assert np.allclose(numbers["generated"]["inner"], numbers["real"]["inner"], atol=0.02)  # piles hide some floor
    page = (out / "README.md").read_text()
    assert f"Made by `opnet-cell check {cell}" in page and (out / "check.png").is_file()
    placement = rig.bin_placement
    monkeypatch.setattr(rig, "bin_placement", lambda T, c, a: (*placement(T, c, a)[:2], placement(T, c, a)[2] + 90.0))
    assert check_main([*argv[:-1], str(tmp_path / "broken")]) == 0
    broken = json.loads((tmp_path / "broken" / "check.json").read_text())
    assert broken["floor_residual_mm"]["p90_abs"] > 10.0
