"""Decoding and pose averaging with shapes fixed by the network's grid, for a CUDA graph.

:meth:`opnet.parameterizations.base.Parameterization.decode` keeps the cells above the threshold
(``nonzero``) and clusters them through a grid of cubes (:mod:`opnet.parameterizations.averaging_torch`):
shapes that depend on the data, so every call launches its kernels one by one and waits for the
device several times. Here every cell of the grid is decoded and averaged, the cells below the
threshold masked out, so no shape depends on the data and no value is read back until the end:
the whole computation can be captured once and replayed as one CUDA graph with the network
(:class:`opnet.inference.GraphedPipeline`).

The same hypotheses as the host's decoding and averaging (to float rounding; tests):

- neighbours: two hypotheses of one image whose translations and symmetry-aware pose distance are
  both within eps (the distance measured from the lower-numbered one, as the host's pairs are);
- DBSCAN as scikit-learn labels it: core points (at least ``min_samples`` neighbours, itself
  counted), clusters = connected components of the core points, found by :data:`ROUNDS` rounds of
  label propagation with hooking and pointer jumping (:func:`component_roots`; an image whose labels
  have not settled by then, which takes a chain of hundreds of hypotheses, is decoded by the
  parameterization itself),
  each cluster named by its smallest member, which orders clusters as the host numbers them; a
  border point joins the lowest-numbered cluster next to it; an image with at most one hypothesis
  keeps it as it is;
- per cluster: the best-scored member (lowest index among equal scores), the score-weighted mean
  translation and visibility, the weighted sum of the members aligned to the best one through the
  symmetry group, and the cluster score (max, sum or mean).

The last step, the projection of each weighted sum of rotations onto SO(3) (or its mean axis for a
revolution object), runs on the host in :meth:`DenseDecoding.hypotheses` with the host averaging's
own numpy functions, after the graph's one transfer (a batched SVD on the device is not capturable).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from opnet.geometry.pose_numpy import axis_rotation, project_to_so3
from opnet.metrics.records import HypothesisSet
from opnet.parameterizations.averaging_torch import torch_space
from opnet.parameterizations.positions import CameraBatch

#: columns of the transferred table, per cell of each image (float64)
COLUMNS = {
    "kept": 1,  # 1: this row is an output hypothesis (a cluster named by this cell, or a kept single)
    "R": 9,  # the best member's rotation (singles and clusters of one keep it)
    "t": 3,  # the weighted mean translation
    "score": 1,  # the cluster score
    "visibility": 1,  # the weighted mean visibility
    "size": 1,  # members (1 for a single)
    "rotation_sum": 9,  # the weighted sum of the aligned members' rotations
    "order": 1,  # the row's place in the image's output (cluster rows by name, then kept noise)
    "present": 1,  # 1: this cell's hypothesis is above the threshold
}
WIDTH = sum(COLUMNS.values())
#: rounds of label propagation with hooking and pointer jumping on the core graph (each about
#: halves what is left to merge): a path of 256 hypotheses numbered at random settles within 6; a
#: cluster of nearby hypotheses, where most members neighbour each other, within 2 or 3
ROUNDS = 6
_OFFSET = dict(zip(COLUMNS, np.cumsum([0, *COLUMNS.values()])[:-1].tolist(), strict=True))


def component_roots(linked: torch.Tensor, core: torch.Tensor, rounds: int = ROUNDS) -> tuple[torch.Tensor, torch.Tensor]:
    """The smallest member of each node's connected component, with fixed shapes.

    Args:
        linked: (B, N, N) bool symmetric adjacency (no node outside ``core`` linked).
        core: (B, N) bool, the nodes that count.
        rounds: rounds of propagation: each node takes the smallest label among itself and its
            neighbours and hands it to the node its label names, then labels jump twice to their
            labels' labels.
    Returns:
        ``(roots, settled)``: (B, N) long, the component's smallest node index (N for a node not in
        ``core``), and (B,) bool, whether the labels settled (no neighbour holds a smaller label:
        then each component holds its smallest member, exactly).
    """
    B, N = core.shape
    idx = torch.arange(N, device=core.device)
    root = torch.cat((torch.where(core, idx, N), torch.full((B, 1), N, device=core.device)), 1)  # N: nowhere
    for _ in range(rounds):
        label = root[:, :N]
        smallest = torch.minimum(label, torch.where(linked, label[:, None, :], N).amin(-1))
        root = root.scatter_reduce(1, label, smallest, "amin")  # each label's node hooks to the smallest seen
        root = torch.minimum(root, torch.cat((smallest, root[:, N:]), 1))
        for _ in range(2):  # pointer jumping
            root = torch.gather(root, 1, root)
    root = root[:, :N]
    settled = (torch.where(linked, root[:, None, :], N).amin(-1) >= root).all(-1)
    return root, settled


class DenseDecoding:
    """Decoding (and averaging) of a batch of ``batch`` outputs of one network-input camera with
    shapes fixed by the grid: :meth:`__call__` on the device (capturable), :meth:`hypotheses` on
    the host.

    Args:
        param: the parameterization (its decoding settings as they are now).
        camera: the network-input camera.
        batch: images per call.
        device: the output's device.
    """

    def __init__(self, param: Any, camera: Any, batch: int, device: torch.device | str) -> None:
        self.param = param
        self.camera = camera
        self.batch = batch
        self.device = torch.device(device)
        L, S = param.slots, param.grid_size
        self.cells = L * S * S
        n = batch * self.cells
        flat = torch.arange(n, device=self.device)
        self.image = flat // self.cells
        within = flat % self.cells
        self.slot, self.row, self.col = within // (S * S), (within // S) % S, within % S
        self.cams = CameraBatch.of([camera] * batch, batch, self.device).take(self.image)
        self.index = torch.arange(self.cells, device=self.device)
        averaging = param.averaging
        self.averaging = averaging
        if averaging is not None:
            space = torch_space(averaging.space)
            self.space = space
            self.eps = float(averaging.eps * space.delta)
            self.rounds = ROUNDS  # of component_roots (``settled`` says whether they sufficed)

    # ---- on the device ------------------------------------------------------------------------
    def __call__(self, output: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, out_channels, S, S) network output -> ((B, cells, :data:`WIDTH`) float64 table,
        (B,) bool settled: the clustering of each image converged within :data:`ROUNDS`).

        No shape depends on the data and nothing is read back: capturable in a CUDA graph.
        """
        param = self.param
        B, N = self.batch, self.cells
        grid5 = param.split_slots(output.detach())
        present = param.cells_to_decode(grid5).reshape(B, N)
        feat = grid5.permute(0, 1, 3, 4, 2).reshape(B * N, -1).to(torch.float64)
        t, R = param.decode_poses(feat, (self.slot, self.row, self.col), self.cams)
        score, v_hat = param.hypothesis_scores(feat)
        R, t, score, v_hat = R.reshape(B, N, 3, 3), t.reshape(B, N, 3), score.reshape(B, N), v_hat.reshape(B, N)
        if self.averaging is None:
            ones = present.to(torch.float64)
            order = self.index.to(torch.float64).expand(B, N)
            rotation_sum = torch.zeros_like(R)
            table = self._table(present, R, t, score, v_hat, ones, rotation_sum, order, present)
            return table, torch.ones(B, dtype=torch.bool, device=table.device)
        return self._averaged(present, R, t, score, v_hat)

    def _averaged(self, present: torch.Tensor, R: torch.Tensor, t: torch.Tensor, score: torch.Tensor,
                  visibility: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
        avg, space, N = self.averaging, self.space, self.cells
        idx = self.index
        # ---- neighbours: translations and pose distance within eps, measured from the lower index
        near = torch.cdist(t, t, compute_mode="donot_use_mm_for_euclid_dist") <= self.eps
        reps = space.representatives(R, t)  # (B, N, K, D)
        B, _, K, D = reps.shape
        pose = torch.cdist(reps[:, :, 0], reps.reshape(B, N * K, D), compute_mode="donot_use_mm_for_euclid_dist")
        pose = pose.reshape(B, N, N, K).amin(-1) <= self.eps  # [b, i, j]: from i's first to j's all
        upper = idx[:, None] < idx[None, :]
        pair = near & pose & upper & present[:, :, None] & present[:, None, :]
        adjacent = pair | pair.transpose(1, 2)
        # ---- DBSCAN
        count = present.sum(-1, keepdim=True)  # hypotheses per image
        alone = count <= 1
        core = present & (adjacent.sum(-1) + 1 >= avg.min_samples)
        linked = adjacent & core[:, :, None] & core[:, None, :]
        root, settled = component_roots(linked, core, self.rounds)
        border = torch.where(adjacent & core[:, None, :], root[:, None, :], N).amin(-1)
        name = torch.where(core, root, torch.where(present, border, N))  # N: noise or no hypothesis
        single = present & (name == N) & (avg.keep_noise | alone)  # kept as its own hypothesis
        name = torch.where(single, N + idx, name)
        name = torch.where(present & alone, idx, name)  # an image with one hypothesis keeps it as it is
        # ---- per cluster k (named by its smallest member): members, best member, weighted means
        member = (name[:, None, :] == idx[:, None]) & present[:, None, :]  # (B, k, i)
        size = member.sum(-1)
        named = size > 0
        best_score = torch.where(member, score[:, None, :], -torch.inf).amax(-1, keepdim=True)
        best = torch.where(member & (score[:, None, :] == best_score), idx, N).amin(-1).clamp_max(N - 1)
        w = score.clamp_min(1e-12)
        weights = member.to(torch.float64) * w[:, None, :]  # (B, k, i)
        w_sum = weights.sum(-1).clamp_min(1e-300)
        t_mean = (weights @ t) / w_sum[..., None]
        vis = (weights @ visibility[..., None])[..., 0] / w_sum
        R_best = torch.gather(R, 1, best[..., None, None].expand(-1, -1, 3, 3))
        # each member aligned to its cluster's best rotation through the symmetry group
        reference = torch.gather(R_best, 1, name.clamp_max(N - 1)[..., None, None].expand(-1, -1, 3, 3))
        aligned = space.closest_equivalent(reference, R)
        rotation_sum = (weights @ aligned.reshape(B, N, 9)).reshape(B, N, 3, 3)
        if avg.cluster_score == "max":
            cluster_score = torch.gather(score, 1, best)
        else:
            cluster_score = (member.to(torch.float64) * score[:, None, :]).sum(-1)
            if avg.cluster_score == "mean":
                cluster_score = cluster_score / size.clamp_min(1)
        # kept singles are their own rows, after the clusters (index order), as the host orders noise
        kept_single = single & ~(present & alone)
        order = torch.where(kept_single, N + idx, idx).to(torch.float64)
        kept = named | kept_single
        t_out = torch.where(kept_single[..., None], t, t_mean)
        R_out = torch.where(kept_single[..., None, None], R, R_best)
        score_out = torch.where(kept_single, score, cluster_score)
        vis_out = torch.where(kept_single, visibility, vis)
        size_out = torch.where(kept_single, 1, size).to(torch.float64)
        rotation_sum = torch.where(kept_single[..., None, None], R, rotation_sum)
        table = self._table(kept, R_out, t_out, score_out, vis_out, size_out, rotation_sum, order, present)
        return table, settled

    def _table(self, kept: torch.Tensor, R: torch.Tensor, t: torch.Tensor, score: torch.Tensor,
               visibility: torch.Tensor, size: torch.Tensor, rotation_sum: torch.Tensor,
               order: torch.Tensor, present: torch.Tensor) -> torch.Tensor:  # fmt: skip
        B, N = self.batch, self.cells
        parts = (kept.to(torch.float64)[..., None], R.reshape(B, N, 9), t, score[..., None], visibility[..., None],
                 size.to(torch.float64)[..., None], rotation_sum.reshape(B, N, 9), order[..., None],
                 present.to(torch.float64)[..., None])  # fmt: skip
        return torch.cat(parts, -1)

    # ---- on the host --------------------------------------------------------------------------
    def decode(self, output: torch.Tensor) -> list[HypothesisSet]:
        """:meth:`__call__` and :meth:`hypotheses` in one: B hypothesis sets of a network output."""
        table, settled = self(output)
        return self.hypotheses(table.cpu().numpy(), settled.cpu().numpy(), output)

    def hypotheses(self, table: np.ndarray, settled: np.ndarray, output: torch.Tensor) -> list[HypothesisSet]:
        """The (B, cells, WIDTH) table and (B,) settled flags of :meth:`__call__`, on the host -> B
        hypothesis sets, as :meth:`~opnet.parameterizations.base.Parameterization.decode` returns
        them; an image whose clustering did not settle (a chain of more than about 2^ROUNDS
        hypotheses) is decoded from its ``output`` by the parameterization itself."""
        out = []
        for b, rows in enumerate(table):
            if not settled[b]:
                out.append(self.param.decode(output[b : b + 1], [self.camera])[0])
                continue
            found = int((rows[:, _OFFSET["present"]] > 0.5).sum())
            rows = rows[rows[:, 0] > 0.5]
            if self.averaging is not None and found > 1 and not len(rows):
                out.append(HypothesisSet.empty())  # every hypothesis noise, as the host's averaging returns it
                continue
            rows = rows[np.argsort(rows[:, _OFFSET["order"]], kind="stable")]
            R = rows[:, _OFFSET["R"] : _OFFSET["R"] + 9].reshape(-1, 3, 3).copy()
            several = rows[:, _OFFSET["size"]] > 1.5
            if several.any():
                sums = rows[several, _OFFSET["rotation_sum"] : _OFFSET["rotation_sum"] + 9].reshape(-1, 3, 3)
                if self.space.revolution:
                    axes = sums[:, :, 2]
                    R[several] = axis_rotation(axes / np.linalg.norm(axes, axis=-1, keepdims=True).clip(1e-12))
                else:
                    R[several] = project_to_so3(sums)
            t = rows[:, _OFFSET["t"] : _OFFSET["t"] + 3].copy()
            out.append(HypothesisSet(R, t, rows[:, _OFFSET["score"]].copy(), rows[:, _OFFSET["visibility"]].copy()))
        return out
