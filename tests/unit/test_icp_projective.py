"""Projective ICP and the batched search (opnet.refine.associations, opnet.refine.search) against depth images
rendered by the real renderer: projective correspondences bring perturbed poses back like nearest-point
ones, a batch gives each pose what it would get alone, and the image-window neighbourhood is the ball a
k-d tree returns."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from test_icp import CAM, T_GT, _perturbed, _setup, assert_brought_back

from opnet.refine import (
    ICPSettings,
    SceneCloud,
    SearchSettings,
    refine_pose,
    refine_poses_nearest,
    refine_poses_projective,
)
from opnet.refine.search import model_axis, search_pose, search_poses


@pytest.mark.parametrize("name", ["bracket", "shaft", "zbracket"])
def test_projective_icp_brings_perturbed_poses_back(name: str) -> None:
    _, R_gt, scene, model, space = _setup(name)
    rng = np.random.default_rng(0)
    starts = [_perturbed(R_gt, rng, deg=6.0, mm=6.0) for _ in range(4)]
    out = refine_poses_projective(np.array([s[0] for s in starts]), np.array([s[1] for s in starts]), model, scene,
                                  space, ICPSettings(association="projective"))  # fmt: skip
    for r in out:
        assert_brought_back(r, R_gt, space, 1.5)  # from 6 mm, 6 degrees


def test_a_projective_batch_gives_each_pose_what_it_gets_alone() -> None:
    _, R_gt, scene, model, space = _setup("bracket")
    rng = np.random.default_rng(5)
    starts = [_perturbed(R_gt, rng, deg=d, mm=d) for d in (2.0, 5.0, 9.0)]
    settings = ICPSettings(association="projective", max_rotation_deg=4.0)  # the 9-degree start is rejected
    R, t = np.array([s[0] for s in starts]), np.array([s[1] for s in starts])
    batch = refine_poses_projective(R, t, model, scene, space, settings)
    for k, result in enumerate(batch):
        alone = refine_poses_projective(R[k : k + 1], t[k : k + 1], model, scene, space, settings)[0]
        assert result.status == alone.status
        assert np.allclose(result.R, alone.R, atol=1e-12) and np.allclose(result.t, alone.t, atol=1e-12)
    assert [r.status for r in batch][-1] == "rejected"
    empty = SceneCloud.from_depth(np.full((64, 64), np.nan), CAM.fx, CAM.fy, 31.5, 31.5)
    assert refine_poses_projective(R, t, model, empty, space, settings)[0].status == "no_depth"


@pytest.mark.parametrize("name", ["bracket", "shaft"])
def test_batched_nearest_point_icp_is_refine_pose_of_each(name: str) -> None:
    """All hypotheses in one k-d tree and one batch: each gets what :func:`refine_pose` gives it alone
    (the same pairs, steps, halvings, stopping rules and guard), a far one no depth, a turned one rejected."""
    _, R_gt, scene, model, space = _setup(name)
    rng = np.random.default_rng(3)
    starts = [_perturbed(R_gt, rng, deg=d, mm=d) for d in (1.0, 4.0, 8.0, 12.0)]
    R, t = np.array([s[0] for s in starts]), np.array([s[1] for s in starts])
    R = np.concatenate((R, R_gt[None])); t = np.concatenate((t, [T_GT + [0.0, 0.0, 0.5]]))  # behind the part: no depth
    for settings in (ICPSettings(max_rotation_deg=6.0), ICPSettings(min_gain=0.0, converged=(1e-6, 1e-7)),
                     ICPSettings(min_gain=0.05), ICPSettings(local_points=500, iterations=3)):
        batch = refine_poses_nearest(R, t, model, scene, space, settings)
        alone = [refine_pose(Rk, tk, model, scene, space, settings) for Rk, tk in zip(R, t, strict=True)]
        assert [r.status for r in batch] == [r.status for r in alone]
        for a, b in zip(batch, alone, strict=True):
            assert np.allclose(a.R, b.R, atol=1e-9) and np.allclose(a.t, b.t, atol=1e-10)
            assert a.correspondences == b.correspondences
            assert np.allclose(a.residual_after, b.residual_after, rtol=1e-9, equal_nan=True)
    statuses = [r.status for r in refine_poses_nearest(R, t, model, scene, space, ICPSettings(max_rotation_deg=6.0))]
    assert statuses[-1] == "no_depth" and "rejected" in statuses and statuses[0] == "refined"


def test_projective_icp_needs_a_depth_image_and_a_known_association() -> None:
    _, R_gt, scene, model, space = _setup("bracket")
    points_only = SceneCloud(scene.points, scene.normals)
    with pytest.raises(ValueError, match="projective needs a scene made from a depth image"):
        refine_poses_projective(R_gt[None], T_GT[None], model, points_only, space)
    with pytest.raises(ValueError, match="icp.association must be one of nearest, projective, got 'closest'"):
        ICPSettings(association="closest")


def test_the_image_window_neighbourhood_is_the_ball_of_the_tree() -> None:
    _, _, scene, model, _ = _setup("shaft")
    points_only = SceneCloud(scene.points, scene.normals)  # no grid: a k-d tree's ball
    for centre, radius in ((T_GT, 0.03), (T_GT + [0.01, 0.0, -0.02], 0.05), (T_GT - [0.0, 0.0, 0.45], 0.5)):  # the last: the ball reaches behind the camera
        a, na = scene.neighbourhood(centre, radius)
        b, nb = points_only.neighbourhood(centre, radius)
        assert len(a) > 0 and np.array_equal(a, b) and np.array_equal(na, nb)
    # nearest-point ICP is the same from either
    R0, t0 = _perturbed(np.eye(3), np.random.default_rng(1), 3.0, 3.0)
    one, two = (refine_pose(R0, t0, model, s, _setup("shaft")[4]) for s in (scene, points_only))
    assert np.allclose(one.R, two.R, atol=1e-9) and np.allclose(one.t, two.t, atol=1e-12)


def test_the_batched_turn_search_gives_each_pose_what_it_gets_alone() -> None:
    _, R_gt, scene, model, _ = _setup("bracket", seed=2)
    depth = np.full((CAM.height, CAM.width), np.nan)
    depth_rows = scene.points  # the rendered depth back from its points
    u = np.rint(depth_rows[:, 0] * CAM.fx / depth_rows[:, 2] + CAM.cx).astype(int)
    v = np.rint(depth_rows[:, 1] * CAM.fy / depth_rows[:, 2] + CAM.cy).astype(int)
    depth[v, u] = depth_rows[:, 2]
    rng = np.random.default_rng(3)
    starts = [_perturbed(R_gt, rng, deg=20.0, mm=8.0) for _ in range(3)]
    R, t = np.array([s[0] for s in starts]), np.array([s[1] for s in starts])
    axis = model_axis(model.points)
    for settings in (SearchSettings(), dataclasses.replace(SearchSettings(), fine="grid"),
                     dataclasses.replace(SearchSettings(), coarse=1, turn_step_deg=20.0, shift_step=0.05)):
        Rb, tb, sb = search_poses(R, t, model, depth, CAM, axis, settings)
        for k in range(3):
            Ra, ta, sa = search_pose(R[k], t[k], model, depth, CAM, axis, settings)
            assert np.allclose(Rb[k], Ra, atol=1e-12) and np.allclose(tb[k], ta, atol=1e-12) and sb[k] == pytest.approx(sa)
        assert (sb >= 0.0).all()
