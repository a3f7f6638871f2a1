"""The pose averaging of :class:`opnet.parameterizations.averaging.PoseAveraging` as torch operations
on the model's device, for every image of a batch at once (``inference.device_side``).

The same clusters and the same averages: candidate pairs are the hypotheses of one image whose
translations lie within eps (found through a grid of eps-sized cubes instead of the k-d tree), kept
when their symmetry-aware pose distance is within eps too; DBSCAN labels them exactly as scikit-learn
does (:func:`dbscan_graph`: core points, connected components by min-label propagation with
pointer jumping, border points to the lowest-numbered cluster next to them); each cluster is then
averaged as the numpy code does (members aligned to the best-scored one through the symmetry
group, score-weighted mean translation, chordal mean rotation projected onto SO(3) or the mean axis
of a revolution object, cluster score max / sum / mean). Clusters of all images are numbered
image by image, so one sort orders them as the numpy code orders each image's.
"""

from __future__ import annotations

import itertools
from typing import Any

import torch

from opnet.geometry.distance import PoseSpace
from opnet.geometry.rotations import project_to_so3, rotation_from_axis
from opnet.parameterizations.averaging import PoseAveraging


def smallest_connected(n: int, i: torch.Tensor, j: torch.Tensor) -> torch.Tensor:
    """:func:`opnet.parameterizations.averaging.smallest_connected` on tensors: (n,) long, the
    smallest node index of each node's component (edges ``i``, ``j`` listed both ways)."""
    label = torch.arange(n, device=i.device)
    while True:
        hooked = label.scatter_reduce(0, i, label[j], reduce="amin")
        hooked = hooked[hooked]
        if torch.equal(hooked, label):  # one device sync per round (a few rounds: log of the diameter)
            return label
        label = hooked


def dbscan_graph(n: int, i: torch.Tensor, j: torch.Tensor, min_samples: int = 1) -> torch.Tensor:
    """:func:`opnet.parameterizations.averaging.dbscan_graph` on tensors: (n,) long DBSCAN labels
    (-1 = noise), numbered by their smallest member, of an eps-neighbour graph (``i``, ``j``: both
    directions, no self pairs)."""
    if min_samples < 1:
        raise ValueError(f"min_samples must be >= 1, got {min_samples}")
    labels = torch.full((n,), -1, dtype=torch.long, device=i.device)
    core = torch.bincount(i, minlength=n) + 1 >= min_samples
    both = core[i] & core[j]
    component = smallest_connected(n, i[both], j[both])
    labels[core] = torch.unique(component[core], return_inverse=True)[1]
    to_core = ~core[i] & core[j]  # border point i next to core point j
    reach = torch.full((n,), n, dtype=torch.long, device=i.device)
    reach = reach.scatter_reduce(0, i[to_core], labels[j[to_core]], reduce="amin")
    return torch.where(reach < n, reach, labels)


def torch_space(space: Any) -> PoseSpace:
    """The pose space with its torch methods (a deployment's :class:`opnet.geometry.pose_numpy.PoseSpaceArrays`
    holds the same numbers without them)."""
    if isinstance(space, PoseSpace):
        return space
    return PoseSpace(space.Lambda, space.group, space.delta, space.revolution, space.lam)


#: the 9 rows of a cube's neighbourhood (itself included) as (dx, dy) steps; each row's three cubes
#: (dz = -1, 0, 1) are consecutive codes, so one range of the sorted codes
NEIGHBOUR_ROWS = tuple(itertools.product((-1, 0, 1), repeat=2))


def neighbour_pairs(averaging: PoseAveraging, image: torch.Tensor, R: torch.Tensor, t: torch.Tensor,
                    batch_size: int) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """The eps-neighbour pairs ``(i, j)`` (both directions) of hypotheses: same image, translations
    within eps and pose distance within eps (what the k-d tree and the pose distance give on the host).

    Candidates come from a grid of cubes a little larger than eps (two translations within eps lie
    in the same or neighbouring cubes): hypotheses sorted by (image, cube), each one's 27
    neighbouring cubes found by binary search (nine ranges), so the work grows with the pairs, not N².
    """
    empty = torch.zeros(0, dtype=torch.long, device=image.device)
    eps = averaging.eps * averaging.space.delta
    if len(image) < 2:
        return empty, empty
    cube = torch.floor(t / (eps * (1 + 1e-9))).long()
    # each axis's occupied cubes ranked: neighbours stay neighbours (gaps close, which only adds candidates),
    # and the codes stay small however far apart the translations are
    cube = torch.stack([torch.unique(c, return_inverse=True)[1] for c in cube.unbind(1)], 1) + 1  # >= 1
    sx, sy, sz = (cube.amax(0) + 2).tolist()  # one past the last neighbour: no code runs into the next row
    key = ((image * sx + cube[:, 0]) * sy + cube[:, 1]) * sz + cube[:, 2]
    sorted_key, order = torch.sort(key)
    rows = torch.tensor([(dx * sy + dy) * sz for dx, dy in NEIGHBOUR_ROWS], device=key.device)
    wanted = (key[:, None] + rows).reshape(-1)  # (N * 9,) the middle cube of each row
    lo = torch.searchsorted(sorted_key, wanted - 1)
    length = torch.searchsorted(sorted_key, wanted + 1, right=True) - lo
    total = int(length.sum())
    point = torch.arange(len(key), device=key.device).repeat_interleave(len(rows)).repeat_interleave(length, output_size=total)
    first = (torch.cumsum(length, 0) - length).repeat_interleave(length, output_size=total)
    other = order[lo.repeat_interleave(length, output_size=total) + torch.arange(total, device=key.device) - first]
    a, c = point[point < other], other[point < other]  # each pair once
    near = (t[a] - t[c]).norm(dim=-1) <= eps
    a, c = a[near], c[near]
    keep = torch_space(averaging.space).distance(R[a], t[a], R[c], t[c]) <= eps
    a, c = a[keep], c[keep]
    return torch.cat((a, c)), torch.cat((c, a))


def segment_sum(x: torch.Tensor, segment: torch.Tensor, count: int) -> torch.Tensor:
    """Sums of the rows of ``x`` (N, ...) by ``segment`` (N,) long in ``[0, count)``."""
    return torch.zeros((count,) + x.shape[1:], dtype=x.dtype, device=x.device).index_add_(0, segment, x)


def average_batch(
    averaging: PoseAveraging,
    image: torch.Tensor,
    R: torch.Tensor,
    t: torch.Tensor,
    score: torch.Tensor,
    visibility: torch.Tensor,
    batch_size: int,
) -> tuple[torch.Tensor, ...]:
    """The averaged hypotheses of every image of a batch, on the hypotheses' device.

    Args:
        averaging: the settings (eps, min_samples, cluster_score, keep_noise, the pose space).
        image: (N,) long, the image of each hypothesis, sorted (as ``nonzero`` gives them).
        R (N, 3, 3), t (N, 3), score (N,), visibility (N,): the decoded hypotheses, float64.
        batch_size: B (images may hold no hypothesis).
    Returns:
        ``(image, R, t, score, visibility)`` of the C output hypotheses, image by image in the numpy
        code's order. An image holding at most one hypothesis keeps it as it is (the numpy code
        forms no cluster there: a lone hypothesis is never noise).
    """
    n = len(image)
    alone = torch.bincount(image, minlength=batch_size) <= 1
    i, j = neighbour_pairs(averaging, image, R, t, batch_size)
    labels = dbscan_graph(n, i, j, averaging.min_samples)
    index = torch.arange(n, device=image.device)
    single = (labels < 0) & (averaging.keep_noise | alone[image])  # noise kept, or an image left as it is
    key = torch.where(labels >= 0, labels, n + index) + image * (2 * n)  # image, its clusters, then noise
    keep = (labels >= 0) | single
    member = index[keep]
    by_score = torch.sort(-score[member], stable=True).indices  # best score first ...
    by_key = torch.sort(key[member][by_score], stable=True).indices  # ... within each cluster
    order, sorted_key = member[by_score[by_key]], key[member][by_score[by_key]]
    first = torch.ones(len(order), dtype=torch.bool, device=image.device)
    first[1:] = sorted_key[1:] != sorted_key[:-1]
    cluster = torch.cumsum(first, 0) - 1  # (M,) cluster of each member, in output order
    clusters = int(cluster[-1]) + 1 if len(order) else 0
    sizes = torch.bincount(cluster, minlength=clusters)
    best = order[first]  # (C,) best member of each cluster
    w = score[order].clamp_min(1e-12)
    w_sum = segment_sum(w, cluster, clusters)
    several = (sizes > 1)[:, None]
    t_mean = torch.where(several, segment_sum(w[:, None] * t[order], cluster, clusters) / w_sum[:, None], t[best])
    vis = torch.where(several[:, 0], segment_sum(w * visibility[order], cluster, clusters) / w_sum, visibility[best])
    R_mean = R[best]  # singletons keep their rotation
    if bool(several.any()):
        grouped = several[cluster, 0]  # members of clusters of several
        new_index = torch.cumsum(several[:, 0], 0) - 1  # their cluster among the clusters of several
        part, w_part = new_index[cluster[grouped]], w[grouped]
        space = torch_space(averaging.space)
        aligned = space.closest_equivalent(R[best][cluster[grouped]], R[order[grouped]])
        count = int(several.sum())
        if space.revolution:
            axes = segment_sum(w_part[:, None] * aligned[:, :, 2], part, count)
            mean = rotation_from_axis(axes / axes.norm(dim=-1, keepdim=True).clamp_min(1e-12))
        else:
            mean = project_to_so3(segment_sum(w_part[:, None, None] * aligned, part, count))
        R_mean = R_mean.index_put((several[:, 0].nonzero()[:, 0],), mean)
    if averaging.cluster_score == "max":
        cluster_score = score[best]
    else:
        cluster_score = segment_sum(score[order], cluster, clusters)
        if averaging.cluster_score == "mean":
            cluster_score = cluster_score / sizes
    return image[best], R_mean, t_mean, cluster_score, vis
