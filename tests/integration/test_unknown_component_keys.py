"""A key a component does not take is named before anything runs, whichever config section holds it:
``eval.py ckpt=<ckpt> +data.bogus_key=1`` ended in a raw TypeError from the data module; train.py's
``+data.*`` and ``+augmentation.*`` too. One check (:func:`opnet.cli.build.check_keys`) for every section
built from a config. Each failed before its fix."""

from __future__ import annotations

from pathlib import Path

import pytest
from omegaconf import OmegaConf

from conftest import compose_cfg, tiny_train_cfg
from opnet.cli.build import build_components, check_keys


def test_eval_names_an_unknown_dataset_key(checkpoint: Path, tmp_path: Path) -> None:
    from opnet.cli import eval as eval_cli

    out = tmp_path / "eval"
    cfg = compose_cfg("eval", [f"ckpt={checkpoint}", f"out={out}", "examples=0", "+data.bogus_key=1"])
    with pytest.raises(ValueError, match=r"^data.bogus_key=1: not a setting of data \(SceneData\); expected "
                                         r"some of .*batch_size") as info:
        eval_cli.run(cfg)
    assert "\n" not in str(info.value)
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("override", ["+data.bogus_key=1", "+augmentation.bogus=2", "+model.bogus=3",
                                      "+loss.bogus=4", "+rotation.bogus=5", "+parameterization.bogus=6"])
def test_train_names_an_unknown_key_of_any_component(tiny_dataset: Path, tmp_path: Path, override: str) -> None:
    from opnet.cli import train as train_cli

    key, value = override[1:].split("=")
    with pytest.raises(ValueError, match=rf"^{key}={value}: not a setting of {key.split('.')[0]} \("):
        train_cli.run(tiny_train_cfg(tiny_dataset, tmp_path / "run", [override, "test=false"]))
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_the_keys_of_every_shipped_component_are_taken() -> None:
    cfg = compose_cfg("train", ["model=tiny", "object=zbracket"])
    for section in ("data", "augmentation", "model", "loss", "rotation", "parameterization"):
        check_keys(cfg[section], section)
    build_components(cfg)


def test_a_component_taking_any_keyword_is_not_checked() -> None:
    check_keys(OmegaConf.create({"_target_": "builtins.dict", "anything": 1}), "x")
