"""Vectorized target assignment: candidate (object, cell) pairs and priority resolution.

Every parameterization lists *candidates*, flat with one entry per (ground-truth instance, output
cell) pair it would like to fill, each with a priority. One stable sort by priority and one stable
sort by cell resolve all conflicts at once (no Python loop over objects or cells): per cell the
candidate of highest priority wins, ties going to the earlier candidate.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

# added to the visibility of an object's own origin cell so that it outranks every other kind of
# candidate (EVE extensions, AP additional points): visibilities lie in [0, 1]
ORIGIN_PRIORITY = 2.0


@dataclass(frozen=True)
class Candidates:
    """Flat (instance, cell) assignment candidates of a batch.

    Attributes:
        index: (K,) long, the ground-truth instance (row of the GroundTruthBatch).
        cell: (K,) long, flat index into the (B, slots, S, S) output grid.
        priority: (K,) float64; per cell the highest wins.
        position: (K, 3) float64, the x, y, z channels the instance gets in that cell.
    """

    index: torch.Tensor
    cell: torch.Tensor
    priority: torch.Tensor
    position: torch.Tensor

    def select(self, keep: torch.Tensor) -> Candidates:
        """The candidates where ``keep`` (K,) bool or a (K',) long index selects."""
        return Candidates(
            self.index[keep], self.cell[keep], self.priority[keep], self.position[keep]
        )


def sort_by_cell(cell: torch.Tensor, priority: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Order candidates by cell, and within a cell by decreasing priority (stable).

    Args:
        cell: (K,) long. priority: (K,) float.
    Returns:
        order (K,) long permutation, first (K,) bool marking the first (winning) entry of each cell
        in that order.
    """
    order = torch.argsort(priority, descending=True, stable=True)
    order = order[torch.argsort(cell[order], stable=True)]
    sorted_cells = cell[order]
    first = torch.ones_like(sorted_cells, dtype=torch.bool)
    first[1:] = sorted_cells[1:] != sorted_cells[:-1]
    return order, first


def resolve(candidates: Candidates) -> Candidates:
    """Keep, per cell, the candidate of highest priority (ties: the earlier one)."""
    order, first = sort_by_cell(candidates.cell, candidates.priority)
    return candidates.select(order[first])


def rank_within_cells(
    cell: torch.Tensor, priority: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Rank candidates inside their cell by decreasing priority.

    Returns:
        order (K,) long permutation (by cell, then priority), rank (K,) long of each entry of that
        order: 0 for the highest priority of its cell, 1 for the next, ...
    """
    order, first = sort_by_cell(cell, priority)
    position = torch.arange(len(order), device=cell.device)
    group_start = torch.cummax(
        torch.where(first, position, torch.zeros_like(position)), dim=0
    ).values
    return order, position - group_start


def flat_cell(
    batch: torch.Tensor,
    slot: torch.Tensor | int,
    row: torch.Tensor,
    col: torch.Tensor,
    slots: int,
    grid: int,
) -> torch.Tensor:
    """Flat index into a (B, slots, S, S) grid of (batch, slot, row, col), each (K,) long."""
    return ((batch * slots + slot) * grid + row) * grid + col
