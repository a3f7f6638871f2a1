"""A small part's dataset is generated with the scene's lengths scaled to it and says so in
``generation.json``; a dataset made with the lengths as given is not completed with scaled ones."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from opnet.objects import builtin_object
from opnet.objects.model import ObjectModel
from opnet.synthesis import SceneConfig, generate_dataset


def _pin15() -> ObjectModel:
    pin = builtin_object("pin")
    mesh = pin.mesh.copy()
    mesh.apply_scale(0.015 / pin.diameter)
    return ObjectModel.from_mesh("pin15", mesh, "none")


def test_a_small_parts_dataset_records_the_scaled_lengths_and_refuses_unscaled_ones(tmp_path: Path) -> None:
    scene = SceneConfig(resolution=64, collision="convex_hull")
    out = tmp_path / "pin15"
    generate_dataset(_pin15(), out, cycles=1, drops=2, scene=scene, progress=False, previews=0)
    recorded = json.loads((out / "generation.json").read_text())["scene"]
    assert recorded["sized_for_d"] == pytest.approx(0.015)
    assert recorded["drop_gap"] == pytest.approx(0.003) and recorded["bin_wall_thickness"] == pytest.approx(0.003)
    assert recorded["camera_jitter_m"] == pytest.approx(0.0015) and recorded["settle_linear"] == pytest.approx(0.015)
    # the same call completes it (nothing to do); the lengths as given (small_part_d=0) are other settings
    generate_dataset(_pin15(), out, cycles=1, drops=2, scene=scene, progress=False, previews=0)
    with pytest.raises(ValueError, match="other settings|differ"):
        generate_dataset(_pin15(), out, cycles=2, drops=2, scene=SceneConfig(resolution=64, collision="convex_hull",
                                                                             small_part_d=0), progress=False, previews=0)
