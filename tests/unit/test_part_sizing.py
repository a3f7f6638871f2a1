"""part_pixels: the network's input sized so that the part's diameter spans a given number of input pixels
(the bin finder's square of S metres), the model and its grid built for it; bad settings one line."""

from __future__ import annotations

import pytest

from opnet.cli.build import build_components
from opnet.cli.sizing import sized_input, size_input_to_part
from opnet.objects import builtin_object
from opnet.studies import compose_train


def test_the_side_follows_the_part_and_the_square() -> None:
    # a 174 mm part in a 0.8 m square: 28 pixels at 128; 56 asked -> 257.5 -> 288 (a multiple of 32)
    assert sized_input(56, 0.8, 0.174, 128) == 288
    assert sized_input(28, 0.8, 0.174, 128) == 160  # 128.7 -> 160
    assert sized_input(20, 0.8, 0.174, 128) == 128  # never below the configured input
    assert sized_input(500, 0.8, 0.05, 128) == 512  # never above 512


def test_the_config_is_sized_and_the_network_built_for_it() -> None:
    obj = builtin_object("bracket")
    cfg = compose_train(["object=bracket", "data.roi=auto:0.4", "part_pixels=45"])
    line = size_input_to_part(cfg, obj.diameter)
    want = sized_input(45, 0.4, obj.diameter, 128)
    assert want > 128 and cfg.data.input_size == want and cfg.model.in_size == want
    assert cfg.parameterization.grid == want // 8  # 16 cells at 128: 8 pixels a cell, kept
    assert f"{want} pixels" in line and "part_pixels=45" in line
    system = build_components(cfg).system
    assert system.parameterization.grid_size == want // 8


def test_unset_leaves_the_config_as_it_is() -> None:
    cfg = compose_train(["object=bracket", "data.roi=auto:0.4"])
    assert size_input_to_part(cfg, 0.1) is None and cfg.data.input_size == 128


@pytest.mark.parametrize(("overrides", "message"), [
    (["part_pixels=45"], "needs data.roi=auto:S|sizes the input of a square of known side"),
    (["data.roi=auto:0.4", "part_pixels=0"], "expected the pixels the part's diameter should span"),
    (["data.roi=auto:0.4", "part_pixels=true"], "expected the pixels the part's diameter should span"),
])  # fmt: skip
def test_bad_settings_are_one_line_naming_the_key(overrides: list[str], message: str) -> None:
    cfg = compose_train(["object=bracket", *overrides])
    with pytest.raises(ValueError, match=message) as e:
        size_input_to_part(cfg, 0.1)
    assert "\n" not in str(e.value) and "part_pixels" in str(e.value)
