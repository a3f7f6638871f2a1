"""Train / eval / predict end to end on a tiny generated dataset (CPU, a few steps each)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from omegaconf import DictConfig, OmegaConf

from opnet.cli import eval as eval_cli
from opnet.cli import predict as predict_cli
from opnet.cli import train as train_cli
from opnet.objects import builtin_object
from opnet.paths import REPO_ROOT
from conftest import compose_cfg, small_builtin_dataset, tiny_train_cfg
from param_checks import parameterization_names

PARAMETERIZATIONS = parameterization_names()


_cfg = compose_cfg
_train_cfg = tiny_train_cfg


@pytest.mark.parametrize("parameterization", PARAMETERIZATIONS)
def test_train_eval_predict_each_parameterization(parameterization: str, tiny_dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "run"
    result = train_cli.run(_train_cfg(tiny_dataset, out, [f"parameterization={parameterization}"]))
    assert 0.0 <= result["ap"] <= 1.0 and result["scenes"] > 0
    last = out / "checkpoints" / "last.ckpt"
    assert last.is_file()
    assert any((out / "tensorboard").rglob("events.out.tfevents*"))
    assert list((out / "test" / "predictions").glob("*.png"))
    # eval.py on the checkpoint: Siléane-format results per scene and the summary
    ev = eval_cli.run(_cfg("eval", [f"ckpt={last}", f"out={tmp_path / 'eval'}"]))
    results = sorted((tmp_path / "eval" / "results").glob("*.json"))
    assert len(results) == ev["scenes"] and set(json.loads((tmp_path / "eval" / "summary.json").read_text())) >= {"ap", "map", "per_scene"}
    # predict.py on one depth PNG of the IPA folder
    png = sorted((tiny_dataset / "p_depth").rglob("*.png"))[-1]
    failed = predict_cli.run(_cfg("predict", [f"ckpt={last}", f"input={png}", f"out={tmp_path / 'pred'}"]))
    assert failed == 0
    doc = json.loads((tmp_path / "pred" / f"{png.stem}.json").read_text())
    assert isinstance(doc["poses"], list)
    assert (tmp_path / "pred" / f"{png.stem}.png").is_file()


def _npy_cfg(ckpt: Path, inp: Path, out: Path, width: int, height: int) -> DictConfig:
    f = 0.9 * width
    return _cfg("predict", [f"ckpt={ckpt}", f"input={inp}", f"out={out}", f"camera.fx={f}", f"camera.fy={f}",
                            f"camera.cx={(width - 1) / 2}", f"camera.cy={(height - 1) / 2}",
                            "camera.clip_start=0.5", "camera.clip_end=1.5"])


@pytest.mark.parametrize("case", ["nan_holes", "zero_holes", "odd_size", "all_missing"])
def test_predict_handles_imperfect_depth(case: str, checkpoint: Path, tmp_path: Path) -> None:
    h, w = (97, 211) if case == "odd_size" else (128, 128)
    depth = np.full((h, w), 1.2, np.float32)
    depth[h // 3 : h // 2, w // 3 : w // 2] = 1.0
    if case == "nan_holes":
        depth[::7, ::5] = np.nan
    if case == "zero_holes":
        depth[10:40, 10:40] = 0.0
    if case == "all_missing":
        depth[:] = np.nan
    path = tmp_path / f"{case}.npy"
    np.save(path, depth)
    failed = predict_cli.run(_npy_cfg(checkpoint, path, tmp_path / "out", w, h))
    assert failed == 0
    doc = json.loads((tmp_path / "out" / f"{case}.json").read_text())
    for pose in doc["poses"]:
        assert np.isfinite(pose["R"]).all() and np.isfinite(pose["t"]).all()


@pytest.mark.parametrize(
    ("case", "message"),
    [("int_dtype", "expected float depth"), ("three_d", "2-D depth array"), ("size_mismatch", "camera.width"),
     ("eight_bit_png", "8-bit"), ("corrupt_png", "corrupt")],
)
def test_predict_bad_input_gives_clear_error(case: str, message: str, checkpoint: Path, tmp_path: Path,
                                             tiny_dataset: Path, capsys: pytest.CaptureFixture[str]) -> None:
    if case in ("eight_bit_png", "corrupt_png"):
        folder = tmp_path / "ipa"
        (folder / "p_depth" / "cycle_0000").mkdir(parents=True)
        (folder / "parameter.json").write_bytes((tiny_dataset / "parameter.json").read_bytes())
        path = folder / "p_depth" / "cycle_0000" / "001_depth_uint16.png"
        if case == "eight_bit_png":
            cv2.imwrite(str(path), np.zeros((128, 128), np.uint8))
        else:
            path.write_bytes(b"\x89PNG\r\n\x1a\n" + b"garbage" * 10)
        cfg = _cfg("predict", [f"ckpt={checkpoint}", f"input={path}", f"out={tmp_path / 'out'}"])
    else:
        arr = {"int_dtype": np.ones((64, 64), np.int32), "three_d": np.ones((64, 64, 3), np.float32),
               "size_mismatch": np.ones((64, 80), np.float32)}[case]
        path = tmp_path / f"{case}.npy"
        np.save(path, arr)
        cfg = _npy_cfg(checkpoint, path, tmp_path / "out", 64, 64)
        if case == "size_mismatch":
            OmegaConf.update(cfg, "camera.width", 64)
    failed = predict_cli.run(cfg)
    assert failed == 1
    err = capsys.readouterr().out
    assert path.name in err and message.lower() in err.lower()


def test_predict_cli_reports_errors_without_traceback(checkpoint: Path, tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, str(REPO_ROOT / "predict.py"), f"ckpt={tmp_path / 'missing.ckpt'}", f"input={tmp_path}",
         f"out={tmp_path / 'o'}", f"hydra.run.dir={tmp_path / 'h'}"],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode == 2
    assert "missing.ckpt" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.slow
def test_resume_after_kill_continues_from_last_checkpoint(tiny_dataset: Path, tmp_path: Path) -> None:
    run_dir = tmp_path / "resume"
    args = [sys.executable, str(REPO_ROOT / "train.py"), "model=tiny", "object=zbracket", f"data.root={tiny_dataset}",
            "data.generate=null", "data.batch_size=4", "+trainer.limit_train_batches=3", "+trainer.limit_val_batches=1",
            "trainer.enable_progress_bar=false", "test=false", f"hydra.run.dir={run_dir}"]
    last = run_dir / "checkpoints" / "last.ckpt"
    proc = subprocess.Popen([*args, "trainer.max_epochs=50"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None:
        if last.is_file() and torch.load(last, map_location="cpu", weights_only=False)["epoch"] >= 1:
            break
        time.sleep(0.5)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    killed = torch.load(last, map_location="cpu", weights_only=False)
    killed_epoch = killed["epoch"]
    assert 1 <= killed_epoch < 49
    steps_per_epoch = killed["global_step"] // (killed_epoch + 1)
    done = subprocess.run([*args, f"trainer.max_epochs={killed_epoch + 2}", "ckpt_path=last"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Restoring states from the checkpoint" in done.stdout + done.stderr
    final = torch.load(last, map_location="cpu", weights_only=False)
    # continued from the killed run's last epoch: exactly one more epoch, steps accumulate
    assert final["epoch"] == killed_epoch + 1
    assert final["global_step"] == steps_per_epoch * (killed_epoch + 2)
    # the optimizer state came along: AdamW's step count continued rather than restarting
    adam_step = next(iter(final["optimizer_states"][0]["state"].values()))["step"]
    assert int(adam_step) == final["global_step"]


@pytest.mark.slow
def test_ddp_two_cpu_processes(tiny_dataset: Path, tmp_path: Path) -> None:
    """trainer=ddp with 2 gloo processes on CPU trains, validates (AP gathered) and checkpoints."""
    run_dir = tmp_path / "ddp"
    proc = subprocess.run(
        [sys.executable, str(REPO_ROOT / "train.py"), "trainer=ddp", "trainer.accelerator=cpu", "trainer.devices=2",
         "model=tiny", "object=zbracket", f"data.root={tiny_dataset}", "data.generate=null", "data.batch_size=2",
         "trainer.max_epochs=1", "+trainer.limit_train_batches=2", "+trainer.limit_val_batches=2",
         "trainer.enable_progress_bar=false", "test=false", f"hydra.run.dir={run_dir}"],
        capture_output=True, text=True, timeout=400, env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    log = proc.stdout + proc.stderr
    assert "distributed_backend=gloo" in log and "All distributed processes registered" in log
    ckpt = torch.load(run_dir / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    assert ckpt["global_step"] == 2 and "val/ap" in str(ckpt["callbacks"])


def test_dataset_of_another_object_is_refused(tiny_dataset: Path, tmp_path: Path) -> None:
    cfg = _train_cfg(tiny_dataset, tmp_path / "run", ["object=shaft"])
    with pytest.raises(ValueError, match=r"object.json: the dataset shows object 'zbracket'.*'shaft'"):
        train_cli.run(cfg)


def test_separate_test_dataset_learning_curve_and_diagnostics(tiny_dataset: Path, tmp_path: Path) -> None:
    """data.test_root scores another dataset; the learning curve records minutes, val and test AP;
    the test summary carries the error diagnostics and the turns of the orientation misses."""
    other = tmp_path / "other_seed"
    small_builtin_dataset(other, "zbracket", 1, 3, 5)
    out = tmp_path / "run"
    result = train_cli.run(_train_cfg(tiny_dataset, out, [f"data.test_root={other}", "trainer.max_epochs=2",
                                                          "callbacks.learning_curve.test_every=1"]))  # fmt: skip
    assert result["scenes"] == 3  # scenes 1..3 of the other dataset's only cycle
    assert set(result["diagnostics"]) >= {"matched", "no_hypothesis", "position", "orientation", "conflict"}
    assert result["diagnostics"]["to_find"] <= 6
    rows = (out / "learning_curve.csv").read_text().splitlines()
    assert rows[0] == "epoch,step,train_minutes,images,val_ap,test_ap" and len(rows) == 3
    minutes = [float(r.split(",")[2]) for r in rows[1:]]
    assert 0 < minutes[0] < minutes[1] and all(r.split(",")[5] != "" for r in rows[1:])
    assert result["orientation_misses"]["count"] == result["diagnostics"]["orientation"]
    assert sum(result["orientation_misses"]["histogram"]) == result["diagnostics"]["orientation"]
    assert {"Error diagnostics", "Orientation misses"} <= set(re.findall(r"Error diagnostics|Orientation misses",
                                                                         (out / "test" / "ap_table.md").read_text()))
    # eval.py on other data, as the README writes it (data.root / data.test_root without a '+')
    ckpt = out / "checkpoints" / "last.ckpt"
    ev = eval_cli.run(_cfg("eval", [f"ckpt={ckpt}", f"data.test_root={other}", f"out={tmp_path / 'ev'}", "examples=0"]))
    assert ev["scenes"] == 3
    ev = eval_cli.run(_cfg("eval", [f"ckpt={ckpt}", f"data.root={tiny_dataset}", "split=val",
                                    f"out={tmp_path / 'ev_root'}", "examples=0"]))  # fmt: skip
    assert ev["scenes"] > 0


def test_several_training_datasets_are_split_by_dataset_and_cycle(tiny_dataset: Path, tmp_path: Path) -> None:
    """data.root as a list: the datasets (e.g. two camera set-ups) are trained on together; cycles
    of different datasets are different groups, names stay unique."""
    from opnet.cli.build import build_datamodule

    other = tmp_path / "wide_view"
    small_builtin_dataset(other, "zbracket", 4, 2, 9, fov_deg=65.0)
    cfg = _train_cfg(tiny_dataset, tmp_path / "run", [f"data.root=[{tiny_dataset},{other}]"])
    dm = build_datamodule(cfg, builtin_object("zbracket"), train=True)
    dm.prepare_data()
    dm.setup("fit")
    sizes = {k: len(v) for k, v in dm.splits.items()}
    assert sum(sizes.values()) == 4 * 4 + 4 * 2  # scenes with objects of both datasets
    names = [dm.splits[k].record(i).name for k in dm.splits for i in range(len(dm.splits[k]))]
    assert len(set(names)) == len(names) and {n[:3] for n in names} == {"d0_", "d1_"}
    cams = {round(dm.splits[k].record(i).camera.fx, 3) for k in dm.splits for i in range(len(dm.splits[k]))}
    assert len(cams) == 2  # both camera set-ups are there
    with pytest.raises(ValueError, match="one data.root"):
        build_datamodule(_train_cfg(tiny_dataset, tmp_path / "r2", [f"data.root=[{tiny_dataset},{other}]",
                                                                     "+data.generate={cycles: 1}"]), builtin_object("zbracket"))  # fmt: skip


def test_eval_and_predict_with_icp_refine_against_each_scene_depth(checkpoint: Path, tiny_dataset: Path,
                                                                    tmp_path: Path) -> None:
    plain = eval_cli.run(_cfg("eval", [f"ckpt={checkpoint}", f"out={tmp_path / 'plain'}", "examples=0"]))
    ev = eval_cli.run(_cfg("eval", [f"ckpt={checkpoint}", f"out={tmp_path / 'icp'}", "examples=0", "refine=icp",
                                    "refine.icp.budget_ms=null"]))
    icp = json.loads((tmp_path / "icp" / "summary.json").read_text())["icp"]
    hypotheses = sum(len(json.loads(p.read_text())) for p in (tmp_path / "plain" / "results").glob("*.json"))
    assert sum(icp["statuses"].values()) == hypotheses and icp["statuses"]["budget"] == 0
    assert icp["ms_per_image"] >= 0 and ev["scenes"] == plain["scenes"]
    with pytest.raises(ValueError, match=r"icp: unknown keys \['radiuss'\]"):
        eval_cli.run(_cfg("eval", [f"ckpt={checkpoint}", f"out={tmp_path / 'bad'}", "refine=icp", "+refine.icp.radiuss=1"]))
    png = sorted((tiny_dataset / "p_depth").rglob("*.png"))[-1]
    args = [f"ckpt={checkpoint}", f"input={png}", "refine=icp", "refine.icp.budget_ms=null"]
    assert predict_cli.run(_cfg("predict", [*args, f"out={tmp_path / 'pred'}"])) == 0
    refined = json.loads((tmp_path / "pred" / f"{png.stem}.json").read_text())["poses"]
    assert predict_cli.run(_cfg("predict", [*args[:2], f"out={tmp_path / 'pred0'}"])) == 0  # without ICP
    assert len(refined) == len(json.loads((tmp_path / "pred0" / f"{png.stem}.json").read_text())["poses"])


def test_a_region_of_interest_is_trained_kept_and_applied_by_eval_predict_and_export(
        tiny_dataset: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from opnet.cli import export as export_cli
    from opnet.deploy.runtime import OnnxPoseEstimator

    out = tmp_path / "run"
    train_cli.run(_train_cfg(tiny_dataset, out, ["data.roi=[8,4,120,116]", "test=false"]))
    assert list(tiny_dataset.glob("cache_*_roi8-4-120-116"))  # the cropped scenes' own cache
    ckpt = out / "checkpoints" / "last.ckpt"
    system = eval_cli.load_checkpoint(ckpt)[0]
    assert list(system.config["data"]["roi"]) == [8, 4, 120, 116]
    ev = eval_cli.run(_cfg("eval", [f"ckpt={ckpt}", f"out={tmp_path / 'eval'}", "examples=0"]))
    assert ev["scenes"] > 0
    png = sorted((tiny_dataset / "p_depth").rglob("*.png"))[-1]
    assert predict_cli.run(_cfg("predict", [f"ckpt={ckpt}", f"input={png}", f"out={tmp_path / 'pred'}"])) == 0
    failed = predict_cli.run(_cfg("predict", [f"ckpt={ckpt}", f"input={png}", f"out={tmp_path / 'pred2'}",
                                              "roi=[0,0,500,50]"]))
    assert failed == 1 and "roi=[0, 0, 500, 50]: outside the 128 x 128 image" in capsys.readouterr().out
    model = tmp_path / "m.onnx"
    export_cli.run(_cfg("export", [f"ckpt={ckpt}", f"out={model}", "check=false"]))
    assert OnnxPoseEstimator(model).roi == (8, 4, 120, 116)


def test_the_bin_finder_roi_is_trained_on_moved_bins_and_kept_by_the_checkpoint_and_the_onnx_export(
        tmp_path: Path) -> None:  # fmt: skip
    """``data.roi=auto:S`` on piles whose bin moves: the checkpoint and the ONNX metadata keep the policy, and
    eval.py, predict.py and the ONNX runtime each find the bin of every image they read."""
    from opnet.cli import export as export_cli
    from opnet.data.bin_finder import find_bin
    from opnet.datasets.ipa import IPADataset
    from opnet.deploy.runtime import OnnxPoseEstimator

    data = small_builtin_dataset(tmp_path / "moved", "zbracket", 4, 3, 1, bin_area=[-0.03, -0.03, 0.03, 0.03],
                                 bin_yaw_deg=[0.0, 90.0])  # fmt: skip
    out = tmp_path / "run"
    train_cli.run(_train_cfg(data, out, ["data.roi=auto:0.2", "test=false"]))
    assert list(data.glob("cache_*_roiauto0.2_f3"))
    ckpt = out / "checkpoints" / "last.ckpt"
    system = eval_cli.load_checkpoint(ckpt)[0]
    assert system.config["data"]["roi"] == "auto:0.2"
    assert eval_cli.run(_cfg("eval", [f"ckpt={ckpt}", f"out={tmp_path / 'eval'}", "examples=0"]))["scenes"] > 0
    png = sorted((data / "p_depth").rglob("*.png"))[-1]
    assert predict_cli.run(_cfg("predict", [f"ckpt={ckpt}", f"input={png}", f"out={tmp_path / 'pred'}"])) == 0
    model = tmp_path / "m.onnx"
    export_cli.run(_cfg("export", [f"ckpt={ckpt}", f"out={model}", "check=false"]))
    runtime = OnnxPoseEstimator(model)
    assert runtime.roi == "auto:0.2"
    record = IPADataset(data)[len(IPADataset(data)) - 1]
    box = find_bin(record.depth, record.camera, 0.2).box
    assert box[2] - box[0] < record.camera.width  # a crop, not the whole image
    runtime.predict(record.depth, record.camera)  # the runtime crops it the same way
