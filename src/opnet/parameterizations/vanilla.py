"""Vanilla OP-Net: one 16 x 16 grid, an object in the cell of its projected origin
(docs/method.md#the-six-parameterizations).

If several origins fall into one cell, the object with the highest visibility wins. Position is
cell-relative: the sub-cell offsets of the projected origin and its depth normalized between the
clip planes. Objects whose origin projects outside the image or outside the clip range are not
representable.
"""

from __future__ import annotations

from typing import Any

import torch

from opnet.objects.model import ObjectModel
from opnet.parameterizations.assignment import Candidates, flat_cell
from opnet.parameterizations.base import GroundTruthBatch, Parameterization
from opnet.parameterizations.positions import CellRelativePosition, ObjectProjection


class VanillaParameterization(CellRelativePosition, Parameterization):
    """OP-Net's original output: ``[p, v, x, y, z, φ1, φ2, (φ3)]`` per cell of an S x S grid.

    Args:
        obj: the object model.
        grid: S (16 in the paper).
        **kwargs: the common settings of :class:`Parameterization` (euler, threshold, score, ...).
    """

    def __init__(self, obj: ObjectModel, grid: int = 16, **kwargs: Any) -> None:
        super().__init__(obj, grid, **kwargs)

    def candidates(self, gt: GroundTruthBatch, proj: ObjectProjection) -> Candidates:
        cells = proj.cells(self.grid_size)
        idx = torch.nonzero(cells.inside & proj.in_range)[:, 0]
        cell = flat_cell(
            gt.batch_index[idx], 0, cells.row[idx], cells.col[idx], self.slots, self.grid_size
        )
        position = torch.stack((cells.x, cells.y, proj.z_norm), -1)[idx]  # (K, 3)
        return Candidates(idx, cell, gt.visibility[idx].double(), position)
