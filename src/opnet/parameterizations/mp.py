"""OP-Net MP, multiple poses per cell (docs/method.md#the-six-parameterizations, paper "Multiple Poses").

An 8 x 8 grid with P = 3 pose slots per cell: the objects whose origins fall into a cell are ranked
by visibility into slots 1..P (further ones are dropped). The presence of slot l+1 means "there is
a further object", so it is only decoded where slot l is present too. Position is cell-relative.
"""

from __future__ import annotations

from typing import Any

import torch

from opnet.objects.model import ObjectModel
from opnet.parameterizations.assignment import Candidates, flat_cell, rank_within_cells
from opnet.parameterizations.base import GroundTruthBatch, Parameterization
from opnet.parameterizations.positions import CellRelativePosition, ObjectProjection


class MPParameterization(CellRelativePosition, Parameterization):
    """Coarse grid with up to ``slots`` objects per cell, ranked by visibility: slot l + 1 counts only where
    slots 1..l are present (:attr:`slot_conditional`).

    Args:
        obj: the object model.
        grid: S (8 in the paper).
        slots: P, poses per cell (3 in the paper).
        conditional_presence_loss: weight the presence term of slot l+1 by the ground-truth
            presence of slot l, so that the network is not asked about slots it will never be
            read at (decision; the paper's formula sums every slot, the default).
        **kwargs: the common settings of :class:`Parameterization`.
    """

    slot_conditional = True

    def __init__(
        self,
        obj: ObjectModel,
        grid: int = 8,
        slots: int = 3,
        conditional_presence_loss: bool = False,
        **kwargs: Any,
    ) -> None:
        super().__init__(obj, grid, slots=slots, **kwargs)
        self.conditional_presence_loss = bool(conditional_presence_loss)

    def candidates(self, gt: GroundTruthBatch, proj: ObjectProjection) -> Candidates:
        cells = proj.cells(self.grid_size)
        idx = torch.nonzero(cells.inside & proj.in_range)[:, 0]
        base_cell = flat_cell(
            gt.batch_index[idx], 0, cells.row[idx], cells.col[idx], 1, self.grid_size
        )
        order, rank = rank_within_cells(base_cell, gt.visibility[idx].double())
        keep = rank < self.slots
        idx, rank = idx[order[keep]], rank[keep]
        cell = flat_cell(
            gt.batch_index[idx], rank, cells.row[idx], cells.col[idx], self.slots, self.grid_size
        )
        position = torch.stack((cells.x, cells.y, proj.z_norm), -1)[idx]  # (K, 3)
        return Candidates(idx, cell, gt.visibility[idx].double(), position)

    def presence_weight(self, target: torch.Tensor) -> torch.Tensor:
        """(B, P, S, S): ones, or (conditional_presence_loss) the GT presence of the slot before."""
        presence = self.split_slots(target)[:, :, self.layout.presence]
        weight = torch.ones_like(presence)
        if self.conditional_presence_loss:
            weight[:, 1:] = presence[:, :-1]
        return weight
