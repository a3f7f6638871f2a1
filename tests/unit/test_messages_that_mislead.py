"""Messages that say what is wrong: a camera tilt is refused with the largest tilt this camera takes (a 60°
tilt at 45° azimuth was "tilt + half the field of view >= 90" at 85°); generation's errors name the key
the user set and its bound (a low camera blamed camera_jitter_m with "expected < -0.021", a narrow field of
view blamed camera_jitter_deg, ``previews=abc`` was int()'s message, ``previews=-1`` passed, the jitter's
bound was "less", ``cycles``/``drops`` shared one message, a physics step of 10 s ended in a traceback).
(The split with nothing to find: tests/unit/test_nothing_to_find.py.) Each failed before its fix."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from opnet.cli.generate import run as generate
from opnet.objects import builtin_object
from opnet.paths import config_dir
from opnet.synthesis import SceneConfig
from opnet.synthesis.layout import make_rig

ZBRACKET = builtin_object("zbracket")


def _rig(**scene: object) -> object:
    return make_rig(ZBRACKET, 3, 2, SceneConfig(resolution=64, **scene))


def test_a_tilt_above_the_horizon_is_refused_with_the_largest_tilt_this_camera_takes() -> None:
    with pytest.raises(ValueError) as info:
        _rig(camera_tilt_deg=60, camera_azimuth_deg=45)
    message = str(info.value)
    assert message.startswith("scene config: camera_tilt_deg=60: ") and ">= 90" not in message, message
    largest = float(re.search(r"takes a tilt below ([\d.]+) degrees", message).group(1))
    assert 50 < largest < 60 and "camera_azimuth_deg=45" in message
    _rig(camera_tilt_deg=largest - 0.2, camera_azimuth_deg=45)  # the bound is the camera's
    with pytest.raises(ValueError, match="camera_tilt_deg"):
        _rig(camera_tilt_deg=largest + 0.2, camera_azimuth_deg=45)


@pytest.mark.parametrize(("override", "message"), [
    ("cycles=-1", r"^cycles=-1: expected a whole number >= 0$"),
    ("drops=300", r"^drops=300: expected a whole number in 0\.\.254"),
    ("previews=abc", r"^previews='abc': expected a whole number"),
    ("previews=-1", r"^previews=-1: expected a whole number >= 0"),
    ("scene.camera_height=0.01", r"^scene config: camera_height=0.01 .*bin walls.*expected more than 0.0"),
    ("scene.fov_deg=1", r"^scene config: camera_jitter_deg=1.0 .*scene.fov_deg=1.*expected camera_jitter_deg < 0.5"),
    ("scene.camera_jitter_deg=30", r"^scene config: camera_jitter_deg=30 .*expected camera_jitter_deg < 25.0"),
    ("scene.time_step=10", r"^scene config: time_step=10.*expected seconds in \(0, 0.05\]"),
])  # fmt: skip
def test_generation_errors_name_the_key_given_and_its_bound(tmp_path: Path, override: str, message: str) -> None:
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose(config_name="generate", overrides=[
            "object=pin", "scene=small", "scene.resolution=32", "cycles=1", "drops=1", f"out={tmp_path / 'ds'}",
            "progress=false", "previews=0", override])  # fmt: skip
    with pytest.raises(ValueError, match=message) as info:
        generate(cfg)
    assert "\n" not in str(info.value)
    assert not (tmp_path / "ds").exists()


def test_a_pile_that_cannot_be_made_is_a_user_error() -> None:
    from opnet.synthesis.physics.base import PileError

    assert issubclass(PileError, ValueError) and issubclass(PileError, RuntimeError)
