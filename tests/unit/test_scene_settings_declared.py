"""Scene settings are declared once: each SceneConfig field carries its group and its roles (later field, rig
length, part length, bin model key), and conf/scene/default.yaml lists the same fields, grouped alike, at the
same defaults."""

from __future__ import annotations

import dataclasses
import re

import pytest
import yaml

from opnet.paths import REPO_ROOT
from opnet.synthesis import config as scene_config
from opnet.synthesis.config import BIN_MODEL_KEYS, SETTING_GROUPS, SceneConfig, scene_keys

DEFAULT_YAML = REPO_ROOT / "conf" / "scene" / "default.yaml"
#: set by SceneConfig.for_part, never by a user
DERIVED = {"sized_for_d"}
#: the fields of the first datasets' generation.json (made before any field declared ``later`` existed): a
#: field outside this list that is not declared ``later`` would be written into every record at its default,
#: and every dataset made before it would no longer match its configuration (refused as another dataset)
FIRST_FORMAT = ("resolution", "width", "height", "fov_deg", "camera_height", "view_margin", "clip_start", "clip_end",
                "camera_jitter_m", "camera_jitter_deg", "bin_jitter_m", "bin_jitter_deg", "bin_inner", "bin_layers",
                "bin_wall_height", "bin_wall_factor", "bin_wall_thickness", "collision", "convexity_threshold",
                "vhacd_resolution", "cache_dir", "time_step", "solver_iterations", "friction", "rolling_friction",
                "restitution", "linear_damping", "angular_damping", "drop_gap", "settle_linear", "settle_angular",
                "settle_checks", "check_every", "settle_time_cap", "max_redrops", "max_cycle_restarts",
                "solo_cache_mm", "solo_cache_deg", "physics")  # fmt: skip


def _yaml_groups() -> dict[str, str]:
    """key -> the group header (``# == <group>: ...``) it is listed under in default.yaml."""
    groups, group = {}, None
    for line in DEFAULT_YAML.read_text().splitlines():
        header = re.match(r"# == (\w+):", line)
        if header:
            group = header.group(1)
        key = re.match(r"^(\w+):", line)
        if key:
            groups[key.group(1)] = group
    return groups


def test_default_yaml_lists_every_field_at_its_default() -> None:
    values = yaml.safe_load(DEFAULT_YAML.read_text())
    fields = {f.name: f.default for f in dataclasses.fields(SceneConfig)}
    assert set(values) == set(fields) - DERIVED, "conf/scene/default.yaml and SceneConfig list other fields"
    for key, value in values.items():
        assert value == pytest.approx(fields[key]) if isinstance(value, float) else value == fields[key], key


def test_default_yaml_groups_the_fields_as_declared() -> None:
    declared = {f.name: f.metadata["group"] for f in dataclasses.fields(SceneConfig)}
    listed = _yaml_groups()
    assert {k: declared[k] for k in listed} == listed
    assert set(declared.values()) <= set(SETTING_GROUPS)


def test_every_field_after_the_first_format_is_declared_later() -> None:
    """A new field must be declared ``later`` (left out of the record at its default), or every dataset made
    before it is refused; the first format's fields are always written."""
    names = [f.name for f in dataclasses.fields(SceneConfig)]
    i = names.index("clip")  # the working volume, recorded as the first format's two planes
    names[i:i + 1] = ["clip_start", "clip_end"]
    assert set(FIRST_FORMAT) <= set(names)
    assert set(scene_keys("later")) == set(names) - set(FIRST_FORMAT)
    assert list(SceneConfig().to_dict()) == [n for n in names if n in FIRST_FORMAT]


def test_roles_come_from_the_declarations() -> None:
    assert set(SceneConfig.RIG_LENGTHS) == {"camera_height", "clip", "camera_jitter_m",
                                            "bin_jitter_m"}
    assert set(SceneConfig.PART_LENGTHS) == {"bin_wall_thickness", "drop_gap", "bin_jitter_m", "camera_jitter_m",
                                             "settle_linear"}
    assert set(BIN_MODEL_KEYS) == {"bin_inner", "bin_inner_y", "bin_wall_height", "bin_wall_thickness",
                                   "bin_hole_size", "bin_hole_pitch", "bin_clearance"}
    assert scene_config._LATER_FIELDS == scene_keys("later")


def test_the_cell_recipe_asks_for_cell_settings_only() -> None:
    """The measured keys ``experiment=cell`` leaves to the cell file (``???``) are the ones declared ``cell``."""
    recipe = yaml.safe_load((REPO_ROOT / "conf" / "experiment" / "cell.yaml").read_text())
    asked = {k for k, v in recipe["scene"].items() if v == "???"}
    assert asked and asked <= set(scene_keys(group="cell"))


def test_a_field_in_an_unknown_group_is_refused() -> None:
    with pytest.raises(ValueError, match="scene setting group 'optics'"):
        scene_config._setting(1.0, "optics")
