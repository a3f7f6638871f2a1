"""The working volume is one setting, ``scene.clip``: its values, the records of the datasets made before it
(``clip_start`` / ``clip_end`` / ``camera_file_clip`` in ``generation.json``) read back and written as they
were, and a command line that names it."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from conftest import compose_cfg
from opnet.objects import builtin_object
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.layout import make_rig
from opnet.synthesis.working_volume import normal_recorded

CAMERA_YAML = "fx: 150.0\nfy: 152.0\ncx: 55.3\ncy: 50.8\nwidth: 160\nheight: 120\nclip_start: 0.3\nclip_end: 2.0\n"


@pytest.fixture
def camera(tmp_path: Path) -> str:
    path = tmp_path / "camera.yaml"
    path.write_text(CAMERA_YAML)
    return str(path)


@pytest.mark.parametrize(("clip", "planes"), [
    (None, (None, None)), ("camera", ("camera", "camera")), ([0.4, 1.5], (0.4, 1.5)), ([None, 1.5], (None, 1.5)),
    ([0.4, "camera"], (0.4, "camera")),
])  # fmt: skip
def test_the_values_of_clip(clip: object, planes: tuple, camera: str) -> None:
    assert SceneConfig(camera_file=camera, clip=clip).clip == planes


@pytest.mark.parametrize(("clip", "planes"), [
    (None, None), ("camera", (0.3, 2.0)), ([0.4, 1.5], (0.4, 1.5)), ([0.4, "camera"], (0.4, 2.0)),
    ([None, 1.5], None),
])  # fmt: skip
def test_the_rig_takes_its_planes_from_clip(clip: object, planes: tuple | None, camera: str) -> None:
    rig = make_rig(builtin_object("zbracket"), 3, 1, SceneConfig(camera_file=camera, camera_height=1.0, clip=clip))
    derived = make_rig(builtin_object("zbracket"), 3, 1, SceneConfig(camera_file=camera, camera_height=1.0)).camera
    want = planes or (derived.clip_start, clip[1] if isinstance(clip, list) else derived.clip_end)
    assert (rig.camera.clip_start, rig.camera.clip_end) == pytest.approx(want)


@pytest.mark.parametrize(("recorded", "clip"), [
    ({"clip_start": None, "clip_end": None}, (None, None)),
    ({"clip_start": None, "clip_end": None, "camera_file_clip": True}, ("camera", "camera")),
    ({"clip_start": 0.4, "clip_end": None, "camera_file_clip": True}, (0.4, "camera")),
    ({"clip_start": 0.4, "clip_end": 1.5}, (0.4, 1.5)),
])  # fmt: skip
def test_a_datasets_record_reads_back_and_is_written_as_it_was(recorded: dict, clip: tuple, camera: str) -> None:
    scene = SceneConfig.from_dict({"camera_file": camera, **recorded})
    assert scene.clip == clip
    written = scene.to_dict()
    assert {k: written[k] for k in recorded} == recorded
    assert ("camera_file_clip" in written) == ("camera_file_clip" in recorded)
    assert list(written).index("clip_end") == list(written).index("clip_start") + 1


def test_a_record_whose_camera_planes_were_both_given_matches_today(camera: str) -> None:
    """The cell recipe used to set both planes and camera_file_clip: true (the file's planes unused): its datasets
    keep matching the same planes given as ``clip: [near, far]``."""
    old = {"camera_file": camera, "clip_start": 0.4, "clip_end": 1.5, "camera_file_clip": True}
    today = SceneConfig(camera_file=camera, clip=[0.4, 1.5]).to_dict()
    assert normal_recorded(old, 20.0) == {k: today[k] for k in old if k in today}
    assert "camera_file_clip" not in today


def test_clip_beside_a_recorded_key_is_refused() -> None:
    with pytest.raises(ValueError, match=r"^scene config: clip_start and clip both given"):
        SceneConfig.from_dict({"clip": None, "clip_start": 0.5})


def test_the_generator_reuses_a_dataset_recorded_with_the_old_keys(tmp_path: Path) -> None:
    """A dataset made before ``clip`` (its generation.json rewritten to the old keys) is still the same dataset
    for the same settings: completing it is not refused."""
    from conftest import small_builtin_dataset

    root = small_builtin_dataset(tmp_path / "d", "zbracket", 1, 1, 0, clip=[None, 1.9])
    record = json.loads((root / "generation.json").read_text())
    assert (record["scene"]["clip_start"], record["scene"]["clip_end"]) == (None, 1.9) and "clip" not in record["scene"]
    record["scene"]["camera_file_clip"] = False  # as a dataset of that time may hold it
    (root / "generation.json").write_text(json.dumps(record))
    small_builtin_dataset(root, "zbracket", 2, 1, 0, clip=[None, 1.9])
    assert (root / "p_depth" / "cycle_0001").is_dir()


def test_the_command_line_sets_it_in_one_key() -> None:
    cfg = compose_cfg("generate", ["scene.clip=[0.5,1.7]"])
    assert SceneConfig.from_dict(dict(cfg.scene) | {"clip": list(cfg.scene.clip)}).clip == (0.5, 1.7)
    with pytest.raises(Exception, match="clip_start"):
        compose_cfg("generate", ["scene.clip_start=0.5"])
