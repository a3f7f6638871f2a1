"""DBSCAN in pose space (checked against scikit-learn) and cluster averaging."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.cluster import DBSCAN

from opnet.geometry import axis_angle_rotation, quaternion_to_matrix
from opnet.metrics.records import HypothesisSet
from opnet.objects import builtin_object
from opnet.parameterizations.averaging import PoseAveraging, dbscan_labels, smallest_connected

ZBRACKET = builtin_object("zbracket")
PIN = builtin_object("pin")


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    n=st.integers(0, 60),
    min_samples=st.sampled_from([1, 2, 3, 5]),
    eps=st.floats(0.05, 0.6),
)
def test_dbscan_matches_sklearn_exactly(seed, n, min_samples, eps):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(0, 3, (4, 2))
    points = centres[rng.integers(0, 4, n)] + rng.normal(0, 0.25, (n, 2))
    distance = np.linalg.norm(points[:, None] - points[None], axis=-1)
    ours = dbscan_labels(distance, eps, min_samples)
    if n == 0:
        assert ours.shape == (0,)
        return
    ref = DBSCAN(eps=eps, min_samples=min_samples, metric="precomputed").fit(distance).labels_
    np.testing.assert_array_equal(ours, ref)


def poses_around(
    R0: torch.Tensor,
    t0: torch.Tensor,
    n: int,
    rot_sigma: float,
    t_sigma: float,
    gen: torch.Generator,
):
    axis = torch.randn(n, 3, generator=gen, dtype=torch.float64)
    angle = rot_sigma * torch.randn(n, 1, generator=gen, dtype=torch.float64)
    rotvec = axis / axis.norm(dim=-1, keepdim=True) * angle
    R = torch.linalg.matrix_exp(
        torch.cross(
            rotvec[:, :, None].expand(n, 3, 3),
            torch.eye(3, dtype=torch.float64).expand(n, 3, 3),
            dim=1,
        )
    )
    return R0 @ R, t0 + t_sigma * torch.randn(n, 3, generator=gen, dtype=torch.float64)


def test_cluster_of_symmetric_equivalents_averages_to_the_true_pose():
    gen = torch.Generator().manual_seed(0)
    R0 = quaternion_to_matrix(torch.tensor([0.3, 0.1, -0.7, 0.4], dtype=torch.float64))
    t0 = torch.tensor([0.05, -0.02, 1.0], dtype=torch.float64)
    R, t = poses_around(R0, t0, 12, 0.02, 0.001, gen)
    half_turn = axis_angle_rotation("Z", torch.tensor(math.pi, dtype=torch.float64))
    R[::2] = R[::2] @ half_turn  # every other member is written as its symmetric equivalent
    R_far, t_far = poses_around(
        R0, t0 + torch.tensor([0.1, 0.0, 0.0], dtype=torch.float64), 3, 0.02, 0.001, gen
    )
    score = torch.rand(15, generator=gen, dtype=torch.float64) * 0.5 + 0.4
    hyps = HypothesisSet(
        torch.cat((R, R_far)).numpy(),
        torch.cat((t, t_far)).numpy(),
        score.numpy(),
        np.full(15, 0.5),
    )
    averaging = PoseAveraging(ZBRACKET.pose_space)
    labels = averaging.cluster(hyps)
    assert labels.tolist() == [0] * 12 + [1] * 3
    out = averaging(hyps)
    assert len(out) == 2
    space = ZBRACKET.pose_space
    err = space.distance(
        torch.from_numpy(out.R[:1]), torch.from_numpy(out.t[:1]), R0[None], t0[None]
    ).item()
    member_err = space.distance(R, t, R0.expand(12, 3, 3), t0.expand(12, 3)).mean().item()
    assert err < 0.5 * member_err
    assert out.score.tolist() == pytest.approx([score[:12].max().item(), score[12:].max().item()])
    np.testing.assert_allclose(out.visibility, 0.5)
    np.testing.assert_allclose(np.linalg.det(out.R), 1.0)
    w = score[:12] / score[:12].sum()
    np.testing.assert_allclose(out.t[0], (w[:, None] * t).sum(0).numpy(), atol=1e-12)


def test_revolution_objects_average_the_axis_through_the_flip():
    R0 = quaternion_to_matrix(torch.tensor([0.8, 0.2, -0.3, 0.1], dtype=torch.float64))
    t0 = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    gen = torch.Generator().manual_seed(1)
    R, t = poses_around(R0, t0, 8, 0.01, 0.0005, gen)
    flip = torch.diag(torch.tensor([1.0, -1.0, -1.0], dtype=torch.float64))
    R[1::2] = R[1::2] @ flip @ axis_angle_rotation("Z", torch.tensor(1.0, dtype=torch.float64))
    out = PoseAveraging(PIN.pose_space)(HypothesisSet(R.numpy(), t.numpy(), np.ones(8)))
    assert len(out) == 1
    axis = out.R[0, :, 2]
    assert abs(abs(axis @ R0[:, 2].numpy()) - 1) < 1e-3


@pytest.mark.parametrize("mode, expected", [("max", 0.9), ("sum", 1.5), ("mean", 0.5)])
def test_cluster_score_options(mode, expected):
    R = np.tile(np.eye(3), (3, 1, 1))
    t = np.array([[0, 0, 1.0], [0.0001, 0, 1.0], [0, 0.0001, 1.0]])
    out = PoseAveraging(ZBRACKET.pose_space, cluster_score=mode)(
        HypothesisSet(R, t, np.array([0.9, 0.3, 0.3]))
    )
    assert out.score.tolist() == pytest.approx([expected])


def test_noise_points_are_dropped_or_kept():
    R = np.tile(np.eye(3), (4, 1, 1))
    t = np.array([[0, 0, 1.0], [0.0001, 0, 1.0], [0, 0.0001, 1.0], [0.3, 0, 1.0]])
    hyps = HypothesisSet(R, t, np.ones(4))
    assert len(PoseAveraging(ZBRACKET.pose_space, min_samples=2)(hyps)) == 1
    assert len(PoseAveraging(ZBRACKET.pose_space, min_samples=2, keep_noise=True)(hyps)) == 2
    assert len(PoseAveraging(ZBRACKET.pose_space)(hyps)) == 2


def test_eps_is_a_fraction_of_delta():
    delta = ZBRACKET.delta
    R = np.tile(np.eye(3), (2, 1, 1))
    t = np.array([[0, 0, 1.0], [0.45 * delta, 0, 1.0]])
    hyps = HypothesisSet(R, t, np.ones(2))
    assert len(PoseAveraging(ZBRACKET.pose_space, eps=0.5)(hyps)) == 1
    assert len(PoseAveraging(ZBRACKET.pose_space, eps=0.4)(hyps)) == 2
    with pytest.raises(ValueError, match="averaging_score"):
        PoseAveraging(ZBRACKET.pose_space, cluster_score="median")


@pytest.mark.parametrize("name", ["zbracket", "pin"])
def test_kd_tree_neighbours_give_the_dense_matrix_clustering(name):
    obj = builtin_object(name)
    space = obj.pose_space
    gen = torch.Generator().manual_seed(5)
    centres_R = quaternion_to_matrix(torch.randn(6, 4, generator=gen, dtype=torch.float64))
    centres_t = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64) + 0.01 * torch.randn(
        6, 3, generator=gen, dtype=torch.float64
    )
    parts = [poses_around(centres_R[k], centres_t[k], 15, 0.05, 0.003, gen) for k in range(6)]
    R, t = torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts])
    hyps = HypothesisSet(R.numpy(), t.numpy(), np.ones(len(t)))
    for min_samples in (1, 3):
        averaging = PoseAveraging(space, min_samples=min_samples)
        dense = dbscan_labels(
            space.distance_matrix(R, t, R, t).numpy(), 0.5 * space.delta, min_samples
        )
        labels = averaging.cluster(hyps)
        np.testing.assert_array_equal(labels, dense)
        assert 6 <= labels.max() + 1 < 0.8 * len(t)  # some merging, not everything


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 80), edges=st.integers(0, 120))
def test_smallest_connected_matches_scipy(seed, n, edges):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rng = np.random.default_rng(seed)
    i, j = rng.integers(0, n, edges), rng.integers(0, n, edges)
    keep = i != j
    i, j = np.concatenate((i[keep], j[keep])), np.concatenate((j[keep], i[keep]))
    ours = smallest_connected(n, i, j)
    graph = coo_matrix((np.ones(len(i)), (i, j)), shape=(n, n))
    _, ref = connected_components(graph, directed=False)
    # same partition, and each label is the smallest member of its component
    assert len(np.unique(ours)) == len(np.unique(ref))
    assert all(
        len(np.unique(ref[ours == label])) == 1 and ours[label] == label
        for label in np.unique(ours)
    )
    assert (ours <= np.arange(n)).all()


def test_smallest_connected_on_a_long_shuffled_path():
    rng = np.random.default_rng(0)
    order = rng.permutation(2000)
    i, j = order[:-1], order[1:]
    labels = smallest_connected(2000, np.concatenate((i, j)), np.concatenate((j, i)))
    assert (labels == 0).all()
