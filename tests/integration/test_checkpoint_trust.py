"""Checkpoints are data: a checkpoint whose saved config names another callable
than opnet's own components is refused by every path that loads one, before anything of it runs.
Before the fix, ``predict.py ckpt=<tampered> ...`` wrote the payload's file and exited 0."""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from conftest import compose_cfg, tiny_train_cfg

from opnet.cli import eval as eval_cli
from opnet.cli import export as export_cli
from opnet.cli import predict as predict_cli
from opnet.cli import train as train_cli
from opnet.cli.build import load_checkpoint
from opnet.cli.train import resolve_ckpt_path
from opnet.datasets.png import encode_depth, write_png
from opnet.paths import REPO_ROOT

EVIL = "opnet.fileio.atomic.write_text_atomic"
CAMERA = ["camera.fx=180", "camera.fy=180", "camera.cx=63.5", "camera.cy=63.5", "camera.clip_start=0.5",
          "camera.clip_end=1.5"]  # fmt: skip


def _payload(target: Path) -> dict[str, Any]:
    return {"_target_": EVIL, "_args_": [str(target), "import os"]}


def _in_loss(config: dict[str, Any], target: Path) -> str:
    config["loss"] = _payload(target)
    return "'loss._target_'"


def _nested_in_model(config: dict[str, Any], target: Path) -> str:
    config["model"]["extra"] = {"deeper": _payload(target)}
    return "'model.extra.deeper._target_'"


EDITS = {"loss": _in_loss, "nested_in_model": _nested_in_model}


def _tampered(checkpoint: Path, folder: Path, edit: Callable[[dict[str, Any], Path], str]) -> tuple[Path, Path, str]:
    """A copy of ``checkpoint`` whose saved config carries the payload: (file, payload's target, key)."""
    ckpt = torch.load(checkpoint, map_location="cpu", weights_only=True)
    target = folder / "pwned.pth"
    key = edit(ckpt["hyper_parameters"]["config"], target)
    torch.save(ckpt, folder / "tampered.ckpt")
    return folder / "tampered.ckpt", target, key


def _depth_png(path: Path) -> Path:
    depth = np.full((128, 128), 1.2, np.float32)
    depth[40:80, 50:90] = 1.05
    write_png(path, encode_depth(depth, 0.5, 1.5))
    return path


LOADERS: dict[str, Callable[[Path, Path], Any]] = {
    "predict": lambda ckpt, tmp: predict_cli.run(compose_cfg("predict", [
        f"ckpt={ckpt}", f"input={_depth_png(tmp / 'in.png')}", f"out={tmp / 'out'}", *CAMERA])),
    "eval": lambda ckpt, tmp: eval_cli.run(compose_cfg("eval", [f"ckpt={ckpt}", f"out={tmp / 'eval'}"])),
    "export": lambda ckpt, tmp: export_cli.run(compose_cfg("export", [f"ckpt={ckpt}", f"out={tmp / 'm.onnx'}"])),
    "resume": lambda ckpt, tmp: resolve_ckpt_path(str(ckpt), tmp),
}  # fmt: skip


@pytest.mark.parametrize("edit", EDITS)
@pytest.mark.parametrize("loader", LOADERS)
def test_tampered_checkpoint_is_refused_and_runs_nothing(loader: str, edit: str, checkpoint: Path,
                                                         tmp_path: Path) -> None:
    ckpt, target, key = _tampered(checkpoint, tmp_path, EDITS[edit])
    with pytest.raises(ValueError, match=f"^{ckpt}: config key {key} names '{EVIL}', not one of opnet's"):
        LOADERS[loader](ckpt, tmp_path)
    assert not target.exists()


def test_predict_entry_point_exits_2_on_a_tampered_checkpoint(checkpoint: Path, tmp_path: Path) -> None:
    ckpt, target, _ = _tampered(checkpoint, tmp_path, _in_loss)
    proc = subprocess.run(
        [sys.executable, str(REPO_ROOT / "predict.py"), f"ckpt={ckpt}", f"input={_depth_png(tmp_path / 'in.png')}",
         f"out={tmp_path / 'out'}", *CAMERA, f"hydra.run.dir={tmp_path / 'run'}"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.strip().splitlines()[-1].startswith(f"error: {ckpt}: config key 'loss._target_' names '{EVIL}'")
    assert "Traceback" not in proc.stderr and not target.exists() and not (tmp_path / "out").exists()


def test_genuine_checkpoint_still_loads_predicts_and_evaluates(checkpoint: Path, tmp_path: Path) -> None:
    system, cfg = load_checkpoint(checkpoint)
    assert cfg.loss._target_ == "opnet.losses.MultiTaskLoss" and not system.training
    assert LOADERS["predict"](checkpoint, tmp_path) == 0
    poses = json.loads((tmp_path / "out" / "in.json").read_text())
    assert poses  # the pose file of the image was written
    assert LOADERS["eval"](checkpoint, tmp_path)["scenes"] > 0 and (tmp_path / "eval" / "summary.json").is_file()


def test_genuine_checkpoint_still_resumes(checkpoint: Path, tiny_dataset: Path, tmp_path: Path) -> None:
    # Lightning reads the whole training state with weights_only=True too
    train_cli.run(tiny_train_cfg(tiny_dataset, tmp_path, ["parameterization=vanilla", "test=false",
                                                          "trainer.max_epochs=2", f"ckpt_path={checkpoint}"]))
    resumed = torch.load(tmp_path / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=True)
    assert resumed["epoch"] == 1 and resumed["global_step"] == 4


def _edited_weights(checkpoint: Path, folder: Path, edit: Callable[[dict[str, torch.Tensor]], None]) -> Path:
    ckpt = torch.load(checkpoint, map_location="cpu", weights_only=True)
    edit(ckpt["state_dict"])
    torch.save(ckpt, folder / "edited.ckpt")
    return folder / "edited.ckpt"


def _nan_weight(state: dict[str, torch.Tensor]) -> None:
    name = next(k for k, v in state.items() if v.is_floating_point() and v.ndim == 4)
    state[name].view(-1)[0] = float("nan")


def _wrong_shape(state: dict[str, torch.Tensor]) -> None:
    name = next(k for k, v in state.items() if v.is_floating_point() and v.ndim == 4)
    state[name] = torch.zeros(3, 3)


@pytest.mark.parametrize("loader", ["predict", "eval", "export"])
def test_nan_weights_are_refused(loader: str, checkpoint: Path, tmp_path: Path) -> None:
    # predicted "0 objects" with exit 0, and the export's self-check printed "largest difference nan"
    ckpt = _edited_weights(checkpoint, tmp_path, _nan_weight)
    with pytest.raises(ValueError, match=r"edited\.ckpt: the checkpoint's weights hold NaN or inf \(1 tensor"):
        LOADERS[loader](ckpt, tmp_path)
    assert not (tmp_path / "out").exists() and not (tmp_path / "m.onnx").exists()


def test_wrong_tensor_shape_is_a_one_line_error(checkpoint: Path, tmp_path: Path) -> None:
    ckpt = _edited_weights(checkpoint, tmp_path, _wrong_shape)
    with pytest.raises(ValueError, match=r"edited\.ckpt: the checkpoint's weights do not fit its config") as err:
        load_checkpoint(ckpt)
    assert "\n" not in str(err.value)


def test_nan_network_output_stops_predict(checkpoint: Path, tmp_path: Path) -> None:
    system, _ = load_checkpoint(checkpoint)
    system.infer = lambda x: torch.full((len(x), system.parameterization.out_channels, 16, 16), float("nan"))
    from opnet.datasets.depth_inputs import DepthImage
    from opnet.geometry.camera import Camera

    image = DepthImage(tmp_path / "in.png", np.full((128, 128), 1.2, np.float32),
                       Camera(180.0, 180.0, 63.5, 63.5, 128, 128, 0.5, 1.5))
    with pytest.raises(ValueError, match=r"in\.png: the network's output holds NaN or inf"):
        predict_cli.predict_image(system, image)


def _as_list(ckpt: dict[str, Any]) -> Any:
    return [ckpt["state_dict"]]


def _without_state_dict(ckpt: dict[str, Any]) -> Any:
    del ckpt["state_dict"]
    return ckpt


def _hyper_parameters_a_list(ckpt: dict[str, Any]) -> Any:
    ckpt["hyper_parameters"] = [ckpt["hyper_parameters"]]
    return ckpt


def _mesh_gone(ckpt: dict[str, Any]) -> Any:
    ckpt["hyper_parameters"]["config"]["object"] = {"name": "part", "mesh": "/nonexistent/part.ply"}
    return ckpt


SHAPES = {
    "a list": (_as_list, r"not an opnet checkpoint \(holds a list, not a dict\)"),
    "no state_dict": (_without_state_dict, r"checkpoint holds no state_dict"),
    "hyper_parameters a list": (_hyper_parameters_a_list, r"checkpoint holds no opnet run config"),
    "its mesh gone": (_mesh_gone, r"the checkpoint's config: /nonexistent/part\.ply: file not found"),
}  # fmt: skip


@pytest.mark.parametrize("shape", SHAPES)
def test_a_checkpoint_of_another_shape_is_a_one_line_error(shape: str, checkpoint: Path, tmp_path: Path) -> None:
    # each raised a raw traceback (TypeError / KeyError / AttributeError) before it was checked
    edit, message = SHAPES[shape]
    ckpt = edit(torch.load(checkpoint, map_location="cpu", weights_only=True))
    torch.save(ckpt, tmp_path / "odd.ckpt")
    with pytest.raises(ValueError, match=f"^{tmp_path / 'odd.ckpt'}: {message}") as err:
        load_checkpoint(tmp_path / "odd.ckpt")
    assert "\n" not in str(err.value)
