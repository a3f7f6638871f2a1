"""predict.py inputs as users have them: a camera PNG with its intrinsics given on the command line
or in a camera YAML, conflicts with a dataset's camera file, folders with equal file names,
existing outputs, FIFOs, and the console's account of what was written."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from opnet.cli import predict as predict_cli
from opnet.datasets.ipa_params import read_parameters
from opnet.datasets.png import encode_depth, write_png
from opnet.paths import REPO_ROOT
from conftest import compose_cfg

CAMERA = {"fx": 180.0, "fy": 181.0, "cx": 70.5, "cy": 60.25, "clip_start": 0.5, "clip_end": 1.5}


def _scene_depth(h: int = 120, w: int = 150) -> np.ndarray:
    depth = np.full((h, w), 1.2, np.float32)
    depth[40:70, 50:90] = 1.05
    return depth


def _camera_args(values: dict[str, float]) -> list[str]:
    return [f"camera.{k}={v}" for k, v in values.items()]


def _run(checkpoint: Path, inp: Path, out: Path, *extra: str) -> int:
    return predict_cli.run(compose_cfg("predict", [f"ckpt={checkpoint}", f"input={inp}", f"out={out}", *extra]))


def test_png_with_intrinsics_on_the_command_line(checkpoint: Path, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    png = tmp_path / "frame.png"  # no camera file anywhere above it
    write_png(png, encode_depth(_scene_depth(), CAMERA["clip_start"], CAMERA["clip_end"]))
    assert _run(checkpoint, png, tmp_path / "out", *_camera_args(CAMERA)) == 0
    doc = json.loads((tmp_path / "out" / "frame.json").read_text())
    assert doc["camera"]["fx"] == 180.0 and doc["camera"]["cy"] == 60.25 and doc["camera"]["width"] == 150
    printed = capsys.readouterr().out
    assert "camera: fx=180 fy=181 cx=70.5 cy=60.25 150x120" in printed and "(from command line)" in printed
    assert "1 of 1 predictions written" in printed


def test_millimetre_png_with_a_camera_yaml(checkpoint: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A RealSense-style 16-bit PNG in millimetres (0 = no depth), the camera in a small YAML."""
    mm = np.round(_scene_depth() * 1000).astype(np.uint16)
    mm[:5] = 0
    write_png(tmp_path / "mm.png", mm)
    yaml_file = tmp_path / "camera.yaml"
    yaml_file.write_text("".join(f"{k}: {v}\n" for k, v in CAMERA.items()) + "depth_scale: 0.001\n")
    assert _run(checkpoint, tmp_path / "mm.png", tmp_path / "out", f"camera.file={yaml_file}") == 0
    printed = capsys.readouterr().out
    assert "depth = value x 0.001 m" in printed and str(yaml_file) in printed
    # the same frame coded between the clip planes gives the same poses
    write_png(tmp_path / "coded.png", encode_depth(np.where(mm == 0, np.nan, mm / 1000.0).astype(np.float32), 0.5, 1.5))
    assert _run(checkpoint, tmp_path / "coded.png", tmp_path / "out", *_camera_args(CAMERA)) == 0
    a = json.loads((tmp_path / "out" / "mm.json").read_text())["poses"]
    b = json.loads((tmp_path / "out" / "coded.json").read_text())["poses"]
    assert len(a) == len(b) and all(np.allclose(p["t"], q["t"], atol=2e-3) for p, q in zip(a, b))


def test_conflicts_are_errors_naming_both(checkpoint: Path, tiny_dataset: Path, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    png = sorted((tiny_dataset / "p_depth").rglob("*.png"))[0]
    params = tiny_dataset / "parameter.json"
    assert _run(checkpoint, png, tmp_path / "o", "camera.fx=1000") == 1  # was: silently ignored
    printed = capsys.readouterr().out
    assert f"error: {png}: camera.fx=1000 (command line) conflicts with fx=" in printed and f"of {params}" in printed
    assert not (tmp_path / "o" / f"{png.stem}.json").exists() and "no predictions written" in printed
    # the same value as the file's is no conflict
    fx = read_parameters(params).camera().fx
    assert _run(checkpoint, png, tmp_path / "o2", f"camera.fx={fx}") == 0
    # a camera YAML against the command line
    yaml_file = tmp_path / "cam.yaml"
    yaml_file.write_text("fx: 200\n")
    with pytest.raises(ValueError, match=r"camera.fx: 300 on the command line conflicts with 200 in .*cam.yaml"):
        _run(checkpoint, png, tmp_path / "o3", f"camera.file={yaml_file}", "camera.fx=300")


@pytest.mark.parametrize(("override", "message"), [
    ("camera.clip_end=1500", "millimetres"), ("camera.fx=-5", "must be positive"), ("camera.fx=abc", "not a number"),
    ("camera.depth_scale=2", "metres per depth unit"), ("camera.clip_start=2.0", "0 < clip_start < clip_end"),
])  # fmt: skip
def test_implausible_camera_values_are_refused(override: str, message: str, checkpoint: Path, tmp_path: Path) -> None:
    png = tmp_path / "frame.png"
    write_png(png, encode_depth(_scene_depth(), 0.5, 1.5))
    values = _camera_args({k: v for k, v in CAMERA.items() if f"camera.{k}=" not in override})
    with pytest.raises(ValueError, match=message):
        _run(checkpoint, png, tmp_path / "o", *values, override)


def test_missing_intrinsics_name_the_keys(checkpoint: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    png = tmp_path / "frame.png"
    write_png(png, encode_depth(_scene_depth(), 0.5, 1.5))
    assert _run(checkpoint, png, tmp_path / "o", "camera.fx=100") == 1  # counted as failed, nothing written
    assert not list((tmp_path / "o").rglob("*.json"))
    assert "missing camera.fy, camera.cx, camera.cy, camera.clip_start, camera.clip_end" in capsys.readouterr().out


def test_dataset_folder_outputs_mirror_the_inputs_and_never_overwrite(checkpoint: Path, tiny_dataset: Path,
                                                                      tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Every cycle has 001_depth_uint16.png ...: named by stem only, most results were lost."""
    inputs = sorted((tiny_dataset / "p_depth").rglob("*.png"))
    assert len({p.name for p in inputs}) < len(inputs)  # the case: equal names in different folders
    out = tmp_path / "out"
    assert _run(checkpoint, tiny_dataset / "p_depth", out) == 0
    written = sorted(p for p in out.rglob("*.json") if p.parent != out / "results")
    assert len(written) == len(inputs) == len(list((out / "results").glob("*.json")))
    assert {p.relative_to(out).with_suffix("") for p in written} == {
        p.relative_to(tiny_dataset / "p_depth").with_suffix("") for p in inputs}
    assert f"{len(inputs)} of {len(inputs)} predictions written" in capsys.readouterr().out
    before = written[0].read_bytes()
    with pytest.raises(ValueError, match="predictions exist already; pass overwrite=true"):
        _run(checkpoint, tiny_dataset / "p_depth", out)
    assert written[0].read_bytes() == before
    assert _run(checkpoint, tiny_dataset / "p_depth", out, "overwrite=true") == 0


def test_output_onto_the_input_is_refused(checkpoint: Path, tmp_path: Path) -> None:
    png = tmp_path / "frame.png"
    write_png(png, encode_depth(_scene_depth(), 0.5, 1.5))
    with pytest.raises(ValueError, match="would overwrite an input image"):
        _run(checkpoint, png, tmp_path, *_camera_args(CAMERA), "overwrite=true")


def test_fifo_in_the_input_folder_is_skipped_not_waited_for(checkpoint: Path, tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "in"
    folder.mkdir()
    np.save(folder / "a.npy", _scene_depth())
    os.mkfifo(folder / "b.png")  # nobody ever writes into it: reading it would block forever
    assert _run(checkpoint, folder, tmp_path / "out", *_camera_args(CAMERA)) == 1
    printed = capsys.readouterr().out
    assert "b.png: not a regular file (a FIFO)" in printed and "1 of 2 predictions written" in printed


def test_nothing_written_is_not_reported_as_written(checkpoint: Path, tmp_path: Path) -> None:
    folder = tmp_path / "in"
    folder.mkdir()
    np.save(folder / "a.npy", np.ones((4, 4, 3), np.float32))
    proc = subprocess.run(
        [sys.executable, str(REPO_ROOT / "predict.py"), f"ckpt={checkpoint}", f"input={folder}", f"out={tmp_path / 'o'}",
         f"hydra.run.dir={tmp_path / 'h'}", *_camera_args(CAMERA)],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 1
    assert "no predictions written" in proc.stdout and "predictions written to" not in proc.stdout
    assert "Traceback" not in proc.stdout + proc.stderr


def test_help_shows_only_prediction_options() -> None:
    proc = subprocess.run([sys.executable, str(REPO_ROOT / "predict.py"), "--help"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0
    assert "camera.fx" in proc.stdout and "depth_scale" in proc.stdout and "overwrite" in proc.stdout
    for training_only in ("optim", "trainer", "augmentation", "parameterization:"):
        assert training_only not in proc.stdout


def test_outputs_for_viewers_and_the_evaluator(checkpoint: Path, tiny_dataset: Path, tmp_path: Path) -> None:
    """A PLY of the scene and the posed models, and results/<scene>.json in the Siléane results
    format under the scene names of the dataset (cycle_XXXX_NNN)."""
    import trimesh

    from opnet.datasets.sileane_json import read_results_json

    png = sorted((tiny_dataset / "p_depth").rglob("*.png"))[-1]
    assert _run(checkpoint, tiny_dataset / "p_depth", tmp_path / "out", "min_score=0") == 0
    name = f"{png.parent.name}_{png.name[:3]}"
    hyps = read_results_json(tmp_path / "out" / "results" / f"{name}.json")
    doc = json.loads((tmp_path / "out" / png.parent.name / f"{png.stem}.json").read_text())
    assert len(hyps) == len(doc["poses"]) and "poses_world" not in doc  # IPA: camera frame only
    cloud = trimesh.load(tmp_path / "out" / png.parent.name / f"{png.stem}.ply")
    assert len(cloud.vertices) > 1000 and cloud.colors.shape[1] == 4


def test_real_sileane_frame(checkpoint: Path, shared: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The real structured-light frame with its own camera file: JSON (camera and world frame),
    results/depth.json, overlay PNG and PLY (the model is a tiny zbracket one: no claim on what it finds)."""
    frame = shared / "data" / "sileane_real_frame"
    assert _run(checkpoint, frame, tmp_path / "out") == 0
    assert "fx=4507.08" in capsys.readouterr().out
    doc = json.loads((tmp_path / "out" / "depth.json").read_text())
    assert len(doc["poses_world"]) == len(doc["poses"])  # camera = world in this file
    for a, b in zip(doc["poses"], doc["poses_world"]):
        assert np.allclose(a["t"], b["t"]) and np.allclose(a["R"], b["R"])
    for suffix in (".png", ".ply"):
        assert (tmp_path / "out" / f"depth{suffix}").stat().st_size > 1000
    assert (tmp_path / "out" / "results" / "depth.json").is_file()


def test_equal_stems_in_different_folders_keep_apart_in_results(checkpoint: Path, tmp_path: Path) -> None:
    for sub in ("left", "right"):
        (tmp_path / "in" / sub).mkdir(parents=True)
        np.save(tmp_path / "in" / sub / "frame.npy", _scene_depth())
    assert _run(checkpoint, tmp_path / "in", tmp_path / "out", *_camera_args(CAMERA)) == 0
    assert sorted(p.name for p in (tmp_path / "out" / "results").glob("*.json")) == ["left_frame.json", "right_frame.json"]


def test_png_whose_size_differs_from_its_camera_file_is_refused(checkpoint: Path, tmp_path: Path,
                                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """A depth PNG beside a camera file of another size is an error naming both (it was silently rescaled)."""
    frame = tmp_path / "frame"
    frame.mkdir()
    (frame / "camera_params.txt").write_text("width\t1296\nheight\t1024\nfu\t4507.08\nfv\t4507.08\ncu\t399.557\n"
                                             "cv\t556.6\nclip_start\t0.76\nclip_end\t0.93\nlocation\t0 0 0\nrotation\t1 0 0 0\n")
    write_png(frame / "depth.PNG", encode_depth(_scene_depth(80, 100), 0.5, 1.5))
    assert _run(checkpoint, frame, tmp_path / "out") == 1
    captured = capsys.readouterr()
    assert "depth.PNG: image is 100x80 but its camera" in captured.out + captured.err
    assert "camera_params.txt is 1296x1024" in captured.out + captured.err
    assert not (tmp_path / "out" / "depth.json").exists()
