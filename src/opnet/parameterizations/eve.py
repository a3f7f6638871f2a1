"""OP-Net EVE, extended volume elements (docs/method.md#the-six-parameterizations, paper "Extended Volume Elements").

As vanilla, plus the neighbouring cells (left/right, up/down and diagonal) whose shared border the
origin lies within ``border`` (0.2 cell units) of. Extensions never overwrite another object's
origin cell; among extensions the highest visibility wins. Several cells predict one object, so
the position is regressed relative to the image enlarged by the object diameter, and the decoded
hypotheses are clustered and averaged (docs/method.md#decoding).
"""

from __future__ import annotations

from typing import Any

import torch

from opnet.objects.model import ObjectModel
from opnet.parameterizations.assignment import ORIGIN_PRIORITY, Candidates, flat_cell
from opnet.parameterizations.base import GroundTruthBatch, Parameterization
from opnet.parameterizations.positions import MultiCellPosition, ObjectProjection


class EVEParameterization(MultiCellPosition, Parameterization):
    """Vanilla grid with feature vectors copied to neighbouring cells near a border.

    Args:
        obj: the object model.
        grid: S (16 in the paper).
        border: distance from a cell border, in cell units, under which the neighbour across that
            border gets the object too (0.2 in the paper).
        averaging: cluster and average the hypotheses (default on).
        position: "enlarged" (paper) or "cell_offset" (:class:`MultiCellPosition`).
        **kwargs: the common settings of :class:`Parameterization`.
    """

    def __init__(
        self,
        obj: ObjectModel,
        grid: int = 16,
        border: float = 0.2,
        averaging: bool = True,
        position: str = "enlarged",
        **kwargs: Any,
    ) -> None:
        self._set_position_mode(position)
        if not 0 <= border <= 0.5:
            raise ValueError(f"eve border must lie in [0, 0.5] (cell units), got {border}")
        super().__init__(obj, grid, averaging=averaging, **kwargs)
        self.border = float(border)

    def candidates(self, gt: GroundTruthBatch, proj: ObjectProjection) -> Candidates:
        cells = proj.cells(self.grid_size)
        steps = torch.tensor([-1, 0, 1], device=cells.row.device)
        # allowed moves per axis: (M, 3) for steps -1, 0, +1
        moves_y = torch.stack(
            (cells.y < self.border, torch.ones_like(cells.inside), cells.y > 1 - self.border), -1
        )
        moves_x = torch.stack(
            (cells.x < self.border, torch.ones_like(cells.inside), cells.x > 1 - self.border), -1
        )
        allowed = moves_y[:, :, None] & moves_x[:, None, :]  # (M, 3, 3): (dy, dx)
        row = cells.row[:, None, None] + steps[None, :, None]  # (M, 3, 1)
        col = cells.col[:, None, None] + steps[None, None, :]  # (M, 1, 3)
        on_grid = (
            (row >= 0) & (row < self.grid_size) & (col >= 0) & (col < self.grid_size)
        )  # (M, 3, 3)
        keep = allowed & on_grid & cells.inside[:, None, None]
        m, dy, dx = torch.nonzero(keep, as_tuple=True)
        is_origin = (dy == 1) & (dx == 1)
        priority = gt.visibility[m].double() + ORIGIN_PRIORITY * is_origin
        row, col = cells.row[m] + dy - 1, cells.col[m] + dx - 1
        cell = flat_cell(gt.batch_index[m], 0, row, col, self.slots, self.grid_size)
        position, ok = self._candidate_positions(proj, m, row, col)
        return Candidates(m, cell, priority, position).select(ok)
