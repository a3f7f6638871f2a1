"""The typed settings a trained model needs at inference (:mod:`opnet.run_settings`): plain data in and out
of a checkpoint's own entry, every value checked by the one schema, one vocabulary for the decoding
(``+decoding.*`` on the command line and the typed settings give the same), and checkpoints written before
the entry read from their run config to the same settings."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from opnet.cli.build import load_checkpoint
from opnet.cli.eval import with_decoding_overrides
from opnet.geometry.camera import Camera
from opnet.objects import builtin_object
from opnet.parameterizations.vanilla import VanillaParameterization
from opnet.paths import REPO_ROOT
from opnet.run_settings import (
    CHECKPOINT_KEY,
    REFINE_NAMES,
    AveragingSettings,
    DecodingSettings,
    InputSettings,
    ObjectSettings,
    RunSettings,
)
from opnet.settings_schema import SettingError

CKPT = REPO_ROOT / "models" / "dense_bunny.ckpt"

EXAMPLES = [
    RunSettings(),
    RunSettings(InputSettings(256, "image", (8, 4, 120, 116), "area", (0.5, 1.5)),
                DecodingSettings(0.3, 0.2, "p*v", AveragingSettings(1.5, 2, "sum", True), turns=4),
                ObjectSettings({"name": "bunny", "mesh": "/m/bunny.obj", "symmetry": {"kind": "none"},
                                "model_rotation": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]})),
    RunSettings(InputSettings(roi="auto:0.8", trained_clip=(1.55, 2.05)), DecodingSettings(averaging=AveragingSettings()),
                ObjectSettings({"name": "ipd_plate", "bop_models": "/d/models", "bop_obj_id": 18})),
    RunSettings(InputSettings(roi="auto")),
    RunSettings(InputSettings(roi="auto:0.8"), refine="search_fast"),
]  # fmt: skip


@pytest.mark.parametrize("settings", EXAMPLES)
def test_to_dict_and_back_through_json(settings: RunSettings) -> None:
    d = settings.to_dict()
    assert json.loads(json.dumps(d)) == d  # plain data, as a checkpoint read with weights_only holds it
    assert RunSettings.from_dict(json.loads(json.dumps(d)), "x.ckpt") == settings


def test_the_entry_spells_the_keys_as_the_onnx_metadata() -> None:
    d = EXAMPLES[1].to_dict()
    assert d["input"] == {"size": 256, "fit": "image", "interpolation": "area", "roi": [8, 4, 120, 116]}
    assert d["trained_clip"] == [0.5, 1.5]
    assert d["decoding"] == {"threshold": 0.3, "min_visibility": 0.2, "score": "p*v", "turns": 4,
                             "averaging": {"eps": 1.5, "min_samples": 2, "cluster_score": "sum", "keep_noise": True}}
    assert DecodingSettings.from_metadata(d) == EXAMPLES[1].decoding
    assert InputSettings.from_metadata(d) == EXAMPLES[1].input


def _set(tree: dict[str, Any], key: str, value: Any) -> dict[str, Any]:
    tree = copy.deepcopy(tree)
    *parents, last = key.split(".")
    node = tree
    for part in parents:
        node = node[part]
    node[last] = value
    return tree


def _drop(tree: dict[str, Any], key: str) -> dict[str, Any]:
    tree = copy.deepcopy(tree)
    *parents, last = key.split(".")
    node = tree
    for part in parents:
        node = node[part]
    del node[last]
    return tree


GOOD = EXAMPLES[1].to_dict()
SOURCE = "run/last.ckpt: the checkpoint's opnet_settings"
CORRUPT = {
    "threshold 1.5": (_set(GOOD, "decoding.threshold", 1.5), "decoding.threshold=1.5: expected a number in [0, 1)"),
    "threshold true": (_set(GOOD, "decoding.threshold", True), "decoding.threshold=True: expected a number in [0, 1)"),
    "eps missing": (_drop(GOOD, "decoding.averaging.eps"), "decoding.averaging.eps=<missing>: missing"),
    "score missing": (_drop(GOOD, "decoding.score"), "decoding.score=<missing>: missing"),
    "averaging a number": (_set(GOOD, "decoding.averaging", 1), "decoding.averaging=1: expected true, false or a mapping"),
    "unknown averaging key": (_set(GOOD, "decoding.averaging.radius", 2), "decoding.averaging.radius=2: unknown setting"),
    "size a flag": (_set(GOOD, "input.size", True), "input.size=True: expected a whole number of pixels"),
    "fit unknown": (_set(GOOD, "input.fit", "stretch"), "input.fit='stretch': expected one of pad, crop"),
    "unknown input key": (_set(GOOD, "input.layout", "x"), "input.layout='x': unknown setting"),
    "roi reversed": (_set(GOOD, "input.roi", [100, 4, 8, 116]), "input.roi=[100, 4, 8, 116]: the corners are reversed"),
    "clip reversed": (_set(GOOD, "trained_clip", [2.0, 1.0]), "trained_clip=[2.0, 1.0]: expected 0 < near < far"),
    "clip text": (_set(GOOD, "trained_clip", "0.5,1.5"), "trained_clip='0.5,1.5': expected [near, far] in metres"),
    "object nameless": (_set(GOOD, "object", {"mesh": "m.obj"}), "object.name=None: expected the object's name"),
    "object a list": (_set(GOOD, "object", ["bunny"]), "object=['bunny']: expected an object config"),
    "format 2": (_set(GOOD, "format", 2), "format=2: expected 1 (written by another opnet version)"),
    "unknown key": (_set(GOOD, "decodng", {}), "decodng={}: unknown setting; expected one of format, input"),
    "not a mapping": ([1, 2], "opnet_settings=[1, 2]: expected a mapping"),
    "refine unknown": (_set(GOOD, "refine", "fast"), "refine='fast': expected null or one of icp, search, search_fast"),
    "refine a flag": (_set(GOOD, "refine", True), "refine=True: expected null or one of icp, search, search_fast"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(CORRUPT))
def test_a_corrupt_entry_is_one_line_naming_the_source_and_the_key(case: str) -> None:
    entry, expected = CORRUPT[case]
    with pytest.raises(SettingError) as e:
        RunSettings.from_dict(entry, SOURCE)
    text = str(e.value)
    assert "\n" not in text and text.startswith(f"{SOURCE} {expected}"), text


def test_a_corrupt_entry_in_a_checkpoint_file_is_named_by_load_checkpoint(tmp_path: Path) -> None:
    ckpt = torch.load(CKPT, map_location="cpu", weights_only=True)
    system, _ = load_checkpoint(CKPT)
    ckpt[CHECKPOINT_KEY] = _set(system.settings.to_dict(), "decoding.averaging.min_samples", 2.5)
    path = tmp_path / "bad.ckpt"
    torch.save(ckpt, path)
    with pytest.raises(ValueError, match=r"^" + str(path) + r": the checkpoint's opnet_settings "
                       r"decoding.averaging.min_samples=2.5: expected a whole number in \[1, 10000\]$"):
        load_checkpoint(path)
    ckpt[CHECKPOINT_KEY] = _set(system.settings.to_dict(), "object.name", "screw")
    torch.save(ckpt, path)
    with pytest.raises(ValueError, match=r"opnet_settings object differs from its config's object"):
        load_checkpoint(path)


OVERRIDES = [
    {"threshold": 0.3},
    {"score": "v", "min_visibility": 0.25},
    {"averaging": False},
    {"averaging": True},
    {"averaging": {"eps": 0.2}},
    {"averaging": {"min_samples": 3, "cluster_score": "mean"}, "threshold": 0.05},
    {},
]


@pytest.mark.parametrize("averaging", [False, True])
@pytest.mark.parametrize("overrides", OVERRIDES, ids=[json.dumps(o) for o in OVERRIDES])
def test_the_command_lines_override_and_the_typed_one_decode_alike(overrides: dict[str, Any], averaging: bool) -> None:
    """eval.py / predict.py ``+decoding.*`` on a parameterization and on the typed settings: the same settings."""
    param = VanillaParameterization(builtin_object("zbracket"), grid=8, averaging=averaging, averaging_eps=0.75,
                                    averaging_score="sum")  # fmt: skip
    typed = DecodingSettings.of(param).with_overrides(overrides)
    assert typed == DecodingSettings.of(with_decoding_overrides(param, overrides))
    assert typed == DecodingSettings.from_overrides(overrides, DecodingSettings.of(param))
    config = {"parameterization": {"threshold": 0.1, "min_visibility": 0.0, "score": "p", "averaging": averaging,
                                   "averaging_eps": 0.75, "averaging_min_samples": 1, "averaging_score": "sum"}}
    assert DecodingSettings.from_training_config(config) == DecodingSettings.of(param)


@pytest.mark.parametrize(("overrides", "message"), [
    ({"treshold": 0.05}, ("decoding.treshold=0.05: unknown setting; expected one of threshold, min_visibility, score, "
                          "turns, averaging")),
    ({"averaging": {"eps": 1e6}}, "decoding.averaging.eps=1000000.0: expected a fraction of delta in (0, 100]"),
    ({"score": "best"}, "decoding.score='best': expected one of p, p*v, v, p*q, p*v*q"),
    (0.3, "decoding=0.3: expected a mapping of threshold, score, min_visibility, turns, averaging"),
])  # fmt: skip
def test_a_bad_override_is_the_same_line_either_way(overrides: Any, message: str) -> None:
    param = VanillaParameterization(builtin_object("zbracket"), grid=8, averaging=True)
    with pytest.raises(SettingError) as typed:
        DecodingSettings.of(param).with_overrides(overrides)
    with pytest.raises(SettingError) as command_line:
        with_decoding_overrides(param, overrides)
    assert str(typed.value) == str(command_line.value) == message


def test_constructed_settings_are_checked_by_the_schema() -> None:
    with pytest.raises(SettingError, match=r"^decoding.threshold=nan: expected a number in \[0, 1\)$"):
        DecodingSettings(threshold=float("nan"))
    with pytest.raises(SettingError, match=r"^input.roi=\[0, 0, 8, 8\]: a box of 8 x 8 pixels"):
        InputSettings(roi=[0, 0, 8, 8])
    with pytest.raises(SettingError, match=r"^decoding.averaging.keep_noise=1: expected true or false$"):
        AveragingSettings(keep_noise=1)
    assert InputSettings(roi=[8, 4, 120, 116], trained_clip=[0.5, 1]).roi == (8, 4, 120, 116)  # typed: a tuple


def _hypotheses(system: Any) -> Any:
    """The decoded hypotheses of one fixed synthetic input, every cell a candidate."""
    torch.manual_seed(0)
    x = torch.rand(1, 1, system.settings.input.size, system.settings.input.size)
    cam = Camera(120.0, 120.0, 63.5, 63.5, 128, 128, *system.settings.input.trained_clip)
    with torch.no_grad():
        return system.decode(system(x), [cam])[0]


def test_a_shipped_checkpoint_without_the_entry_reads_its_config_to_the_same_settings(tmp_path: Path) -> None:
    """``models/dense_bunny.ckpt`` holds no settings entry: its settings come from its run config, and the same
    checkpoint with the entry added loads to equal settings and decodes alike."""
    saved = torch.load(CKPT, map_location="cpu", weights_only=True)
    assert CHECKPOINT_KEY not in saved
    system, cfg = load_checkpoint(CKPT)
    settings = system.settings
    assert settings.input == InputSettings(128, "image", None, "area", (0.87599, 1.70602))
    assert settings.decoding == DecodingSettings(0.1, 0.2, "p*v", AveragingSettings(1.0, 1, "max"))
    assert settings.object == ObjectSettings(dict(saved["hyper_parameters"]["config"]["object"]))
    assert settings == RunSettings.from_training_config(cfg, decoding=DecodingSettings.of(system.parameterization))
    saved[CHECKPOINT_KEY] = settings.to_dict()
    path = tmp_path / "with_entry.ckpt"
    torch.save(saved, path)
    again, _ = load_checkpoint(path)
    assert again.settings == settings
    a, b = _hypotheses(system), _hypotheses(again)
    assert len(a) > 0 and np.array_equal(a.t, b.t) and np.array_equal(a.score, b.score)


def test_the_entry_decides_how_a_checkpoint_decodes(tmp_path: Path) -> None:
    saved = torch.load(CKPT, map_location="cpu", weights_only=True)
    system, _ = load_checkpoint(CKPT)
    tuned = system.settings.decoding.with_overrides({"threshold": 0.3, "averaging": {"eps": 0.5}})
    saved[CHECKPOINT_KEY] = system.settings.with_decoding(tuned).to_dict()
    path = tmp_path / "tuned.ckpt"
    torch.save(saved, path)
    loaded, _ = load_checkpoint(path)
    assert loaded.settings.decoding == tuned
    assert loaded.parameterization.threshold == 0.3 and loaded.parameterization.averaging.eps == 0.5
    system.set_decoding(tuned)
    a, b = _hypotheses(system), _hypotheses(loaded)
    assert np.array_equal(a.t, b.t) and np.array_equal(a.score, b.score)


def test_the_refinement_a_model_records_comes_from_deploy_refine_and_an_old_entry_records_none() -> None:
    cfg = {"deploy_refine": "search_fast", "data": {"roi": "auto:0.8"}}
    assert RunSettings.from_training_config(cfg).refine == "search_fast"
    assert RunSettings.from_training_config({"deploy_refine": None}).refine is None
    with pytest.raises(SettingError, match=r"^deploy_refine='serch': expected null or one of icp, search, search_fast"):
        RunSettings.from_training_config({"deploy_refine": "serch"})
    entry = EXAMPLES[-1].to_dict()
    assert entry["refine"] == "search_fast"
    del entry["refine"]  # an entry written before the key
    assert RunSettings.from_dict(entry, "x").refine is None


@pytest.mark.parametrize("name", ["icp", "search", "search_fast", "search_flat"])
def test_a_recorded_refinement_is_its_group_as_hydra_composes_it(name: str) -> None:
    from conftest import compose_cfg
    from omegaconf import OmegaConf

    from opnet.refine import model_refinement, refine_config, settings_from_config

    composed = OmegaConf.to_container(compose_cfg("eval", ["ckpt=x", f"refine={name}"]).refine, resolve=True)
    assert refine_config(name) == composed
    default = OmegaConf.to_container(compose_cfg("eval", ["ckpt=x"]).refine, resolve=True)
    assert default == {"method": "model"}  # eval.py's default: the model's own
    group, by_model = model_refinement(default, name)
    assert by_model and settings_from_config(group) == settings_from_config(composed)
    assert model_refinement(default, None) == ({"method": "none"}, False)
    assert model_refinement(composed, "icp") == (composed, False)  # a refinement named on the command line wins
    with pytest.raises(ValueError, match="refine=model"):
        settings_from_config(default)  # never read without its checkpoint


@pytest.mark.parametrize("name", REFINE_NAMES)
def test_the_runtime_runs_every_recordable_refinement_as_its_config(name: str) -> None:
    """Every name a checkpoint may record (REFINE_NAMES) has its case in the torch-free runtime, the settings
    its YAML gives (icp: the runtime's 100 ms budget); a name without one is refused, never run as another."""
    from opnet.deploy.runtime import recorded_refinement
    from opnet.refine import refine_config, settings_from_config

    expected = settings_from_config(refine_config(name))
    assert recorded_refinement(name, budget_ms=expected.budget_ms) == expected
    with pytest.raises(ValueError, match="refinement 'polish'"):
        recorded_refinement("polish")
