"""The one schema where it had not reached: train.py refuses eval.py's ``+decoding.*`` overrides (it trained and
dropped them; ONNX metadata of another format or with an unknown key: tests/unit/test_onnx_metadata.py), eval.py's
and predict.py's ``+decoding.averaging`` take ``keep_noise`` (every checkpoint records it), a checkpoint whose
recorded input size is not its network's is refused when read (it failed on every image), and the ONNX runtime's
refinement flags are one each (``--search --search-fast`` dropped one). Each failed before its fix."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import tiny_train_cfg
from opnet.cli.build import load_checkpoint, read_checkpoint
from opnet.deploy.__main__ import main as deploy_main
from opnet.run_settings import CHECKPOINT_KEY, DecodingSettings
from opnet.settings_schema import SettingError


@pytest.mark.parametrize("override", ["+decoding.threshold=7", "+decoding.threshold=0.5", "+decoding.bogus=1",
                                      "+decoding.averaging.eps=0.3"])
def test_train_refuses_the_decoding_overrides_of_eval_and_predict(tiny_dataset: Path, tmp_path: Path,
                                                                  override: str) -> None:  # fmt: skip
    from opnet.cli import train as train_cli

    key = override[1:].split("=")[0]
    with pytest.raises(SettingError, match=rf"^{key}=.*train.py") as info:
        train_cli.run(tiny_train_cfg(tiny_dataset, tmp_path / "run", [override, "test=false"]))
    assert "\n" not in str(info.value)
    if key in ("decoding.threshold", "decoding.averaging.eps"):
        assert {"decoding.threshold": "parameterization.threshold",
                "decoding.averaging.eps": "parameterization.averaging_eps"}[key] in str(info.value)
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_the_averaging_override_takes_keep_noise_as_every_checkpoint_records_it(checkpoint: Path) -> None:
    base = DecodingSettings()
    tuned = base.with_overrides({"averaging": {"keep_noise": True, "min_samples": 2}})
    assert tuned.averaging is not None and tuned.averaging.keep_noise and tuned.averaging.min_samples == 2
    with pytest.raises(SettingError, match=r"decoding.averaging.keep_noise=1: expected true or false"):
        base.with_overrides({"averaging": {"keep_noise": 1}})
    system, _ = load_checkpoint(checkpoint)
    param = system.parameterization.with_decoding(averaging={"keep_noise": True, "min_samples": 2})
    assert param.averaging.keep_noise and param.averaging.min_samples == 2
    system.set_decoding(system.settings.decoding.with_overrides({"averaging": {"keep_noise": True}}))
    assert system.parameterization.averaging.keep_noise


def test_a_checkpoint_whose_input_size_is_not_its_networks_is_refused_when_read(checkpoint: Path,
                                                                               tmp_path: Path) -> None:  # fmt: skip
    ckpt = read_checkpoint(checkpoint)
    ckpt[CHECKPOINT_KEY]["input"]["size"] = 256
    edited = tmp_path / "edited.ckpt"
    torch.save(ckpt, edited)
    with pytest.raises(ValueError, match=rf"^{edited}: .*input.size=256.*128") as info:
        load_checkpoint(edited)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("flags", [["--search", "--search-fast"], ["--icp", "--search"], ["--no-refine", "--icp"]])
def test_the_runtime_takes_one_refinement_flag(tmp_path: Path, capsys, flags: list[str]) -> None:
    model = tmp_path / "m.onnx"
    model.write_bytes(b"stand-in")
    image = tmp_path / "d.npy"
    np.save(image, np.ones((4, 4), np.float32))
    with pytest.raises(SystemExit) as info:
        deploy_main([str(model), str(image), "--out", str(tmp_path / "out"), *flags])
    assert info.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and flags[0] in err and flags[1] in err, err
    assert not (tmp_path / "out").exists()
    shutil.rmtree(tmp_path / "out", ignore_errors=True)


@pytest.mark.parametrize(("key", "value"), [("roi", "auto:0.5"), ("fit", "crop")])
def test_a_framing_edited_in_the_config_and_not_in_the_settings_is_refused(checkpoint: Path, tmp_path: Path,
                                                                          key: str, value: object) -> None:  # fmt: skip
    """predict.py runs the settings entry's framing: a config edited alone (data.roi=auto on a checkpoint
    recorded without one) was ignored without a word, and predicted on the whole frame."""
    ckpt = read_checkpoint(checkpoint)
    ckpt["hyper_parameters"]["config"]["data"][key] = value
    edited = tmp_path / "edited.ckpt"
    torch.save(ckpt, edited)
    with pytest.raises(ValueError, match=rf"^{edited}: the checkpoint's config data.{key}=.* but its {CHECKPOINT_KEY} "
                                         r"input\.\w+=.*edited without the other") as info:  # fmt: skip
        load_checkpoint(edited)
    assert "\n" not in str(info.value)
