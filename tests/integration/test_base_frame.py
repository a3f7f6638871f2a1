"""Poses in the robot's base frame: the camera's ``T_base_cam`` from a camera YAML or recorded in the
checkpoint (its cell's) and the ONNX export; predict.py and ``python -m opnet.deploy`` write the same
base-frame poses beside the camera-frame ones, and a ``T_base_cam`` that is not a rigid transform is
refused in one line naming its file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from conftest import compose_cfg
from opnet.cli import predict as predict_cli
from opnet.cli.build import load_checkpoint
from opnet.cli.console import guarded
from opnet.deploy.export import export_onnx
from opnet.geometry.frames import camera_to_base
from opnet.run_settings import CHECKPOINT_KEY

pytest.importorskip("onnxruntime")
from opnet.deploy.__main__ import main as deploy_main  # noqa: E402
from opnet.deploy.runtime import OnnxPoseEstimator  # noqa: E402


def _pose(deg: float, axis: list[float], t: list[float]) -> np.ndarray:
    """A rigid transform: a turn of ``deg`` about ``axis`` and the translation ``t`` (metres)."""
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    th = np.radians(deg)
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K
    T[:3, 3] = t
    return T


#: the training camera's pose over the robot's base (recorded in the checkpoint) and another one (a camera YAML's)
T_CELL = _pose(160.0, [0.3, 1.0, 0.2], [0.45, -0.20, 1.30])
T_FILE = _pose(-120.0, [1.0, -0.4, 0.5], [-0.30, 0.60, 0.95])


@pytest.fixture(scope="module")
def cell_model(checkpoint: Path, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The tiny checkpoint with ``T_CELL`` recorded and every cell a hypothesis (threshold 0, averaging
    on), and its ONNX export."""
    folder = tmp_path_factory.mktemp("cell_model")
    raw = torch.load(checkpoint, map_location="cpu", weights_only=True)
    raw[CHECKPOINT_KEY]["T_base_cam"] = T_CELL.tolist()
    raw[CHECKPOINT_KEY]["decoding"] = {**raw[CHECKPOINT_KEY]["decoding"], "threshold": 0.0, "score": "p*v",
                                       "averaging": {"eps": 0.5, "min_samples": 1, "cluster_score": "sum",
                                                     "keep_noise": True}}
    ckpt = folder / "cell.ckpt"
    torch.save(raw, ckpt)
    system, cfg = load_checkpoint(ckpt)
    assert np.allclose(system.settings.T_base_cam, T_CELL)
    model = folder / "cell.onnx"
    meta = export_onnx(system, cfg, ckpt, model)
    assert np.allclose(meta["T_base_cam"], T_CELL)
    return ckpt, model


@pytest.fixture(scope="module")
def exact_cell_model(cell_model: tuple[Path, Path], tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """``cell_model`` whose network's output is its head's bias alone (the head's weights zero; the bias drawn
    per channel): both runtimes compute that output exactly, so what follows the network (decoding, the move to
    the base frame) is all that can part their poses."""
    folder = tmp_path_factory.mktemp("exact_cell_model")
    raw = torch.load(cell_model[0], map_location="cpu", weights_only=True)
    weight, bias = "backbone.head.2.weight", "backbone.head.2.bias"
    raw["state_dict"][weight] = torch.zeros_like(raw["state_dict"][weight])
    raw["state_dict"][bias] = torch.randn(raw["state_dict"][bias].shape, generator=torch.Generator().manual_seed(0))
    ckpt = folder / "exact.ckpt"
    torch.save(raw, ckpt)
    system, cfg = load_checkpoint(ckpt)
    model = folder / "exact.onnx"
    export_onnx(system, cfg, ckpt, model)
    return ckpt, model


def _images(dataset: Path, tmp_path: Path, cycle: str, n: int) -> Path:
    """A folder of the first ``n`` depth PNGs of ``cycle`` of ``dataset``, its parameter.json above them."""
    images = tmp_path / "images"
    images.mkdir()
    (images / "parameter.json").write_bytes((dataset / "parameter.json").read_bytes())
    for png in sorted((dataset / "p_depth" / cycle).glob("*.png"))[:n]:
        (images / png.name).write_bytes(png.read_bytes())
    return images


def _run_both(ckpt: Path, model: Path, images: Path, out: Path, camera: Path | None) -> tuple[dict, dict]:
    """predict.py and the ONNX runtime on ``images`` (no refinement); their pose files by name."""
    given = [] if camera is None else [f"camera.file={camera}"]
    assert predict_cli.run(compose_cfg("predict", [f"ckpt={ckpt}", f"input={images}", f"out={out / 'torch'}",
                                                   "refine=none", *given])) == 0
    argv = [str(model), str(images), "--out", str(out / "onnx"), "--no-refine"]
    assert deploy_main(argv + ([] if camera is None else ["--camera", str(camera)])) == 0
    read = lambda folder: {p.stem: json.loads(p.read_text()) for p in sorted(folder.glob("*.json"))}  # noqa: E731
    return read(out / "torch"), read(out / "onnx")


def _by_score(poses: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    order = np.argsort([-p["score"] for p in poses], kind="stable")
    return (np.array([poses[i]["R"] for i in order]), np.array([poses[i]["t"] for i in order]),
            np.array([poses[i]["score"] for i in order]))


@pytest.mark.parametrize("source", ["checkpoint", "camera file"])
def test_predict_and_the_onnx_runtime_write_the_same_base_frame_poses(cell_model: tuple[Path, Path], tiny_dataset: Path,
                                                                      tmp_path: Path, source: str) -> None:
    ckpt, model = cell_model
    images = _images(tiny_dataset, tmp_path, "cycle_0001", 2)
    camera = None
    expected = T_CELL
    if source == "camera file":  # a camera YAML of T_base_cam alone: the intrinsics stay parameter.json's
        camera = tmp_path / "camera.yaml"
        camera.write_text(yaml.safe_dump({"T_base_cam": T_FILE.tolist()}))
        expected = T_FILE
    by_torch, by_onnx = _run_both(ckpt, model, images, tmp_path, camera)
    assert sorted(by_torch) == sorted(by_onnx) and len(by_torch) == 2
    for name, doc in by_torch.items():
        other = by_onnx[name]
        for d in (doc, other):
            assert np.allclose(d["T_base_cam"], expected, atol=1e-12)
            R_cam, t_cam, score = _by_score(d["poses"])
            R_base, t_base, score_base = _by_score(d["poses_base"])
            assert len(score) > 0 and np.array_equal(score, score_base)
            R_want, t_want = camera_to_base(R_cam, t_cam, expected)
            assert np.abs(R_base - R_want).max() < 1e-12 and np.abs(t_base - t_want).max() < 1e-12
        # the two runtimes' networks (fp32 in PyTorch and in ONNX Runtime) differ by ~1e-5 in a pose; the move to
        # the base frame adds nothing to it: the base-frame poses differ by the camera-frame difference, turned
        R_a, t_a, s_a = _by_score(doc["poses_base"])
        R_b, t_b, s_b = _by_score(other["poses_base"])
        Rc_a, tc_a, _ = _by_score(doc["poses"])
        Rc_b, tc_b, _ = _by_score(other["poses"])
        assert len(s_a) == len(s_b) and np.abs(s_a - s_b).max() < 1e-6
        assert np.abs(R_a - R_b).max() < 1e-4 and np.abs(t_a - t_b).max() < 1e-4  # as in the camera frame (metres)
        assert np.abs(R_a - R_b - expected[:3, :3] @ (Rc_a - Rc_b)).max() < 1e-6
        assert np.abs((t_a - t_b) - (tc_a - tc_b) @ expected[:3, :3].T).max() < 1e-6
    assert OnnxPoseEstimator(model).T_base_cam is not None


def test_with_the_same_network_output_both_runtimes_write_the_same_base_frame_poses_to_1e6(
        exact_cell_model: tuple[Path, Path], tiny_dataset: Path, tmp_path: Path) -> None:
    ckpt, model = exact_cell_model
    by_torch, by_onnx = _run_both(ckpt, model, _images(tiny_dataset, tmp_path, "cycle_0002", 1), tmp_path, None)
    (name,) = by_torch
    doc, other = by_torch[name], by_onnx[name]
    R_a, t_a, s_a = _by_score(doc["poses_base"])
    R_b, t_b, s_b = _by_score(other["poses_base"])
    assert len(s_a) > 1 and len(s_a) == len(s_b) and np.abs(s_a - s_b).max() < 1e-6
    assert np.abs(R_a - R_b).max() < 1e-6 and np.abs(t_a - t_b).max() < 1e-6  # metres
    R_want, t_want = camera_to_base(*_by_score(doc["poses"])[:2], T_CELL)
    assert np.abs(R_a - R_want).max() < 1e-12 and np.abs(t_a - t_want).max() < 1e-12


def test_predict_without_a_base_pose_writes_camera_poses_only(checkpoint: Path, tiny_dataset: Path, tmp_path: Path) -> None:
    png = sorted((tiny_dataset / "p_depth" / "cycle_0001").glob("*.png"))[0]
    assert predict_cli.run(compose_cfg("predict", [f"ckpt={checkpoint}", f"input={png}", f"out={tmp_path}",
                                                   "refine=none"])) == 0
    doc = json.loads((tmp_path / f"{png.stem}.json").read_text())
    assert "poses" in doc and "poses_base" not in doc and "T_base_cam" not in doc


@pytest.mark.parametrize("matrix, problem", [
    ((2 * np.eye(4)).tolist(), "last row"),
    ([[2, 0, 0, 0], [0, 2, 0, 0], [0, 0, 2, 1.5], [0, 0, 0, 1]], "not a rigid transform"),
    (np.diag([1.0, 1.0, -1.0, 1.0]).tolist(), "reflection"),
    ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], "4 x 4"),
])
def test_a_non_rigid_T_base_cam_is_refused_in_one_line_naming_the_file(cell_model: tuple[Path, Path], tiny_dataset: Path,
                                                                       tmp_path: Path, capsys: pytest.CaptureFixture,
                                                                       matrix: list, problem: str) -> None:
    ckpt, model = cell_model
    camera = tmp_path / "camera.yaml"
    camera.write_text(yaml.safe_dump({"fx": 500.0, "fy": 500.0, "T_base_cam": matrix}))
    png = sorted((tiny_dataset / "p_depth" / "cycle_0001").glob("*.png"))[0]
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        guarded(predict_cli.run, compose_cfg("predict", [f"ckpt={ckpt}", f"input={png}", f"out={tmp_path / 'a'}",
                                                         f"camera.file={camera}"]))
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {camera}: T_base_cam") and problem in err and "\n" not in err, err
    assert deploy_main([str(model), str(png), "--out", str(tmp_path / "b"), "--camera", str(camera)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {camera}: T_base_cam") and problem in err and "\n" not in err, err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_a_cells_T_base_cam_is_recorded_in_the_run_settings() -> None:
    from opnet.run_settings import RunSettings

    settings = RunSettings.from_training_config({"object": {"name": "zbracket"}, "cell": {"T_base_cam": T_CELL.tolist()}})
    assert np.allclose(settings.T_base_cam, T_CELL)
    assert RunSettings.from_dict(settings.to_dict()) == settings
    assert "T_base_cam" not in RunSettings().to_dict()  # none recorded: the entry as before
    with pytest.raises(ValueError, match=r"^run\.ckpt: cell\.T_base_cam's rotation is no rotation \(a reflection"):
        RunSettings.from_training_config({"cell": {"T_base_cam": np.diag([1.0, -1.0, 1.0, 1.0]).tolist()}}, "run.ckpt")


def test_the_robot_loop_of_the_deployment_page_runs_and_picks_the_runtimes_best_part(
        cell_model: tuple[Path, Path], tiny_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture,
        monkeypatch: pytest.MonkeyPatch) -> None:
    """docs/deployment.md's Python loop, run as printed in a folder of its model.onnx, camera.yaml (with
    T_base_cam) and frames/*.npy: one line per frame, the best-scored part where the runtime's poses_base put it."""
    import re

    from opnet.datasets.ipa import IPADataset
    from opnet.paths import REPO_ROOT

    page = (REPO_ROOT / "docs" / "deployment.md").read_text()
    code = re.search(r"### Poses in the robot's base frame\n.*?```python\n(.*?)```", page, re.DOTALL).group(1)
    _, model = cell_model
    (tmp_path / "model.onnx").write_bytes(model.read_bytes())
    records = [IPADataset(tiny_dataset)[i] for i in (3, 9)]
    cam = records[0].camera
    (tmp_path / "camera.yaml").write_text(yaml.safe_dump(
        {**{k: float(getattr(cam, k)) for k in ("fx", "fy", "cx", "cy", "clip_start", "clip_end")},
         "T_base_cam": T_FILE.tolist()}))
    (tmp_path / "frames").mkdir()
    for i, r in enumerate(records):
        np.save(tmp_path / "frames" / f"frame{i}.npy", r.depth.astype(np.float32))
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    exec(compile(code, "docs/deployment.md", "exec"), {"__name__": "robot_loop"})  # noqa: S102 - the page's own code
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split(":")[0] for line in lines] == ["frame0.npy", "frame1.npy"], lines
    assert deploy_main([str(tmp_path / "model.onnx"), str(tmp_path / "frames"), "--out", str(tmp_path / "out"),
                        "--camera", str(tmp_path / "camera.yaml")]) == 0
    for i, line in enumerate(lines):
        poses = json.loads((tmp_path / "out" / f"frame{i}.json").read_text())["poses_base"]
        best = max(poses, key=lambda p: p["score"])
        picked = json.loads(line.split("pick at ")[1].split(" m,")[0])
        assert np.allclose(picked, np.round(best["t"], 4), atol=1e-9), (line, best["t"])
        assert f"score {best['score']:.3f}" in line


def test_the_training_camera_is_the_default_of_an_image_given_without_one(
        cell_model: tuple[Path, Path], tiny_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A .npy of the training camera's size with no camera given: predict.py and the ONNX runtime take the camera
    the checkpoint and the export record (the dataset's); an image of another size is refused naming both sizes."""
    from opnet.datasets.camera_file import dataset_camera
    from opnet.datasets.ipa import IPADataset

    ckpt, model = cell_model
    camera = dataset_camera(tiny_dataset)
    want = [float(getattr(camera, k)) for k in ("fx", "fy", "cx", "cy", "width", "height", "clip_start", "clip_end")]
    system, _ = load_checkpoint(ckpt)
    assert list(system.settings.camera) == want
    assert list(OnnxPoseEstimator(model).camera) == want
    frames = tmp_path / "frames"
    frames.mkdir()
    np.save(frames / "frame.npy", IPADataset(tiny_dataset)[4].depth.astype(np.float32))
    capsys.readouterr()
    by_torch, by_onnx = _run_both(ckpt, model, frames, tmp_path, None)
    printed = capsys.readouterr().out
    assert f"(from the training camera of {ckpt})" in printed and f"(from the training camera of {model})" in printed
    for doc in (by_torch["frame"], by_onnx["frame"]):
        assert [float(doc["camera"][k]) for k in ("fx", "fy", "cx", "cy", "width", "height")] == want[:6]
        assert len(doc["poses"]) > 0
    other = tmp_path / "other"
    other.mkdir()
    np.save(other / "small.npy", np.full((60, 80), 0.2, np.float32))
    assert predict_cli.run(compose_cfg("predict", [f"ckpt={ckpt}", f"input={other}", f"out={tmp_path / 'o1'}"])) == 1
    assert deploy_main([str(model), str(other), "--out", str(tmp_path / "o2")]) == 1
    for line in [x for x in capsys.readouterr().out.splitlines() if x.startswith("error:")]:
        assert f"{other / 'small.npy'}: no camera file above it and no intrinsics given; the training camera of" in line
        assert "is 128x128, the image 80x60" in line
