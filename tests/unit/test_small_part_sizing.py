"""A part smaller than the scene's absolute lengths are set for gets them scaled to its size
(``scene.small_part_d``, :meth:`opnet.synthesis.SceneConfig.for_part`); the built-in parts and larger
ones keep their settings, so their datasets keep their bytes."""

from __future__ import annotations

import pytest

from opnet.objects import builtin_names, builtin_object
from opnet.objects.model import ObjectModel
from opnet.synthesis import SceneConfig
from opnet.synthesis.layout import make_rig

LENGTHS = {"bin_wall_thickness": 0.01, "drop_gap": 0.01, "bin_jitter_m": 0.01, "camera_jitter_m": 0.005,
           "settle_linear": 0.05}  # fmt: skip


def _pin(diameter: float) -> ObjectModel:
    pin = builtin_object("pin")
    mesh = pin.mesh.copy()
    mesh.apply_scale(diameter / pin.diameter)
    return ObjectModel.from_mesh("pin_small", mesh, "none")


def test_the_defaults_are_the_lengths_scaled() -> None:
    assert {k: getattr(SceneConfig(), k) for k in SceneConfig.PART_LENGTHS} == LENGTHS


def test_a_small_part_gets_the_lengths_scaled_by_its_size_once() -> None:
    cfg = SceneConfig(bin_jitter_m=0.03)  # a recipe's own value is scaled too
    sized = cfg.for_part(0.015)
    assert sized.sized_for_d == 0.015
    assert sized.bin_wall_thickness == pytest.approx(0.003) and sized.drop_gap == pytest.approx(0.003)
    assert sized.bin_jitter_m == pytest.approx(0.009) and sized.camera_jitter_m == pytest.approx(0.0015)
    assert sized.settle_linear == pytest.approx(0.015)
    assert sized.for_part(0.015) is sized and sized.for_part(0.005) is sized  # never twice
    assert sized.camera_jitter_deg == cfg.camera_jitter_deg and sized.resolution == cfg.resolution  # angles, pixels: kept


@pytest.mark.parametrize("diameter", [0.05, 0.0514, 0.234, 0.45])
def test_a_part_of_the_reference_size_or_larger_keeps_the_settings(diameter: float) -> None:
    cfg = SceneConfig()
    assert cfg.for_part(diameter) is cfg
    assert SceneConfig(small_part_d=0).for_part(0.001).drop_gap == 0.01  # 0: never scaled


def test_every_built_in_part_is_at_least_the_reference_size_and_the_record_is_unchanged() -> None:
    for name in builtin_names():
        cfg = SceneConfig()
        assert cfg.for_part(builtin_object(name).diameter) is cfg, name
    assert "small_part_d" not in SceneConfig().to_dict() and "sized_for_d" not in SceneConfig().to_dict()
    assert SceneConfig(small_part_d=0.02).to_dict()["small_part_d"] == 0.02


def test_make_rig_builds_a_small_parts_bin_with_the_scaled_walls() -> None:
    small, large = make_rig(_pin(0.015), 5, 1, SceneConfig()), make_rig(_pin(0.06), 5, 1, SceneConfig())
    assert small.bin.thickness == pytest.approx(0.003)
    assert large.bin.thickness == 0.01
    assert make_rig(_pin(0.015), 5, 1, SceneConfig(small_part_d=0)).bin.thickness == 0.01


@pytest.mark.parametrize("value", [-0.01, float("nan"), 25.0])
def test_a_bad_reference_size_is_one_line_naming_the_key(value: float) -> None:
    with pytest.raises(ValueError, match=r"^scene config: small_part_d="):
        SceneConfig(small_part_d=value)


def _dense(rig_d: float | None = 0.2) -> SceneConfig:
    from opnet.paths import REPO_ROOT

    return SceneConfig(camera_file=str(REPO_ROOT / "conf" / "cameras" / "sileane_bunny.yaml"), clip="camera",
                       camera_height=1.5, camera_jitter_m=0.03, bin_jitter_m=0.03, rig_d=rig_d)


def test_a_rig_set_up_for_one_part_is_scaled_to_another() -> None:
    half = _dense().for_part(0.1)
    assert half.sized_for_d == 0.1 and half.rig_d is None
    assert half.camera_height == pytest.approx(0.75)
    assert (half.clip_start, half.clip_end) == pytest.approx((0.875990 / 2, 1.706020 / 2))  # the file's, scaled
    assert half.camera_jitter_m == pytest.approx(0.015) and half.bin_jitter_m == pytest.approx(0.015)
    assert half.drop_gap == 0.01 and half.camera_jitter_deg == _dense().camera_jitter_deg  # not the rig's lengths
    assert half.for_part(0.1) is half  # never twice
    # a part smaller than small_part_d: the rig's lengths by the rig, the others by small_part_d
    pin = _dense().for_part(0.02)
    assert pin.camera_jitter_m == pytest.approx(0.003) and pin.drop_gap == pytest.approx(0.004)


def test_the_part_the_rig_is_set_up_for_keeps_its_settings_and_record() -> None:
    cfg = _dense(0.2)
    same = cfg.for_part(0.2)
    assert same.rig_d is None and same.sized_for_d is None
    assert same.to_dict() == _dense(None).to_dict()  # its datasets' generation.json as before the key
    assert _dense(None).for_part(0.1).camera_height == 1.5  # no rig_d: the rig as given


def test_make_rig_frames_every_part_as_the_rig_frames_its_own() -> None:
    """The image of a part scaled from the rig's: the same pixels per diameter, the bin in view."""
    sizes = {}
    for d in (0.03, 0.2, 0.45):
        rig = make_rig(_pin(d), 20, 1, _dense(0.2))
        sizes[d] = rig.camera.fx * d / rig.params.location[2]
        assert rig.camera.clip_start == pytest.approx(0.875990 * d / 0.2)
    assert sizes[0.03] == pytest.approx(sizes[0.2], rel=1e-6) and sizes[0.45] == pytest.approx(sizes[0.2], rel=1e-6)


def test_rig_d_is_checked() -> None:
    for bad in (0.0, -1.0, float("nan")):
        with pytest.raises(ValueError, match="rig_d"):
            SceneConfig(rig_d=bad)
