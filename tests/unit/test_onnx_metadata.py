"""ONNX metadata validated like a checkpoint's config: NaN or -1 thresholds, bad
names and ill-typed fields were accepted (or crashed later) before; every refusal is one line that
names the file and the key."""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np
import pytest

from opnet.deploy.metadata import validate_metadata


def _meta() -> dict[str, Any]:
    return {
        "format": 1, "object": "bunny", "parameterization": "vanilla", "grid_size": 16, "slots": 1,
        "channels_per_slot": 8, "outputs": ["presence", "visibility", "translation", "rotation"],
        "input": {"size": 128, "fit": "pad", "interpolation": "area"},
        "decoding": {"threshold": 0.5, "score": "p", "min_visibility": 0.0,
                     "averaging": {"eps": 0.5, "min_samples": 1, "cluster_score": "max", "keep_noise": False}},
        "pose_space": {"Lambda": np.eye(3).tolist(), "group": [np.eye(3).tolist()], "delta": 0.01,
                       "revolution": False, "lam": 0.0},
    }


def test_a_valid_metadata_is_typed() -> None:
    s = validate_metadata(_meta(), "m.onnx")
    assert (s["threshold"], s["score"], s["input_size"], s["fit"]) == (0.5, "p", 128, "pad")
    assert s["pose_space"]["group"].shape == (1, 3, 3) and s["averaging"]["cluster_score"] == "max"


def test_whether_slots_are_conditional_is_read_and_exports_without_the_key_are_mp_alone() -> None:
    assert validate_metadata(_set(_meta(), "slot_conditional", True), "m.onnx")["slot_conditional"] is True
    assert validate_metadata(_meta(), "m.onnx")["slot_conditional"] is False  # vanilla, exported before the key
    assert validate_metadata(_set(_meta(), "parameterization", "mp"), "m.onnx")["slot_conditional"] is True


def test_the_parameterizations_say_whether_their_slots_are_conditional() -> None:
    """MP's slot l + 1 counts only where slots 1..l are present; the mask follows the class's flag."""
    import torch

    from opnet.objects import builtin_object
    from opnet.parameterizations import MPParameterization, ZParameterization

    obj = builtin_object("bracket")
    presence = torch.tensor([0.9, 0.0, 0.9]).reshape(1, 3, 1, 1)  # slot 2 absent, slot 3 present
    mp, z = MPParameterization(obj, grid=1), ZParameterization(obj, grid=1, depth_slabs=3)
    assert mp.slot_conditional and not z.slot_conditional
    assert mp.presence_mask(presence).flatten().tolist() == [True, False, False]
    assert z.presence_mask(presence).flatten().tolist() == [True, False, True]


def _set(meta: dict[str, Any], key: str, value: Any) -> dict[str, Any]:
    meta = copy.deepcopy(meta)
    *parents, last = key.split(".")
    node = meta
    for p in parents:
        node = node[p]
    if value is KeyError:
        del node[last]
    else:
        node[last] = value
    return meta


@pytest.mark.parametrize(("key", "value", "message"), [
    ("decoding.threshold", math.nan, "decoding.threshold=nan: expected a number in [0, 1)"),
    ("decoding.threshold", -1, "decoding.threshold=-1: expected a number in [0, 1)"),
    ("decoding.threshold", True, "decoding.threshold=True"),
    ("decoding.threshold", KeyError, "lacks decoding.threshold"),
    ("decoding.score", "q", "decoding.score='q': expected one of p, p*v, v, p*q, p*v*q"),
    ("decoding.min_visibility", "0.1", "decoding.min_visibility='0.1'"),
    ("decoding.averaging.eps", 0, "decoding.averaging.eps=0"),
    ("decoding.averaging.min_samples", 1.5, "decoding.averaging.min_samples=1.5"),
    ("decoding.averaging.cluster_score", "median", "decoding.averaging.cluster_score='median'"),
    ("decoding.averaging.keep_noise", "false", "decoding.averaging.keep_noise='false': expected true or false"),
    ("decoding.averaging", [1], "decoding.averaging=[1]"),
    ("input.size", 10**9, "input.size=1000000000"),
    ("input.fit", "stretch", "input.fit='stretch'"),
    ("input.interpolation", "cubic", "input.interpolation='cubic'"),
    ("grid_size", 0, "grid_size=0"),
    ("slots", "4", "slots='4'"),
    ("slot_conditional", 1, "slot_conditional=1: expected true or false"),
    ("pose_space.delta", math.inf, "pose_space.delta=inf"),
    ("pose_space.revolution", 1, "pose_space.revolution=1: expected true or false"),
    ("pose_space.Lambda", [[1, 2], [3]], "pose_space.Lambda="),
    ("pose_space.group", [np.diag([1.0, 1.0, -1.0]).tolist()], "pose_space.group: symmetry rotations must be proper"),
    ("pose_space.group", [[[1, 0, 0], [0, 1, 0], [0, 0, math.nan]]], "pose_space.group="),
    ("pose_space", "x", "pose_space='x': expected a mapping"),
    ("object", "x" * 10_000, "object='xxxx"),
    ("outputs", "presence", "outputs='presence'"),
])  # fmt: skip
def test_bad_metadata_is_refused_naming_file_and_key(key: str, value: Any, message: str) -> None:
    with pytest.raises(ValueError) as err:
        validate_metadata(_set(_meta(), key, value), "m.onnx")
    assert str(err.value).startswith(f"m.onnx: opnet metadata {message}"), str(err.value)
    assert "\n" not in str(err.value) and len(str(err.value)) < 300


def test_metadata_that_is_not_an_object() -> None:
    with pytest.raises(ValueError, match="m.onnx: opnet metadata is a list, expected a JSON object"):
        validate_metadata([1, 2], "m.onnx")


# ---------------------------------------------------- format and keys (a checkpoint's entry was refused, not these)


def _full_meta() -> dict[str, Any]:
    """The metadata an export writes, every key."""
    return {
        "format": 1, "opnet_version": "0", "checkpoint": "x.ckpt", "object": "bunny", "parameterization": "vanilla",
        "rotation": "r6d", "grid_size": 16, "slots": 1, "channels_per_slot": 8, "out_channels": 8,
        "outputs": ["presence", "visibility", "translation", "rotation"],
        "input": {"size": 128, "fit": "pad", "interpolation": "area", "roi": None, "layout": "NCHW"},
        "camera_input": ["fx", "fy", "cx", "cy", "width", "height", "clip_start", "clip_end"], "trained_clip": None,
        "decoding": {"threshold": 0.5, "score": "p", "min_visibility": 0.0,
                     "averaging": {"eps": 0.5, "min_samples": 1, "cluster_score": "max", "keep_noise": False}},
        "pose_space": {"Lambda": np.eye(3).tolist(), "group": [np.eye(3).tolist()], "delta": 0.01,
                       "revolution": False, "lam": 0.0},
        "icp_model": None, "refine": None,
    }  # fmt: skip


def test_the_full_metadata_of_an_export_is_valid() -> None:
    assert validate_metadata(_full_meta(), "m.onnx")["input_size"] == 128


@pytest.mark.parametrize(("path", "value", "message"), [
    ("format", 2, "m.onnx: opnet metadata format=2: expected 1"),
    ("format", True, "format=True: expected 1"),
    ("format", KeyError, "format"),
    ("bogus", 1, "m.onnx: opnet metadata bogus=1: unknown key"),
    ("input.bogus", 1, "input.bogus=1: unknown key"),
    ("decoding.bogus", 1, "decoding.bogus=1: unknown setting"),
    ("decoding.averaging.bogus", 1, "decoding.averaging.bogus=1: unknown setting"),
    ("pose_space.bogus", 1, "pose_space.bogus=1: unknown key"),
])  # fmt: skip
def test_metadata_of_another_format_or_with_an_unknown_key_is_refused_as_a_checkpoints_entry_is(path: str, value: Any, message: str) -> None:
    with pytest.raises(ValueError, match=message) as info:
        validate_metadata(_set(_full_meta(), path, value), "m.onnx")
    assert "\n" not in str(info.value)
