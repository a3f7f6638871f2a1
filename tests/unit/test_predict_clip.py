"""The clip planes an input's depth is normalized with: the training scenes' (recorded by train.py
when they share one pair), the camera's, or given ones (predict.py clip=, the runtime's --clip); a
bad value is one error naming it."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from omegaconf import OmegaConf

from opnet.data.scene_data import SceneSamples
from opnet.geometry.camera import Camera, describe_clip, parse_clip, working_clip


def test_clip_reads_two_metres() -> None:
    assert parse_clip(None) is None
    assert parse_clip(OmegaConf.to_container(OmegaConf.create({"c": [1.55, 2.05]}).c)) == (1.55, 2.05)
    assert parse_clip([1, 2]) == (1.0, 2.0)
    assert parse_clip(OmegaConf.create({"c": [1.55, 2.05]}).c) == (1.55, 2.05)  # a Hydra override as it comes


@pytest.mark.parametrize(("value", "message"), [
    ([2.05, 1.55], r"clip=\[2.05, 1.55\]: expected 0 < near < far"),
    ([0.5], r"clip=\[0.5\]: expected \[near, far\] in metres"),
    ("1.5", r"clip='1.5': expected \[near, far\] in metres"),
    ("12", r"clip='12': expected \[near, far\] in metres"),
    ([0.5, 1550.0], r"far <= 50 metres"),
])
def test_a_bad_clip_is_one_error(value, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        parse_clip(value)


def test_working_clip_is_the_models_planes_unless_told_otherwise() -> None:
    trained = (1.55, 2.05)
    assert working_clip("model", trained) == trained and working_clip(None, trained) == trained
    assert working_clip("model", None) is None  # a checkpoint that records none: the camera's
    assert working_clip("camera", trained) is None
    assert working_clip([0.5, 1.5], trained) == (0.5, 1.5)
    with pytest.raises(ValueError, match=r"clip='modle': expected model, camera or \[near, far\]"):
        working_clip("modle", trained)
    assert describe_clip(trained, trained) == "clip planes: [1.55, 2.05] m (the model's training planes)"
    assert describe_clip((0.5, 1.5), trained) == "clip planes: [0.5, 1.5] m (given)"
    assert describe_clip(None, None) == "clip planes: each camera's own (the model records no training planes)"


class _Scenes:
    """Records with only a camera, the planes of scene i from ``planes(i)``."""

    def __init__(self, n: int, planes) -> None:
        self.n, self.planes = n, planes

    def __len__(self) -> int:
        return self.n

    def __getitem__(self, i: int) -> SimpleNamespace:
        near, far = self.planes(i)
        return SimpleNamespace(camera=Camera(500.0, 500.0, 63.5, 63.5, 128, 128, near, far))


def test_training_scenes_clip_planes_are_one_pair_or_none() -> None:
    same = SceneSamples(_Scenes(40, lambda i: (0.5, 1.5)), range(40))
    assert same.clip_planes() == (0.5, 1.5)
    mixed = SceneSamples(_Scenes(40, lambda i: (0.5, 1.5) if i < 30 else (1.0, 2.0)), range(40))
    assert mixed.clip_planes() is None  # two camera set-ups: no one normalization
    assert SceneSamples(_Scenes(3, lambda i: (0.5, 1.5)), []).clip_planes() is None


@pytest.mark.parametrize("value", [[True, 2], [1, False], ["1.5", "2"], [1.5, 2.0, 3.0], list(range(200_000))])
def test_clip_planes_are_two_numbers_never_booleans_or_text_and_the_message_stays_short(value: list) -> None:
    """A checkpoint's or an ONNX export's trained_clip of [true, 2] was read as [1, 2] m; a 200,000-number one
    was echoed whole in the message."""
    with pytest.raises(ValueError, match=r"^trained_clip=.*: expected \[near, far\] in metres$") as e:
        parse_clip(value, "trained_clip")
    assert len(str(e.value)) < 160


def test_onnx_metadata_refuses_a_boolean_trained_clip() -> None:
    import importlib.util

    from opnet.deploy.metadata import validate_metadata
    from opnet.paths import REPO_ROOT

    spec = importlib.util.spec_from_file_location("onnx_meta_tests", REPO_ROOT / "tests" / "unit" / "test_onnx_metadata.py")
    helpers = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(helpers)
    meta = helpers._meta()
    meta["trained_clip"] = [1.55, 2.05]
    assert validate_metadata(meta, "m.onnx")["trained_clip"] == (1.55, 2.05)
    meta["trained_clip"] = [True, 2]
    with pytest.raises(ValueError, match=r"trained_clip=\[True, 2\]: expected \[near, far\] in metres"):
        validate_metadata(meta, "m.onnx")
