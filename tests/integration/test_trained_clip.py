"""train.py records the training scenes' clip planes in its checkpoints (``trained_clip`` of the settings
entry; of the run config in checkpoints written before it), and
predict.py, the ONNX export and the torch-free runtime normalize a new image's depth with them
whatever planes its camera gives (``clip=camera`` / ``--camera-clip``: the camera's own)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import compose_cfg

from opnet.cli import eval as eval_cli
from opnet.cli import predict as predict_cli
from opnet.cli.build import load_checkpoint, read_checkpoint
from opnet.datasets.ipa import IPADataset
from opnet.deploy.export import export_onnx
from opnet.geometry.camera import with_clip
from opnet.paths import REPO_ROOT
from opnet.run_settings import CHECKPOINT_KEY


def _planes(tiny_dataset: Path) -> tuple[float, float]:
    camera = IPADataset(tiny_dataset)[0].camera
    return camera.clip_start, camera.clip_end


def _predict(ckpt: Path, tiny_dataset: Path, out: Path, clip: str, capsys) -> tuple[list, str]:
    """predict.py on a scene of ``tiny_dataset`` saved as .npy, with a camera of wider clip planes
    than the training scenes', every cell a hypothesis: its poses and its console."""
    record = IPADataset(tiny_dataset)[5]
    npy = out.parent / "in" / "frame.npy"
    if not npy.exists():
        npy.parent.mkdir(parents=True)
        np.save(npy, record.depth.astype(np.float32))
    c = record.camera
    args = [f"ckpt={ckpt}", f"input={npy}", f"out={out}", f"clip={clip}", "+decoding.threshold=0.0",
            "+decoding.averaging=false", f"camera.fx={c.fx}", f"camera.fy={c.fy}", f"camera.cx={c.cx}",
            f"camera.cy={c.cy}", f"camera.clip_start={c.clip_start / 2}", f"camera.clip_end={c.clip_end + 0.3}"]
    assert predict_cli.run(compose_cfg("predict", args)) == 0
    poses = json.loads((out / f"{npy.stem}.json").read_text())["poses"]
    return poses, capsys.readouterr().out


def test_checkpoints_record_the_training_planes_and_predict_uses_them(checkpoint: Path, tiny_dataset: Path,
                                                                      tmp_path: Path, capsys) -> None:
    planes = _planes(tiny_dataset)
    system, _ = load_checkpoint(checkpoint)
    assert system.settings.input.trained_clip == pytest.approx(planes)
    assert read_checkpoint(checkpoint)[CHECKPOINT_KEY]["trained_clip"] == pytest.approx(list(planes))
    model, said = _predict(checkpoint, tiny_dataset, tmp_path / "model", "model", capsys)
    assert f"clip planes: [{planes[0]:g}, {planes[1]:g}] m (the model's training planes)" in said
    given, _ = _predict(checkpoint, tiny_dataset, tmp_path / "given", f"[{planes[0]},{planes[1]}]", capsys)
    camera, said = _predict(checkpoint, tiny_dataset, tmp_path / "camera", "camera", capsys)
    assert "clip planes: each camera's own" in said
    t = lambda poses: np.array([p["t"] for p in poses])  # noqa: E731
    assert len(model) == len(given) and np.allclose(t(model), t(given))
    assert len(model) != len(camera) or not np.allclose(t(model), t(camera))  # the camera's planes: another input


def test_a_checkpoint_without_planes_or_with_bad_ones(checkpoint: Path, tiny_dataset: Path, tmp_path: Path,
                                                      capsys) -> None:
    ckpt = read_checkpoint(checkpoint)
    del ckpt[CHECKPOINT_KEY]  # written before train.py recorded them: no settings entry, nor planes in its config
    ckpt["hyper_parameters"]["config"].pop("trained_clip", None)
    old = tmp_path / "old.ckpt"
    torch.save(ckpt, old)
    _, said = _predict(old, tiny_dataset, tmp_path / "old", "model", capsys)
    assert "clip planes: each camera's own (the model records no training planes)" in said
    for value, message in (([2.0, 1.0], r"expected 0 < near < far"), ("far", r"expected \[near, far\] in metres")):
        ckpt["hyper_parameters"]["config"]["trained_clip"] = value
        bad = tmp_path / "bad.ckpt"
        torch.save(ckpt, bad)
        with pytest.raises(ValueError, match=rf"{bad}: the checkpoint's config trained_clip=.*{message}"):
            load_checkpoint(bad)


def test_record_trained_clip_reads_the_planes_of_an_old_checkpoints_datasets(checkpoint: Path, tiny_dataset: Path,
                                                                             tmp_path: Path, capsys) -> None:
    from opnet.tools import record_trained_clip as script
    ckpt = read_checkpoint(checkpoint)
    del ckpt[CHECKPOINT_KEY]
    ckpt["hyper_parameters"]["config"].pop("trained_clip", None)
    old = tmp_path / "old.ckpt"
    torch.save(ckpt, old)
    assert script.main([str(old), "--in-place"]) == 0  # the config's data.root: the tiny dataset
    assert tuple(load_checkpoint(old)[1].trained_clip) == pytest.approx(_planes(tiny_dataset))
    assert load_checkpoint(old)[0].settings.input.trained_clip == pytest.approx(_planes(tiny_dataset))
    assert f"{old}: trained_clip [" in capsys.readouterr().out
    assert script.main([str(old), "--write", str(tmp_path / "c.ckpt"), "--data", str(tmp_path / "gone")]) == 2
    assert f"{tmp_path / 'gone'}: training dataset not found" in capsys.readouterr().err
    assert not (tmp_path / "c.ckpt").exists()


def test_eval_warns_when_the_scenes_planes_are_not_the_models(checkpoint: Path, tiny_dataset: Path, tmp_path: Path,
                                                              caplog) -> None:
    ckpt = read_checkpoint(checkpoint)
    ckpt[CHECKPOINT_KEY]["trained_clip"] = [0.4, 1.9]
    other = tmp_path / "other.ckpt"
    torch.save(ckpt, other)
    with caplog.at_level("WARNING"):
        eval_cli.run(compose_cfg("eval", [f"ckpt={other}", f"out={tmp_path / 'ev'}", "examples=0"]))
    planes = _planes(tiny_dataset)
    assert f"the scenes' clip planes [{planes[0]:g}, {planes[1]:g}] m differ from the model's training planes " \
           "[0.4, 1.9] m" in caplog.text
    caplog.clear()
    with caplog.at_level("WARNING"):
        eval_cli.run(compose_cfg("eval", [f"ckpt={checkpoint}", f"out={tmp_path / 'ev2'}", "examples=0"]))
    assert "differ from the model's training planes" not in caplog.text


def test_the_export_carries_the_planes_and_the_runtime_uses_them(checkpoint: Path, tiny_dataset: Path,
                                                                 tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    from opnet.deploy.runtime import OnnxPoseEstimator

    system, cfg = load_checkpoint(checkpoint)
    system.parameterization = system.parameterization.with_decoding(threshold=0.0)
    onnx_path = tmp_path / "model.onnx"
    meta = export_onnx(system, cfg, checkpoint, onnx_path)
    planes = _planes(tiny_dataset)
    assert meta["trained_clip"] == pytest.approx(list(planes))
    record = IPADataset(tiny_dataset)[5]
    wide = with_clip(record.camera, (planes[0] / 2, planes[1] + 0.3))  # a camera file with other planes
    est = OnnxPoseEstimator(onnx_path)
    assert est.clip == pytest.approx(planes)
    assert np.allclose(est.predict(record.depth, wide).t, est.predict(record.depth, record.camera).t)
    own = OnnxPoseEstimator(onnx_path, clip="camera")
    a, b = own.predict(record.depth, wide).t, est.predict(record.depth, wide).t
    assert own.clip is None and (a.shape != b.shape or not np.allclose(a, b))  # the camera's planes: another input
    code = "import sys; sys.modules['torch'] = None\nfrom opnet.deploy.__main__ import main\nsys.exit(main(sys.argv[1:]))"
    folder = tiny_dataset / "p_depth" / "cycle_0001"
    for flags, line in (([], f"clip planes: [{planes[0]:g}, {planes[1]:g}] m (the model's training planes)"),
                        (["--camera-clip"], "clip planes: each camera's own")):
        proc = subprocess.run([sys.executable, "-c", code, str(onnx_path), str(folder), "--out",
                               str(tmp_path / f"out{len(flags)}"), *flags], capture_output=True, text=True, cwd=REPO_ROOT)
        assert proc.returncode == 0 and line in proc.stdout, proc.stdout[-1000:] + proc.stderr[-1000:]
    both = subprocess.run([sys.executable, "-c", code, str(onnx_path), str(folder), "--out", str(tmp_path / "o"),
                           "--camera-clip", "--clip", "1", "2"], capture_output=True, text=True, cwd=REPO_ROOT)
    assert both.returncode == 2 and "not allowed with argument" in both.stderr


def test_eval_normalizes_bop_scenes_with_the_models_planes(checkpoint: Path, tiny_dataset: Path, tmp_path: Path,
                                                           caplog) -> None:
    from opnet.datasets.bop import convert_ipa_to_bop

    split = convert_ipa_to_bop(tiny_dataset, tmp_path / "bop", split="test", obj_id=3)
    planes = _planes(tiny_dataset)
    base = [f"ckpt={checkpoint}", f"data.root={split}", f"data.test_root={split}", "+data.object_id=3",
            "+data.cache=false", "examples=0", "+decoding.threshold=0.0"]
    results = {}
    for name, extra in (("default", []), ("given", [f"+data.clip=[{planes[0]},{planes[1]}]"]),
                        ("other", [f"+data.clip=[{planes[0] / 2},{planes[1] + 0.3}]"])):
        caplog.clear()
        with caplog.at_level("WARNING"):
            eval_cli.run(compose_cfg("eval", [*base, f"out={tmp_path / name}", *extra]))
        results[name] = sorted((p.name, p.read_text()) for p in (tmp_path / name / "results").glob("*.json"))
        assert ("differ from the model's training planes" in caplog.text) == (name == "other"), name
    assert results["default"] == results["given"] and results["default"] != results["other"]
