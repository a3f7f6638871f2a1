"""The network's input sized to the part (``part_pixels``): the input side, the network and its grid chosen so
that the part's diameter D spans a given number of input pixels (results/flat_parts/README.md: what a flat
part needs), before anything is built; the resolved sizes are what the run records (checkpoint, ONNX).

Where the input is a square of known metric side, the bin finder's crop ``data.roi=auto:S`` (the cell recipe),
the side is ``S``: ``input = 32 * ceil(part_pixels * S / D / 32)`` (at least ``model.in_size`` as configured,
at most 512), the model built for it and the grid keeping the configured pixels per cell (16 cells at 128:
8 pixels a cell)."""

from __future__ import annotations

import math
from typing import Any

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


def size_input_to_part(cfg: DictConfig, diameter_m: float) -> str | None:
    """Apply ``part_pixels`` to ``cfg`` (``data.input_size``, ``model.in_size``, ``parameterization.grid``); the
    line the console states, or None where it is not set. Raises ValueError naming the key where it cannot be
    applied (not a positive number; an input that is not the bin finder's square ``data.roi=auto:S``)."""
    from opnet.data.roi import auto_side, is_auto, parse_roi

    pixels: Any = cfg.get("part_pixels")
    if pixels is None:
        return None
    if isinstance(pixels, bool) or not isinstance(pixels, (int, float)) or not 8 <= float(pixels) <= 512:
        raise ValueError(f"part_pixels={pixels!r}: expected the pixels the part's diameter should span at the "
                         "network's input, a number from 8 to 512 (null: the input as configured)")
    roi = parse_roi((cfg.get("data") or {}).get("roi"))
    side = auto_side(roi) if is_auto(roi) else None
    if side is None:
        raise ValueError(f"part_pixels={pixels}: sizes the input of a square of known side, the bin finder's crop "
                         f"data.roi=auto:S (S metres); data.roi is {roi!r}: set data.roi=auto:S or part_pixels=null")
    in_size, grid = int(cfg.model.in_size), int(cfg.parameterization.grid)
    size = sized_input(float(pixels), side, diameter_m, in_size)
    new_grid = max(1, grid * size // in_size)
    with open_dict(cfg):
        cfg.data.input_size = size
        cfg.model.in_size = size
        cfg.parameterization.grid = new_grid
    return (f"input sized to the part: D {diameter_m * 1000:.0f} mm over the {side:g} m square spans "
            f"{diameter_m / side * size:.0f} of {size} pixels (part_pixels={pixels:g}), grid {new_grid}")


__all__ = ["MAX_SIZED_INPUT", "SIZE_STEP", "size_input_to_part", "sized_input"]
