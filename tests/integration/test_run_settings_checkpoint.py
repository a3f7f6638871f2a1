"""A freshly trained checkpoint holds its settings as their own entry (``opnet_settings``), and predict.py,
eval.py, the export and the ONNX runtime read them from there; the same checkpoint in the layout of before
the entry (its settings in its run config) loads to equal settings."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from conftest import compose_cfg

from opnet.cli import eval as eval_cli
from opnet.cli import predict as predict_cli
from opnet.cli.build import load_checkpoint, read_checkpoint
from opnet.datasets.ipa import IPADataset
from opnet.deploy.export import export_onnx
from opnet.run_settings import CHECKPOINT_KEY, RunSettings


def _old_layout(ckpt: dict[str, Any]) -> dict[str, Any]:
    """``ckpt`` as train.py wrote it before the settings entry: the clip planes in the run config."""
    entry = ckpt.pop(CHECKPOINT_KEY)
    ckpt["hyper_parameters"]["config"]["trained_clip"] = entry["trained_clip"]
    return ckpt


def _with_entry(checkpoint: Path, path: Path, **changes: Any) -> Path:
    """A copy of ``checkpoint`` whose settings entry has ``changes`` (``decoding={...}``, ``input={...}``); a
    framing changed in the entry is changed in the run config alike (``data.<key>``: a checkpoint whose two
    disagree is refused when read)."""
    ckpt = read_checkpoint(checkpoint)
    for section, values in changes.items():
        ckpt[CHECKPOINT_KEY][section].update(values)
    config_keys = {"size": "input_size", "fit": "fit", "interpolation": "interpolation", "roi": "roi"}
    for key, value in changes.get("input", {}).items():
        if key in config_keys:
            ckpt["hyper_parameters"]["config"]["data"][config_keys[key]] = value
    torch.save(ckpt, path)
    return path


def test_a_trained_checkpoint_holds_its_settings_and_the_old_layout_reads_alike(checkpoint: Path,
                                                                                tmp_path: Path) -> None:
    ckpt = read_checkpoint(checkpoint)
    entry = ckpt[CHECKPOINT_KEY]
    assert json.loads(json.dumps(entry)) == entry  # plain data
    system, cfg = load_checkpoint(checkpoint)
    assert system.settings == RunSettings.from_dict(entry, "x")
    assert system.settings.object.name == "zbracket" == system.obj.name
    assert system.settings.input.trained_clip is not None
    assert "trained_clip" not in cfg  # the planes travel in the settings, not in the run config
    old = tmp_path / "old.ckpt"
    torch.save(_old_layout(ckpt), old)
    # the training camera came with the entry: a checkpoint of before it reads as one that records none
    assert system.settings.camera is not None
    assert load_checkpoint(old)[0].settings == dataclasses.replace(system.settings, camera=None)


def _predict(ckpt: Path, tiny_dataset: Path, out: Path, *extra: str) -> list[dict[str, Any]]:
    record = IPADataset(tiny_dataset)[5]
    npy = out.parent / "frame.npy"
    if not npy.exists():
        np.save(npy, record.depth.astype(np.float32))
    c = record.camera
    args = [f"ckpt={ckpt}", f"input={npy}", f"out={out}", f"camera.fx={c.fx}", f"camera.fy={c.fy}",
            f"camera.cx={c.cx}", f"camera.cy={c.cy}", f"camera.clip_start={c.clip_start}",
            f"camera.clip_end={c.clip_end}", *extra]  # fmt: skip
    assert predict_cli.run(compose_cfg("predict", args)) == 0
    return json.loads((out / f"{npy.stem}.json").read_text())["poses"]


def test_predict_reads_the_decoding_and_the_framing_from_the_entry(checkpoint: Path, tiny_dataset: Path,
                                                                   tmp_path: Path) -> None:
    edited = _with_entry(checkpoint, tmp_path / "edited.ckpt", decoding={"threshold": 0.0, "averaging": None},
                         input={"roi": [8, 4, 120, 116]})  # fmt: skip
    by_entry = _predict(edited, tiny_dataset, tmp_path / "entry")
    by_command_line = _predict(checkpoint, tiny_dataset, tmp_path / "command_line", "+decoding.threshold=0.0",
                               "+decoding.averaging=false", "roi=[8,4,120,116]")  # fmt: skip
    plain = _predict(checkpoint, tiny_dataset, tmp_path / "plain")
    assert len(by_entry) > len(plain)  # every cell a hypothesis
    assert by_entry == by_command_line


def test_eval_reads_the_decoding_from_the_entry(checkpoint: Path, tmp_path: Path) -> None:
    edited = _with_entry(checkpoint, tmp_path / "edited.ckpt", decoding={"threshold": 0.0, "averaging": None})
    by_entry = eval_cli.run(compose_cfg("eval", [f"ckpt={edited}", f"out={tmp_path / 'entry'}", "examples=0"]))
    by_command_line = eval_cli.run(compose_cfg("eval", [f"ckpt={checkpoint}", f"out={tmp_path / 'command_line'}",
                                                        "examples=0", "+decoding.threshold=0.0",
                                                        "+decoding.averaging=false"]))  # fmt: skip
    results = [sorted((p.name, p.read_text()) for p in (tmp_path / name / "results").glob("*.json"))
               for name in ("entry", "command_line")]  # fmt: skip
    assert results[0] and results[0] == results[1]
    assert by_entry["ap"] == by_command_line["ap"]


def test_eval_runs_the_refinement_the_entry_records(checkpoint: Path, tmp_path: Path) -> None:
    edited = tmp_path / "edited.ckpt"
    ckpt = read_checkpoint(checkpoint)
    ckpt[CHECKPOINT_KEY]["refine"] = "search_fast"
    ckpt[CHECKPOINT_KEY]["decoding"]["threshold"] = 0.0  # every cell a hypothesis: something to refine
    torch.save(ckpt, edited)
    assert load_checkpoint(edited)[0].settings.refine == "search_fast"

    def results(ckpt: Path, name: str, *extra: str) -> tuple[dict[str, Any], list[tuple[str, str]]]:
        summary = eval_cli.run(compose_cfg("eval", [f"ckpt={ckpt}", f"out={tmp_path / name}", "examples=0", *extra]))
        return summary, sorted((p.name, p.read_text()) for p in (tmp_path / name / "results").glob("*.json"))

    by_entry = results(edited, "entry")
    by_command_line = results(checkpoint, "command_line", "refine=search_fast", "+decoding.averaging=false",
                              "+decoding.threshold=0.0")  # fmt: skip
    assert by_entry[1] and by_entry[1] == by_command_line[1]  # the search, decoded without averaging
    assert by_entry[0]["icp"]["statuses"] == by_command_line[0]["icp"]["statuses"]
    as_decoded = results(edited, "none", "refine=none")  # the command line wins
    assert as_decoded[1] == results(checkpoint, "plain", "+decoding.threshold=0.0")[1] != by_entry[1]


def test_the_export_and_its_runtime_carry_the_entrys_settings(checkpoint: Path, tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    from opnet.deploy.runtime import OnnxPoseEstimator

    edited = _with_entry(checkpoint, tmp_path / "edited.ckpt",
                         decoding={"threshold": 0.25, "averaging": {"eps": 0.75, "min_samples": 2,
                                                                    "cluster_score": "mean", "keep_noise": True}})
    system, cfg = load_checkpoint(edited)
    meta = export_onnx(system, cfg, edited, tmp_path / "m.onnx")
    assert meta["decoding"] == system.settings.decoding.to_metadata()["decoding"]
    assert meta["decoding"]["averaging"]["keep_noise"] is True
    assert system.parameterization.averaging.keep_noise is True
    estimator = OnnxPoseEstimator(tmp_path / "m.onnx")
    assert estimator.decoding == system.settings.decoding
    assert estimator.input == system.settings.input


def test_the_export_carries_the_recorded_refinement_and_the_runtime_runs_it(checkpoint: Path, tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    from opnet.deploy.__main__ import main as deploy_main
    from opnet.deploy.runtime import OnnxPoseEstimator, recorded_refinement
    from opnet.refine import refine_config, settings_from_config

    ckpt = read_checkpoint(checkpoint)
    ckpt[CHECKPOINT_KEY]["refine"] = "search_fast"
    torch.save(ckpt, tmp_path / "edited.ckpt")
    system, cfg = load_checkpoint(tmp_path / "edited.ckpt")
    assert system.parameterization.averaging is not None  # the tiny model decodes with averaging
    assert export_onnx(system, cfg, tmp_path / "edited.ckpt", tmp_path / "m.onnx")["refine"] == "search_fast"
    by_model = OnnxPoseEstimator(tmp_path / "m.onnx")
    assert by_model.recorded_refine == "search_fast"
    assert by_model.refiner is not None and by_model.refiner.settings == settings_from_config(refine_config("search_fast"))
    assert by_model.averaging is None  # the search's hypotheses are not averaged first, as eval.py runs it
    plain = OnnxPoseEstimator(tmp_path / "m.onnx", icp=None)
    assert plain.refiner is None and plain.averaging is not None
    assert recorded_refinement(None) is None
    old = export_onnx(*load_checkpoint(checkpoint), checkpoint, tmp_path / "old.onnx")
    assert old["refine"] is None and OnnxPoseEstimator(tmp_path / "old.onnx").refiner is None
    with pytest.raises(SystemExit) as refused:  # one refinement flag: argparse's one-line refusal
        deploy_main([str(tmp_path / "m.onnx"), str(tmp_path), "--out", str(tmp_path / "o"), "--no-refine", "--search"])
    assert refused.value.code == 2


def test_a_search_decodes_the_image_alone_and_icp_keeps_the_turns(checkpoint: Path, tmp_path: Path) -> None:
    """A model recording four turns: before a search (recorded or named) eval.py and the runtime decode one pass,
    unless +decoding.turns says otherwise; ICP and the poses as decoded keep the turns."""
    from opnet.cli.eval import model_settings
    from opnet.refine import refine_config

    ckpt = read_checkpoint(checkpoint)
    ckpt[CHECKPOINT_KEY]["refine"] = "search_fast"
    ckpt[CHECKPOINT_KEY]["decoding"]["turns"] = 4
    torch.save(ckpt, tmp_path / "turns.ckpt")

    def turns_with(refine: Any, decoding: Any = None) -> int:
        system, _ = load_checkpoint(tmp_path / "turns.ckpt")
        assert system.parameterization.turns == 4
        model_settings(system, refine, decoding)
        return system.parameterization.turns

    assert turns_with({"method": "model"}) == 1
    assert turns_with(refine_config("search")) == 1
    assert turns_with(refine_config("search"), {"turns": 2}) == 2
    assert turns_with(refine_config("icp")) == 4
    assert turns_with({"method": "none"}) == 4
    pytest.importorskip("onnxruntime")
    from opnet.deploy.runtime import OnnxPoseEstimator

    system, cfg = load_checkpoint(tmp_path / "turns.ckpt")
    export_onnx(system, cfg, tmp_path / "turns.ckpt", tmp_path / "turns.onnx")
    assert OnnxPoseEstimator(tmp_path / "turns.onnx").turns == 1  # the recorded search
    assert OnnxPoseEstimator(tmp_path / "turns.onnx", icp=None).turns == 4
