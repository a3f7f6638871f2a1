"""A checkpoint's saved config is read as it was trained: AP checkpoints from before AP had point
placements keep the points they were trained with (the extent's ends)."""

from __future__ import annotations

import pytest

from opnet.cli.build import checkpoint_config

AP = "opnet.parameterizations.ap.APParameterization"


def _ckpt(param: dict) -> dict:
    return {"hyper_parameters": {"config": {"parameterization": param}}}


def test_an_ap_checkpoint_without_placement_keeps_the_extent_points():
    cfg = checkpoint_config(_ckpt({"_target_": AP, "grid": 16, "points": None}), "old.ckpt")
    assert cfg.parameterization.placement == "extent"


@pytest.mark.parametrize("placement", ["on_part", "extent"])
def test_a_saved_placement_is_kept(placement):
    cfg = checkpoint_config(_ckpt({"_target_": AP, "grid": 16, "placement": placement}), "new.ckpt")
    assert cfg.parameterization.placement == placement


def test_other_parameterizations_get_no_placement():
    cfg = checkpoint_config(_ckpt({"_target_": "opnet.parameterizations.vanilla.VanillaParameterization"}), "v.ckpt")
    assert "placement" not in cfg.parameterization
