"""The network sized to the part, before anything is built; the resolved sizes are what the run records
(checkpoint, ONNX). Two settings (results/flat_parts/README.md: what a flat part needs):

- ``part_pixels``: the input side, the network and its grid chosen so that the part's diameter D spans a given
  number of input pixels;
- ``part_cells``: the output grid chosen so that D spans at least this many of its cells (a finer grid over the
  same input: the network keeps fewer of its halvings), never coarser than configured, at most one cell per
  ``model.stem_stride`` pixels. A part spanning two or three cells is found as one hypothesis of a few cells that
  also see its neighbours; spanning five or more, each of its cells sees mostly the part.

Where the input is a square of known metric side, the bin finder's crop ``data.roi=auto:S`` (the cell recipe),
the side is ``S``: ``input = 32 * ceil(part_pixels * S / D / 32)`` (at least ``model.in_size`` as configured,
at most 512), the model built for it and the grid keeping the configured pixels per cell (16 cells at 128:
8 pixels a cell).

A third, ``flat_part``, is what a flat part (thin against its width: the refinement's search turns it about its
normal, :func:`opnet.refine.search.is_flat`) trains and records instead of the recipe's own: ``deploy_refine`` (its
refinement), ``threshold`` (the decoding's presence threshold) and ``max_steps``; a key given on the command line
wins."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from omegaconf import DictConfig, open_dict

#: the largest input the sizing chooses (pixels a side)
MAX_SIZED_INPUT = 512
#: input sides are multiples of this (the network halves the input up to five times)
SIZE_STEP = 32


def sized_input(part_pixels: float, side_m: float, diameter_m: float, smallest: int) -> int:
    """The input side (pixels) at which a part of ``diameter_m`` spans ``part_pixels`` pixels of a square of
    ``side_m`` metres: a multiple of :data:`SIZE_STEP`, at least ``smallest``, at most :data:`MAX_SIZED_INPUT`."""
    need = part_pixels * side_m / diameter_m
    return int(min(MAX_SIZED_INPUT, max(smallest, SIZE_STEP * math.ceil(need / SIZE_STEP - 1e-9))))


def sized_grid(part_cells: float, side_m: float, diameter_m: float, grid: int, finest: int) -> int:
    """The output grid (cells a side) at which a part of ``diameter_m`` spans ``part_cells`` cells of a square of
    ``side_m`` metres: ``grid`` doubled until it does, at most ``finest`` (the grid of one cell per stem stride)."""
    while grid < finest and diameter_m / side_m * grid < part_cells - 1e-9:
        grid *= 2
    return min(grid, finest)


def _square_side(cfg: DictConfig, key: str, value: Any) -> float:
    """The metric side of the input square (``data.roi=auto:S``); ValueError naming ``key`` without one."""
    from opnet.data.roi import auto_side, is_auto, parse_roi

    roi = parse_roi((cfg.get("data") or {}).get("roi"))
    side = auto_side(roi) if is_auto(roi) else None
    if side is None:
        raise ValueError(f"{key}={value}: sizes the input of a square of known side, the bin finder's crop "
                         f"data.roi=auto:S (S metres); data.roi is {roi!r}: set data.roi=auto:S or {key}=null")
    return side


def _sizing_setting(cfg: DictConfig, key: str, lo: float, hi: float, expected: str) -> tuple[Any, float]:
    """(value of ``key``, side of the input square), or (None, 0.0) where ``key`` is not set; ValueError naming
    ``key`` where its value is not a number in [lo, hi] or the input is not the bin finder's square."""
    value: Any = cfg.get(key)
    if value is None:
        return None, 0.0
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not lo <= float(value) <= hi:
        raise ValueError(f"{key}={value!r}: expected {expected}")
    return value, _square_side(cfg, key, value)


def size_to_part(cfg: DictConfig, diameter_m: float) -> list[str]:
    """Apply ``part_pixels`` then ``part_cells`` to ``cfg``; the lines the console states (none where neither is
    set). Raises ValueError naming the key where one cannot be applied."""
    lines = [size_input_to_part(cfg, diameter_m), size_grid_to_part(cfg, diameter_m)]
    return [line for line in lines if line]


def size_grid_to_part(cfg: DictConfig, diameter_m: float) -> str | None:
    """Apply ``part_cells`` to ``cfg`` (``parameterization.grid``); the line the console states, or None where it
    is not set. Raises ValueError naming the key where it cannot be applied (not a number from 1 to 64; an input
    that is not the bin finder's square)."""
    cells, side = _sizing_setting(cfg, "part_cells", 1, 64, "the output cells the part's diameter should span at "
                                  "least, a number from 1 to 64 (null: the grid as configured)")
    if cells is None:
        return None
    in_size, grid = int(cfg.model.in_size), int(cfg.parameterization.grid)
    finest = in_size // int(cfg.model.get("stem_stride", 2))
    new_grid = sized_grid(float(cells), side, diameter_m, grid, finest)
    with open_dict(cfg):
        cfg.parameterization.grid = new_grid
    reached = "" if diameter_m / side * new_grid >= float(cells) - 1e-9 else " (the finest grid of this input)"
    return (f"grid sized to the part: D {diameter_m * 1000:.0f} mm over the {side:g} m square spans "
            f"{diameter_m / side * new_grid:.1f} of {new_grid} cells (part_cells={cells:g}){reached}")


def size_input_to_part(cfg: DictConfig, diameter_m: float) -> str | None:
    """Apply ``part_pixels`` to ``cfg`` (``data.input_size``, ``model.in_size``, ``parameterization.grid``); the
    line the console states, or None where it is not set. Raises ValueError naming the key where it cannot be
    applied (not a positive number; an input that is not the bin finder's square ``data.roi=auto:S``)."""
    pixels, side = _sizing_setting(cfg, "part_pixels", 8, 512, "the pixels the part's diameter should span at the "
                                   "network's input, a number from 8 to 512 (null: the input as configured)")
    if pixels is None:
        return None
    in_size, grid = int(cfg.model.in_size), int(cfg.parameterization.grid)
    size = sized_input(float(pixels), side, diameter_m, in_size)
    new_grid = max(1, grid * size // in_size)
    with open_dict(cfg):
        cfg.data.input_size = size
        cfg.model.in_size = size
        cfg.parameterization.grid = new_grid
    return (f"input sized to the part: D {diameter_m * 1000:.0f} mm over the {side:g} m square spans "
            f"{diameter_m / side * size:.0f} of {size} pixels (part_pixels={pixels:g}), grid {new_grid}")


#: the keys ``flat_part`` may set, and the config key each one sets
FLAT_PART_KEYS = {"deploy_refine": "deploy_refine", "threshold": "parameterization.threshold",
                  "max_steps": "trainer.max_steps"}


def settings_for_flat_part(cfg: DictConfig, mesh: Any, given: set[str] = frozenset()) -> str | None:
    """Apply ``flat_part`` to ``cfg`` where the part of ``mesh`` (a trimesh) is flat, but for the config keys in
    ``given`` (set on the command line: they win); the line the console states, or None where ``flat_part`` is not
    set or the part is not flat. Raises ValueError naming the key where it is not a mapping of
    :data:`FLAT_PART_KEYS`."""
    flat_part: Any = cfg.get("flat_part")
    if flat_part is None:
        return None
    if not isinstance(flat_part, DictConfig) or set(flat_part) - set(FLAT_PART_KEYS):
        raise ValueError(f"flat_part={flat_part!r}: expected a mapping of {', '.join(FLAT_PART_KEYS)} (null: none)")
    if mesh is None:
        return None
    import trimesh
    from omegaconf import OmegaConf

    from opnet.refine.search import is_flat

    points, _ = trimesh.sample.sample_surface_even(mesh, 600, seed=0)
    if not is_flat(np.asarray(points)):
        return None
    said = []
    with open_dict(cfg):
        for key, value in flat_part.items():
            target = FLAT_PART_KEYS[key]
            if target in given:
                said.append(f"{target} as given")
            else:
                OmegaConf.update(cfg, target, value, merge=False)
                said.append(f"{target}={value}")
    return "a flat part (flat_part): " + ", ".join(said)


def command_line_keys() -> set[str]:
    """The config keys set on the command line of the running Hydra app (none outside one)."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return set()
    return {item.split("=", 1)[0].lstrip("+~") for item in HydraConfig.get().overrides.task}


__all__ = ["FLAT_PART_KEYS", "MAX_SIZED_INPUT", "SIZE_STEP", "command_line_keys", "settings_for_flat_part",
           "size_grid_to_part", "size_input_to_part", "size_to_part", "sized_grid", "sized_input"]
