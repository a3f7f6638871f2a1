"""Nothing lost, nothing stale: writers refuse a non-empty target unless told to
replace it and then replace it whole; concurrent runs into one output folder cannot lose files;
output names are unique within a run; an output onto an input is refused; a generation cut short
fails the dataset check."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import compose_cfg
from opnet.cli import export as export_cli
from opnet.cli import predict as predict_cli
from opnet.datasets.bop import main as bop_main
from opnet.datasets.check import check_dataset
from opnet.datasets.ipa import scene_paths
from opnet.deploy.__main__ import main as deploy_main
from opnet.metrics.records import HypothesisSet
from opnet.paths import REPO_ROOT

CAMERA_ARGS = ["--fx", "100", "--fy", "100", "--cx", "3.5", "--cy", "2.5", "--clip-start", "0.5", "--clip-end", "1.5"]


def _npy(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    np.save(path, np.full((6, 8), 1.0, np.float32))
    return path


class _FakeEstimator:
    """Stands in for the ONNX model: the output handling of ``python -m opnet.deploy`` is tested."""

    meta = {"object": "box"}
    on_predict = None  # a hook run inside the first prediction
    clip = trained_clip = None  # each camera's own planes
    T_base_cam = camera = None  # no base pose, no training camera recorded

    def __init__(self, path: Path, threads: int | None = None, **settings: object) -> None:  # icp=, roi=
        self.path = Path(path)

    def predict(self, depth: np.ndarray, camera: object) -> HypothesisSet:
        hook, _FakeEstimator.on_predict = _FakeEstimator.on_predict, None
        if hook is not None:
            hook()
        return HypothesisSet(np.eye(3)[None], np.array([[0.0, 0.0, 1.0]]), np.array([0.9]))


@pytest.fixture
def fake_onnx(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    import opnet.deploy.runtime as runtime

    monkeypatch.setattr(runtime, "OnnxPoseEstimator", _FakeEstimator)
    model = tmp_path / "model.onnx"
    model.write_bytes(b"stand-in")
    return model


# ---------------------------------------------------------------------------------------- BOP writer


def test_bop_writer_refuses_a_non_empty_target_and_replaces_it_whole(tiny_dataset: Path, tmp_path: Path,
                                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "bop"
    assert bop_main([str(tiny_dataset), str(out), "--obj-id", "3"]) == 0
    first = sorted(p.relative_to(out) for p in out.rglob("*"))
    ply = (out / "models" / "obj_000003.ply").read_bytes()
    capsys.readouterr()
    assert bop_main([str(tiny_dataset), str(out), "--obj-id", "1", "--split", "other"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {out}: ") and "--overwrite" in err and "\n" not in err
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == first  # nothing written
    assert (out / "models" / "obj_000003.ply").read_bytes() == ply
    # replaced as a whole: nothing of the first dataset is left, nothing temporary beside it
    assert bop_main([str(tiny_dataset), str(out), "--obj-id", "1", "--split", "other", "--overwrite"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["models", "other"]
    assert set(json.loads((out / "models" / "models_info.json").read_text())) == {"1"}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bop"]


def test_bop_writer_refuses_to_write_over_its_input(tiny_dataset: Path, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    ipa = tmp_path / "ipa"
    shutil.copytree(tiny_dataset, ipa)
    before = sorted(p.relative_to(ipa) for p in ipa.rglob("*"))
    for out in (ipa, ipa.parent):
        assert bop_main([str(ipa), str(out), "--overwrite"]) == 2
        assert "input" in capsys.readouterr().err
    assert sorted(p.relative_to(ipa) for p in ipa.rglob("*")) == before


# ---------------------------------------------------------------------------- concurrent runs, names


def _deploy(model: Path, inp: Path, out: Path, *extra: str) -> int:
    return deploy_main([str(model), str(inp), "--out", str(out), *CAMERA_ARGS, *extra])


def test_deploy_run_into_a_folder_another_run_writes_is_refused(fake_onnx: Path, tmp_path: Path,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Both runs used to pass the existence check before either wrote, and both said "written"."""
    a, b = _npy(tmp_path / "in_a" / "x.npy"), _npy(tmp_path / "in_b" / "x.npy")
    out = tmp_path / "out"
    second: list[int] = []
    _FakeEstimator.on_predict = lambda: second.append(_deploy(fake_onnx, b, out))
    assert _deploy(fake_onnx, a, out) == 0
    assert second == [2]
    err = capsys.readouterr().err
    assert f"error: {out}: another run (pid {os.getpid()}) is writing into this folder" in err  # this process's
    assert json.loads((out / "x.json").read_text())["image"] == str(a)
    assert sorted(p.name for p in out.iterdir()) == ["results", "x.json"]  # the lock is gone
    assert _deploy(fake_onnx, b, out) == 2  # afterwards: the outputs exist, overwrite is needed
    assert "exist already" in capsys.readouterr().err


def test_deploy_output_names_are_unique_within_a_run(fake_onnx: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    inp = tmp_path / "in"
    for rel in ("a/x.npy", "b/x.npy", "a_x.npy"):
        _npy(inp / rel)
    assert _deploy(fake_onnx, inp, tmp_path / "out") == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "a_x.json" in err and "rename one of them" in err
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").rglob("*.json"))
    # a pose file that would be a results file of another image
    inp2 = tmp_path / "in2"
    _npy(inp2 / "results" / "y.npy")
    assert _deploy(fake_onnx, inp2, tmp_path / "out2") == 2
    assert "results/y.json" in capsys.readouterr().err


def test_deploy_output_onto_an_input_is_refused(fake_onnx: Path, tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    x = _npy(tmp_path / "x.npy")
    for out in (x, fake_onnx, x / "sub"):
        assert _deploy(fake_onnx, x, out) == 2
        assert str(out) in capsys.readouterr().err
    assert fake_onnx.read_bytes() == b"stand-in" and np.load(x).shape == (6, 8)


def test_predict_run_into_a_folder_another_run_writes_is_refused(checkpoint: Path, tmp_path: Path,
                                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    a, b = _npy(tmp_path / "in_a" / "x.npy"), _npy(tmp_path / "in_b" / "x.npy")
    out = tmp_path / "out"
    camera = ["camera.fx=100", "camera.fy=100", "camera.cx=3.5", "camera.cy=2.5", "camera.clip_start=0.5",
              "camera.clip_end=1.5"]

    def run(inp: Path) -> int:
        return predict_cli.run(compose_cfg("predict", [f"ckpt={checkpoint}", f"input={inp}", f"out={out}", *camera]))

    errors: list[str] = []
    real = predict_cli.write_prediction

    def write_and_race(*args, **kwargs):
        if not errors:
            try:
                run(b)
                errors.append("")
            except ValueError as e:
                errors.append(str(e))
        return real(*args, **kwargs)

    monkeypatch.setattr(predict_cli, "write_prediction", write_and_race)
    assert run(a) == 0
    assert errors[0].startswith(f"{out}: another run (pid {os.getpid()}) is writing into this folder")
    assert "\n" not in errors[0]
    assert json.loads((out / "x.json").read_text())["image"] == str(a)


def test_predict_out_onto_an_input_file_is_refused(checkpoint: Path, tmp_path: Path) -> None:
    x = _npy(tmp_path / "x.npy")
    for out in (x, x / "sub", checkpoint):
        with pytest.raises(ValueError, match=f"{out}: "):
            predict_cli.run(compose_cfg("predict", [f"ckpt={checkpoint}", f"input={x}", f"out={out}",
                                                    "camera.fx=100", "camera.fy=100", "camera.cx=3.5", "camera.cy=2.5",
                                                    "camera.clip_start=0.5", "camera.clip_end=1.5"]))
    assert np.load(x).shape == (6, 8)


# -------------------------------------------------------------------------------------------- export


def test_export_onto_its_checkpoint_is_refused(checkpoint: Path, tmp_path: Path) -> None:
    ckpt = tmp_path / "X.ckpt"
    shutil.copy(checkpoint, ckpt)
    data = ckpt.read_bytes()
    (tmp_path / "link.ckpt").symlink_to(ckpt)
    for out in (ckpt, tmp_path / "link.ckpt", tmp_path / "." / "X.ckpt"):
        with pytest.raises(ValueError, match="the checkpoint itself"):
            export_cli.run(compose_cfg("export", [f"ckpt={ckpt}", f"out={out}", "overwrite=true"]))
    assert ckpt.read_bytes() == data
    proc = subprocess.run([sys.executable, "export.py", f"ckpt={ckpt}", f"out={ckpt}", "overwrite=true"],
                          cwd=REPO_ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and proc.stderr.strip().startswith("error:") and "X.ckpt" in proc.stderr
    assert "\n" not in proc.stderr.strip() and ckpt.read_bytes() == data


# ---------------------------------------------------------------------------------- partial datasets


def _copy(dataset: Path, dest: Path) -> Path:
    shutil.copytree(dataset, dest, ignore=shutil.ignore_patterns("cache_*"))
    return dest


def test_generation_cut_short_fails_the_check(tiny_dataset: Path, tmp_path: Path) -> None:
    """A full disk: the last cycle stopped after scene 002, the cycle before lost its depth PNG."""
    data = _copy(tiny_dataset, tmp_path / "d")
    assert check_dataset(data, fast=True).ok
    for n in (3, 4):
        for path in scene_paths(data, 3, n).values():
            path.unlink()
    scene_paths(data, 2, 4)["depth"].unlink()
    for fast in (True, False):
        report = check_dataset(data, fast=fast)
        text = "\n".join(map(str, report.problems))
        assert str(scene_paths(data, 3, 3)["csv"]) in text and str(scene_paths(data, 3, 4)["csv"]) in text, text
        assert str(scene_paths(data, 2, 4)["depth"]) in text, text
    shutil.rmtree(data / "gt" / "cycle_0003")
    shutil.rmtree(data / "p_depth" / "cycle_0003")
    report = check_dataset(data, fast=True)
    assert any("cycle_0003" in str(p) and "number_cycles" in str(p) for p in report.problems), report.problems
    proc = subprocess.run([sys.executable, "-m", "opnet.datasets.check", str(data), "--fast"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1 and "cycle_0003" in proc.stdout


def test_empty_and_truncated_pngs_of_a_generation_fail_the_check(tiny_dataset: Path, tmp_path: Path) -> None:
    data = _copy(tiny_dataset, tmp_path / "d")
    seg, depth = scene_paths(data, 1, 2)["segmentation"], scene_paths(data, 0, 1)["depth"]
    seg.write_bytes(b"")
    depth.write_bytes(depth.read_bytes()[:-40])
    for fast in (True, False):
        text = "\n".join(map(str, check_dataset(data, fast=fast).problems))
        assert str(seg) in text and str(depth) in text, text


def test_generation_json_without_drops_names_the_key(tiny_dataset: Path, tmp_path: Path) -> None:
    data = _copy(tiny_dataset, tmp_path / "d")
    doc = json.loads((data / "generation.json").read_text())
    del doc["drops"]
    (data / "generation.json").write_text(json.dumps(doc))
    report = check_dataset(data, fast=True)
    assert any("generation.json" in str(p) and "'drops'" in str(p) for p in report.problems), report.problems
