"""The check of configs read back from files: every ``_target_`` at any depth
of a group's node must be one that the shipped ``conf/<group>/*.yaml`` name; nothing else is
instantiated, however it is wrapped (``_args_``, ``_partial_``, tuples, interpolations)."""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import pytest
from conftest import compose_cfg

from opnet.cli.build import run_config
from opnet.cli.trusted import QUOTE_CHARS, check_saved_config, saved_config, shipped_targets

EVIL = "opnet.fileio.atomic.write_text_atomic"
PAYLOAD = {"_target_": EVIL, "_args_": ["/tmp/pwned.pth", "import os"]}


@pytest.fixture(scope="module")
def genuine() -> dict[str, Any]:
    """The run config a checkpoint of ``train.py model=tiny`` saves."""
    return run_config(compose_cfg("train", ["model=tiny"]))


def test_allowlist_is_what_the_shipped_groups_name() -> None:
    assert shipped_targets("loss") == {"opnet.losses.MultiTaskLoss"}
    assert shipped_targets("model") == {"opnet.models.densenet.DenseNetBC"}
    assert "opnet.parameterizations.rotation.SixDCodec" in shipped_targets("rotation")
    assert shipped_targets("augmentation") == {"opnet.data.augment.DepthAugmenter"}
    assert len(shipped_targets("parameterization")) == 6
    assert shipped_targets("object") == shipped_targets("../conf/loss") == shipped_targets("nosuch") == frozenset()


def test_genuine_config_passes(genuine: dict[str, Any]) -> None:
    check_saved_config(genuine, "run.ckpt")
    assert saved_config(genuine, "run.ckpt").loss._target_ == "opnet.losses.MultiTaskLoss"


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    def edit(cfg: dict[str, Any]) -> None:
        *parents, last = path.split(".")
        node = cfg
        for key in parents:
            node = node.setdefault(key, {})
        node[last] = value

    return edit


ATTACKS = [  # (edit of the saved config, the key the message names)
    (_set("loss", PAYLOAD), "'loss._target_' names 'opnet.fileio.atomic.write_text_atomic'"),
    (_set("model.extra", PAYLOAD), "'model.extra._target_'"),
    (_set("data.generate", {"scene": PAYLOAD}), "'data.generate.scene._target_'"),
    (_set("loss._args_", [PAYLOAD]), "'loss._args_[0]._target_'"),  # inside an allowed target's arguments
    (_set("loss._args_", (PAYLOAD,)), "'loss._args_[0]._target_'"),  # a tuple (OmegaConf makes it a list)
    (_set("rotation", {**PAYLOAD, "_partial_": True}), "'rotation._target_'"),
    (_set("loss._target_", "opnet.models.densenet.DenseNetBC"), "not one of opnet's loss components"),  # a model
    (_set("loss._target_", ["opnet.losses.MultiTaskLoss"]), "'loss._target_' names ['opnet.losses.MultiTaskLoss']"),
    (_set("object._target_", EVIL), "none: conf/object/ names no class"),
    (_set("_target_", EVIL), "config key '_target_'"),
    (_set("loss.lambda_pos", "${oc.create:{_target_: " + EVIL + "}}"), "'loss.lambda_pos' holds the interpolation"),
]  # fmt: skip


@pytest.mark.parametrize(("edit", "message"), ATTACKS)
def test_anything_else_is_refused_naming_the_key(edit: Callable[[dict[str, Any]], None], message: str,
                                                 genuine: dict[str, Any]) -> None:
    cfg = copy.deepcopy(genuine)
    edit(cfg)
    with pytest.raises(ValueError, match="^run.ckpt: config key ") as err:
        saved_config(cfg, "run.ckpt")
    assert message in str(err.value)


def test_messages_quote_values_from_the_file_truncated(genuine: dict[str, Any]) -> None:
    cfg = copy.deepcopy(genuine)
    cfg["loss"] = {"_target_": "x" * 100_000}
    with pytest.raises(ValueError) as err:
        saved_config(cfg, "run.ckpt")
    assert "x" * QUOTE_CHARS not in str(err.value) and len(str(err.value)) < 400


@pytest.mark.parametrize("config", [["loss"], "loss", {"loss": {"weights": {1, 2}}}])
def test_a_config_that_is_no_plain_mapping_is_refused(config: Any) -> None:
    with pytest.raises(ValueError, match="^run.ckpt: the saved config"):
        saved_config(config, "run.ckpt")
