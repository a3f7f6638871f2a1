"""part_pixels: the network's input sized so that the part's diameter spans a given number of input pixels
(the bin finder's square of S metres), the model and its grid built for it; bad settings one line."""

from __future__ import annotations

import pytest

from opnet.cli.build import build_components
from opnet.cli.sizing import size_input_to_part, size_to_part, sized_grid, sized_input
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


def test_the_grid_follows_the_part_and_the_square() -> None:
    # a 175 mm part in a 0.8 m square spans 3.5 cells of 16: 5.5 asked -> 32 (7 cells); never beyond the finest
    assert sized_grid(5.5, 0.8, 0.175, 16, 32) == 32
    assert sized_grid(3.0, 0.8, 0.175, 16, 32) == 16  # already spans 3.5: kept, never coarser
    assert sized_grid(20.0, 0.8, 0.175, 16, 32) == 32  # the finest grid of the input
    assert sized_grid(5.5, 0.4, 0.175, 8, 32) == 16  # 3.5 cells of 8 -> 7 of 16


def test_part_cells_sizes_the_grid_and_the_network_is_built_for_it() -> None:
    obj = builtin_object("bracket")
    side = 3.0 * obj.diameter  # the part spans 16 / 3 cells of the configured 16
    cfg = compose_train(["object=bracket", f"data.roi=auto:{side:g}", "model=small", "part_cells=8"])
    lines = size_to_part(cfg, obj.diameter)
    assert cfg.parameterization.grid == 32 and cfg.data.input_size == 128  # the input as configured
    assert len(lines) == 1 and "of 32 cells (part_cells=8)" in lines[0]
    assert build_components(cfg).system.parameterization.grid_size == 32


def test_part_pixels_then_part_cells() -> None:
    obj = builtin_object("bracket")
    cfg = compose_train(["object=bracket", "data.roi=auto:0.4", "model=small", "part_pixels=45", "part_cells=20"])
    lines = size_to_part(cfg, obj.diameter)
    size = sized_input(45, 0.4, obj.diameter, 128)
    assert cfg.data.input_size == size and cfg.parameterization.grid == size // 4  # the finest at stem stride 4
    assert len(lines) == 2 and "the finest grid of this input" in lines[1]


@pytest.mark.parametrize(("overrides", "message"), [
    (["part_pixels=45"], "needs data.roi=auto:S|sizes the input of a square of known side"),
    (["data.roi=auto:0.4", "part_pixels=0"], "expected the pixels the part's diameter should span"),
    (["data.roi=auto:0.4", "part_pixels=true"], "expected the pixels the part's diameter should span"),
    (["part_cells=5"], "sizes the input of a square of known side"),
    (["data.roi=auto:0.4", "part_cells=0"], "expected the output cells the part's diameter should span"),
    (["data.roi=auto:0.4", "part_cells=abc"], "expected the output cells the part's diameter should span"),
])  # fmt: skip
def test_bad_settings_are_one_line_naming_the_key(overrides: list[str], message: str) -> None:
    cfg = compose_train(["object=bracket", *overrides])
    with pytest.raises(ValueError, match=message) as e:
        size_to_part(cfg, 0.1)
    key = overrides[-1].split("=")[0]
    assert "\n" not in str(e.value) and key in str(e.value)


def _box(*sides: float):
    import trimesh

    return trimesh.creation.box(sides)


def test_a_flat_part_trains_and_records_the_cell_recipes_flat_part_settings() -> None:
    """experiment=cell's ``flat_part``: a 120 x 80 x 2 mm plate gets its refinement and threshold, a 50 x 40 x 30 mm
    block the recipe's own."""
    from opnet.cli.sizing import settings_for_flat_part

    cfg = compose_train(["experiment=cell", "object=bracket"])
    assert cfg.flat_part.deploy_refine == "search_flat" and cfg.deploy_refine == "search_fast"
    threshold = cfg.parameterization.threshold
    assert settings_for_flat_part(cfg, _box(0.05, 0.04, 0.03)) is None
    assert cfg.deploy_refine == "search_fast" and cfg.parameterization.threshold == threshold
    line = settings_for_flat_part(cfg, _box(0.12, 0.08, 0.002))
    assert cfg.deploy_refine == "search_flat" and cfg.parameterization.threshold == cfg.flat_part.threshold != threshold
    assert cfg.trainer.max_steps == cfg.flat_part.max_steps == 6000
    assert "deploy_refine=search_flat" in line and "parameterization.threshold=" in line


def test_a_key_given_on_the_command_line_wins_over_flat_part() -> None:
    from opnet.cli.sizing import settings_for_flat_part

    cfg = compose_train(["experiment=cell", "object=bracket", "trainer.max_steps=300"])
    line = settings_for_flat_part(cfg, _box(0.12, 0.08, 0.002), {"trainer.max_steps"})
    assert cfg.trainer.max_steps == 300 and cfg.deploy_refine == "search_flat"
    assert "trainer.max_steps as given" in line


@pytest.mark.parametrize("value", ["{refine: search_flat}", "search_flat"])
def test_a_bad_flat_part_is_one_line_naming_it(value: str) -> None:
    from opnet.cli.sizing import settings_for_flat_part

    cfg = compose_train(["object=bracket", f"flat_part={value}"])
    with pytest.raises(ValueError, match="^flat_part=.*expected a mapping of deploy_refine, threshold") as e:
        settings_for_flat_part(cfg, _box(0.12, 0.08, 0.002))
    assert "\n" not in str(e.value)
