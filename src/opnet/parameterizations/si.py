"""OP-Net SI, assignment by the resized segmentation image (docs/method.md#the-six-parameterizations, paper §SI).

The instance segmentation at network-input resolution is resized to 32 x 32 by nearest
neighbour (each cell takes the pixel nearest to its centre) and every cell showing instance k gets
k's feature vector. Dense assignment, so the pose terms of the loss are weighted linearly
(λ3 = v); the position is relative to the enlarged image and the hypotheses are averaged.
"""

from __future__ import annotations

from typing import Any

import torch

from opnet.objects.model import ObjectModel
from opnet.parameterizations.assignment import Candidates, flat_cell
from opnet.parameterizations.base import GroundTruthBatch, Parameterization
from opnet.parameterizations.positions import MultiCellPosition, ObjectProjection


def resize_nearest(segmentation: torch.Tensor, size: int) -> torch.Tensor:
    """(B, H, W) instance ids -> (B, size, size): the pixel nearest to each cell centre."""
    _, H, W = segmentation.shape
    grid = torch.arange(size, device=segmentation.device, dtype=torch.float64) + 0.5
    rows = torch.floor(grid * H / size).long().clamp(max=H - 1)
    cols = torch.floor(grid * W / size).long().clamp(max=W - 1)
    return segmentation[:, rows][:, :, cols]


class SIParameterization(MultiCellPosition, Parameterization):
    """Every cell of a fine grid showing an instance predicts that instance's pose.

    Args:
        obj: the object model.
        grid: S (32 in the paper).
        averaging: cluster and average the hypotheses (default on).
        position: "enlarged" (paper) or "cell_offset" (:class:`MultiCellPosition`).
        **kwargs: the common settings of :class:`Parameterization`.
    """

    pose_weighting = "linear"
    needs_segmentation = True

    def __init__(
        self, obj: ObjectModel, grid: int = 32, averaging: bool = True, position: str = "enlarged", **kwargs: Any
    ) -> None:
        self._set_position_mode(position)
        super().__init__(obj, grid, averaging=averaging, **kwargs)

    def candidates(self, gt: GroundTruthBatch, proj: ObjectProjection) -> Candidates:
        if gt.segmentation is None:
            raise ValueError(
                "si: GroundTruthBatch.segmentation is None; the SI parameterization needs "
                "instance masks"
            )
        ids = resize_nearest(gt.segmentation, self.grid_size)  # (B, S, S)
        b, row, col = torch.nonzero(ids > 0, as_tuple=True)
        gt_index, found = _instance_lookup(gt, b, ids[b, row, col])
        m, b, row, col = gt_index[found], b[found], row[found], col[found]
        cell = flat_cell(b, 0, row, col, self.slots, self.grid_size)
        position, ok = self._candidate_positions(proj, m, row, col)
        return Candidates(m, cell, gt.visibility[m].double(), position).select(ok)


def _instance_lookup(
    gt: GroundTruthBatch, batch: torch.Tensor, ids: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Ground-truth rows of (image, instance id) pairs (K,): (index (K,) long, found (K,) bool)."""
    if len(gt) == 0:
        return torch.zeros_like(ids), torch.zeros_like(ids, dtype=torch.bool)
    span = int(max(int(ids.max()) if len(ids) else 0, int(gt.instance_id.max()))) + 1
    gt_key, perm = torch.sort(gt.batch_index * span + gt.instance_id)
    key = batch * span + ids
    pos = torch.searchsorted(gt_key, key).clamp(max=len(gt_key) - 1)
    return perm[pos], gt_key[pos] == key
