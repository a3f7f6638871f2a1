"""OP-Net Z, discretization in depth (docs/method.md#the-six-parameterizations, paper "Discretization in z-Direction").

A 16 x 16 grid of the image times ``S_z`` = 16 depth slabs between the clip planes: an object goes
to the voxel (cell, slab) of its origin, the highest visibility winning per voxel. x, y are the
sub-cell offsets and z the origin depth relative to its slab. Output ``S x S x 8 S_z``
(slot = slab).
"""

from __future__ import annotations

from typing import Any

import torch

from opnet.objects.model import ObjectModel
from opnet.parameterizations.assignment import Candidates, flat_cell
from opnet.parameterizations.base import GroundTruthBatch, Parameterization
from opnet.parameterizations.positions import (
    CameraBatch,
    CellIndex,
    DecodedPosition,
    ObjectProjection,
    cell_pixel,
)


class ZParameterization(Parameterization):
    """Vanilla grid with one slot per depth slab.

    Args:
        obj: the object model.
        grid: S (16 in the paper).
        depth_slabs: S_z, slabs of equal thickness between the clip planes (16 in the paper).
        **kwargs: the common settings of :class:`Parameterization`.
    """

    def __init__(
        self, obj: ObjectModel, grid: int = 16, depth_slabs: int = 16, **kwargs: Any
    ) -> None:
        super().__init__(obj, grid, slots=depth_slabs, **kwargs)

    def candidates(self, gt: GroundTruthBatch, proj: ObjectProjection) -> Candidates:
        cells = proj.cells(self.grid_size)
        idx = torch.nonzero(cells.inside & proj.in_range)[:, 0]
        z_slabs = proj.z_norm[idx] * self.slots
        slab = (
            torch.floor(z_slabs).long().clamp(max=self.slots - 1)
        )  # the far clip plane belongs to the last slab
        cell = flat_cell(
            gt.batch_index[idx], slab, cells.row[idx], cells.col[idx], self.slots, self.grid_size
        )
        position = torch.stack((cells.x[idx], cells.y[idx], z_slabs - slab), -1)  # (K, 3)
        return Candidates(idx, cell, gt.visibility[idx].double(), position)

    def decode_position(
        self, position: torch.Tensor, cells: CellIndex, cams: CameraBatch
    ) -> DecodedPosition:
        slot, row, col = cells
        u, v = cell_pixel(row, col, position[:, 0], position[:, 1], cams, self.grid_size)
        return u, v, (slot + position[:, 2]) / self.slots
