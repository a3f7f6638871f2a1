"""One validation for every value a run takes, whatever its source: the same bad value from the
command line (eval.py / predict.py ``+decoding.*``), a checkpoint's config and an ONNX export's metadata is
refused with the same one line, ``[<source> ]<key>=<value>: <expected>``, naming the key as that source
spells it; booleans are never numbers. Each source had its own messages and bounds before (an averaging eps
of 1e6 passed the command line and the checkpoint, and the export made of it was refused by its runtime; a
checkpoint's ``parameterization.grid: true`` was read as 1)."""

from __future__ import annotations

import copy
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from opnet._repr import short_repr
from opnet.cli.build import load_checkpoint
from opnet.cli.eval import with_decoding_overrides
from opnet.deploy.__main__ import main as run_onnx
from opnet.deploy.export import export_metadata
from opnet.objects import builtin_object
from opnet.parameterizations.vanilla import VanillaParameterization
from opnet.paths import REPO_ROOT

CKPT = REPO_ROOT / "models" / "dense_bunny.ckpt"
NUMBER = "expected a number in [0, 1)"
EPS = "expected a fraction of delta in (0, 100]"
SAMPLES = "expected a whole number in [1, 10000]"

#: value, what is expected, and the key as the command line, a checkpoint and ONNX metadata spell it (None: not a key there)
CASES = [
    (True, NUMBER, "decoding.threshold", "parameterization.threshold", "decoding.threshold"),
    (math.nan, NUMBER, "decoding.threshold", "parameterization.threshold", "decoding.threshold"),
    (1.5, NUMBER, "decoding.threshold", "parameterization.threshold", "decoding.threshold"),
    (False, NUMBER, "decoding.min_visibility", "parameterization.min_visibility", "decoding.min_visibility"),
    ("best", "expected one of p, p*v, v, p*q, p*v*q", "decoding.score", "parameterization.score", "decoding.score"),
    (True, EPS, "decoding.averaging.eps", "parameterization.averaging_eps", "decoding.averaging.eps"),
    (math.inf, EPS, "decoding.averaging.eps", "parameterization.averaging_eps", "decoding.averaging.eps"),
    (1e6, EPS, "decoding.averaging.eps", "parameterization.averaging_eps", "decoding.averaging.eps"),
    (True, SAMPLES, "decoding.averaging.min_samples", "parameterization.averaging_min_samples",
     "decoding.averaging.min_samples"),
    (2.5, SAMPLES, "decoding.averaging.min_samples", "parameterization.averaging_min_samples",
     "decoding.averaging.min_samples"),
    (10**6, SAMPLES, "decoding.averaging.min_samples", "parameterization.averaging_min_samples",
     "decoding.averaging.min_samples"),
    ("median", "expected one of max, sum, mean", "decoding.averaging.cluster_score", "parameterization.averaging_score",
     "decoding.averaging.cluster_score"),
    (True, "expected a whole number in [1, 1024]", None, "parameterization.grid", "grid_size"),
    (True, "expected a whole number of pixels in [8, 4096]", None, "data.input_size", "input.size"),
    ("stretch", "expected one of pad, crop, image, image_crop", None, "data.fit", "input.fit"),
    ([0, 0, True, 64], "the box needs whole pixel numbers", None, "data.roi", "input.roi"),
    ([True, 2], "expected [near, far] in metres", None, "trained_clip", "trained_clip"),
]  # fmt: skip
IDS = [f"{c[3]}={c[0]!r}" for c in CASES]


def _set(tree: dict[str, Any], key: str, value: Any) -> dict[str, Any]:
    tree = copy.deepcopy(tree)
    *parents, last = key.split(".")
    node = tree
    for part in parents:
        node = node.setdefault(part, {})
    node[last] = value
    return tree


@pytest.fixture(scope="module")
def saved() -> dict[str, Any]:
    return torch.load(CKPT, map_location="cpu", weights_only=True)


@pytest.fixture(scope="module")
def metadata(saved: dict[str, Any]) -> dict[str, Any]:
    """The metadata an export of the checkpoint writes (with its averaging)."""
    system, cfg = load_checkpoint(CKPT)
    return json.loads(json.dumps(export_metadata(system, cfg, CKPT)))


def _onnx(path: Path, meta: dict[str, Any]) -> Path:
    """An ONNX file holding ``meta`` (the graph: one Identity; the metadata is read before the graph)."""
    import onnx
    from onnx import TensorProto, helper

    graph = helper.make_graph([helper.make_node("Identity", ["x"], ["y"])], "g",
                              [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1])],
                              [helper.make_tensor_value_info("y", TensorProto.FLOAT, [1])])  # fmt: skip
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    helper.set_model_props(model, {"opnet": json.dumps(meta)})
    onnx.save(model, str(path))
    return path


def _command_line(key: str, value: Any) -> str:
    param = VanillaParameterization(builtin_object("zbracket"), grid=8, averaging=True)
    with pytest.raises(ValueError) as e:
        with_decoding_overrides(param, _set({}, key, value)["decoding"])
    return str(e.value)


def _checkpoint(saved: dict[str, Any], key: str, value: Any, path: Path) -> str:
    torch.save(_set(saved, f"hyper_parameters.config.{key}", value), path)
    with pytest.raises(ValueError) as e:
        load_checkpoint(path)
    return str(e.value)


def _metadata(meta: dict[str, Any], key: str, value: Any, tmp_path: Path, capsys: pytest.CaptureFixture) -> str:
    """The one line ``python -m opnet.deploy`` prints for an export holding ``value`` at ``key``; exit 2, nothing written."""
    model = _onnx(tmp_path / "m.onnx", _set(meta, key, value))
    np.save(tmp_path / "frame.npy", np.full((64, 64), 1.2, np.float32))
    out = tmp_path / "poses"
    capsys.readouterr()
    assert run_onnx([str(model), str(tmp_path / "frame.npy"), "--out", str(out), "--fx", "60", "--fy", "60", "--cx", "32",
                     "--cy", "32", "--clip-start", "0.5", "--clip-end", "2"]) == 2  # fmt: skip
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and not out.exists(), err
    return err[len("error: "):].rstrip("\n")


@pytest.mark.parametrize(("value", "expected", "override", "config_key", "meta_key"), CASES, ids=IDS)
def test_a_bad_value_is_one_line_naming_its_key_in_every_source(
    value: Any, expected: str, override: str | None, config_key: str, meta_key: str, saved: dict[str, Any],
    metadata: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture,
) -> None:  # fmt: skip
    shown = short_repr(value)
    if override is not None:
        assert _command_line(override, value) == f"{override}={shown}: {expected}"
    ckpt = tmp_path / "edited.ckpt"
    assert _checkpoint(saved, config_key, value, ckpt) == f"{ckpt}: the checkpoint's config {config_key}={shown}: {expected}"
    model = tmp_path / "m.onnx"
    assert _metadata(metadata, meta_key, value, tmp_path, capsys) == f"{model}: opnet metadata {meta_key}={shown}: {expected}"


@pytest.mark.parametrize(("key", "value"), [("averaging.eps", 0.75), ("averaging.min_samples", 3), ("threshold", 0.3),
                                            ("averaging.cluster_score", "mean"), ("min_visibility", 0.0)])  # fmt: skip
def test_a_good_value_is_taken_from_every_source(key: str, value: Any, saved: dict[str, Any], metadata: dict[str, Any],
                                                 tmp_path: Path) -> None:  # fmt: skip
    from opnet.deploy.metadata import validate_metadata

    param = VanillaParameterization(builtin_object("zbracket"), grid=8, averaging=True)
    name = key.split(".")[-1]
    taken = with_decoding_overrides(param, _set({}, key, value))
    assert getattr(taken.averaging if key.startswith("averaging.") else taken, name) == value
    training = {"averaging.eps": "averaging_eps", "averaging.min_samples": "averaging_min_samples",
                "averaging.cluster_score": "averaging_score"}.get(key, key)  # fmt: skip
    torch.save(_set(saved, f"hyper_parameters.config.parameterization.{training}", value), tmp_path / "ok.ckpt")
    system, _ = load_checkpoint(tmp_path / "ok.ckpt")
    loaded = system.parameterization
    assert getattr(loaded.averaging if key.startswith("averaging.") else loaded, name) == value
    settings = validate_metadata(_set(metadata, f"decoding.{key}", value), "m.onnx")
    assert (settings["averaging"][name] if key.startswith("averaging.") else settings[name]) == value


def test_a_misspelt_override_is_named_as_written() -> None:
    assert _command_line("decoding.treshold", 0.05) == (
        "decoding.treshold=0.05: unknown setting; expected one of threshold, min_visibility, score, turns, averaging")
    assert _command_line("decoding.averaging.radius", 2) == (
        "decoding.averaging.radius=2: unknown setting; expected one of eps, min_samples, cluster_score, keep_noise")


def test_a_training_config_is_checked_by_the_same_schema() -> None:
    """train.py's parameterization (YAML) and a directly built averaging: the same lines, the training keys."""
    from opnet.parameterizations.averaging import PoseAveraging

    obj = builtin_object("zbracket")
    with pytest.raises(ValueError, match=r"^parameterization.min_target_visibility='abc': expected a number in \[0, 1\)$"):
        VanillaParameterization(obj, grid=8, min_target_visibility="abc")  # was a TypeError (a traceback)
    with pytest.raises(ValueError, match=r"^parameterization.grid=True: expected a whole number in \[1, 1024\]$"):
        VanillaParameterization(obj, grid=True)  # was read as a 1 x 1 grid
    with pytest.raises(ValueError, match=r"^parameterization.quality='maybe': expected true or false$"):
        VanillaParameterization(obj, grid=8, quality="maybe")  # any text would have added the channel
    with pytest.raises(ValueError, match=r"^parameterization.averaging_eps=1000.0: expected a fraction of delta"):
        PoseAveraging(obj.pose_space, eps=1000.0)


@pytest.mark.parametrize("clip", [[True, 2], [0.5, "2"], [2.0, 0.5]])
def test_data_clip_is_checked_like_the_trained_planes(clip: list) -> None:
    """eval.py's data.clip (the planes BOP scenes are normalized with) took [true, 2] as [1, 2] m."""
    from opnet.data.scene_data import SceneData

    with pytest.raises(ValueError, match=r"^data.clip=.*: expected (\[near, far\] in metres|0 < near < far)"):
        SceneData(None, "/nonexistent", clip=clip)
