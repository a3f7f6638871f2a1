"""Point-to-plane ICP (opnet.refine) against depth images rendered by the real renderer: it
improves perturbed poses, keeps a symmetric part's pose on the twin it started from, and skips or
rejects what it cannot refine."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from opnet.geometry.camera import Camera
from opnet.geometry.pose_numpy import PoseSpaceArrays, rotation_change_deg
from opnet.objects import builtin_object
from opnet.refine import ICPSettings, ModelCloud, SceneCloud, refine_hypotheses, refine_pose
from opnet.refine.icp import _rotation
from opnet.synthesis.layout import homogeneous
from opnet.synthesis.rendering import SceneRenderer

CAM = Camera(600.0, 600.0, 255.5, 255.5, 512, 512, 0.3, 2.0)
T_GT = np.array([0.02, -0.01, 0.6])


def _setup(name: str, seed: int = 1) -> tuple[object, np.ndarray, SceneCloud, ModelCloud, PoseSpaceArrays]:
    obj = builtin_object(name)
    R_gt = Rotation.random(random_state=seed).as_matrix()
    renderer = SceneRenderer(obj.mesh, CAM)
    depth = renderer.render(homogeneous(R_gt, T_GT)[None]).depth
    renderer.close()
    scene = SceneCloud.from_depth(depth, CAM.fx, CAM.fy, CAM.cx, CAM.cy)
    return obj, R_gt, scene, ModelCloud.from_mesh(obj.mesh, 600, obj.diameter), PoseSpaceArrays.of(obj.pose_space)


def _perturbed(R: np.ndarray, rng: np.random.Generator, deg: float, mm: float) -> tuple[np.ndarray, np.ndarray]:
    w, d = rng.normal(size=3), rng.normal(size=3)
    return _rotation(w / np.linalg.norm(w) * np.radians(deg)) @ R, T_GT + d / np.linalg.norm(d) * mm / 1000


@pytest.mark.parametrize("name", ["bracket", "shaft", "zbracket"])
def test_icp_brings_perturbed_poses_back(name: str) -> None:
    _, R_gt, scene, model, space = _setup(name)
    rng = np.random.default_rng(0)
    for _ in range(4):
        R0, t0 = _perturbed(R_gt, rng, deg=6.0, mm=6.0)
        assert_brought_back(refine_pose(R0, t0, model, scene, space), R_gt, space, 1.0)  # from 6 mm, 6 degrees


def assert_brought_back(out: object, R_gt: np.ndarray, space: PoseSpaceArrays, within: float) -> None:
    """A refined pose within ``within`` mm and degrees of the ground truth, its fit cost lowered, R a rotation."""
    assert out.status == "refined"
    assert np.linalg.norm(out.t - T_GT) * 1000 < within
    assert rotation_change_deg(R_gt, out.R, space) < within
    assert out.residual_after < out.residual_before
    assert np.allclose(out.R @ out.R.T, np.eye(3), atol=1e-9) and np.linalg.det(out.R) > 0


def test_icp_keeps_a_symmetric_part_on_the_twin_it_started_from() -> None:
    # zbracket: cyclic order 2 about z; start near the twin R_gt @ Rz(180°): equivalent, and ICP
    # must end near that twin, not turn half a revolution towards the other representative
    obj, R_gt, scene, model, space = _setup("zbracket", seed=3)
    step = obj.symmetry.group()[1]
    twin = R_gt @ step
    rng = np.random.default_rng(2)
    R0, t0 = _perturbed(twin, rng, deg=5.0, mm=4.0)
    out = refine_pose(R0, t0, model, scene, space)
    assert out.status == "refined"
    assert rotation_change_deg(R_gt, out.R, space) < 1.0  # equivalent to the ground truth
    plain = PoseSpaceArrays(space.Lambda, np.eye(3)[None], space.delta)  # no symmetry: the plain angle
    assert rotation_change_deg(twin, out.R, plain) < 1.0  # and still on the twin it started from


def test_a_refinement_beyond_the_guard_is_rejected_and_the_pose_kept() -> None:
    _, R_gt, scene, model, space = _setup("bracket")
    R0, t0 = _perturbed(R_gt, np.random.default_rng(4), deg=8.0, mm=2.0)
    out = refine_pose(R0, t0, model, scene, space, ICPSettings(max_rotation_deg=2.0))
    assert out.status == "rejected" and np.array_equal(out.R, R0) and np.array_equal(out.t, t0)


def test_no_depth_near_the_hypothesis_is_a_skip_with_the_pose_kept() -> None:
    _, R_gt, scene, model, space = _setup("bracket")
    far = T_GT + np.array([0.3, 0.0, 0.0])  # 30 cm beside the part: no scene point within reach
    out = refine_pose(R_gt, far, model, scene, space)
    assert out.status == "no_depth" and np.array_equal(out.t, far)
    empty = SceneCloud.from_depth(np.full((64, 64), np.nan), CAM.fx, CAM.fy, 31.5, 31.5)
    assert refine_pose(R_gt, T_GT, model, empty, space).status == "no_depth"


def test_the_scene_cloud_holds_only_measured_points_with_their_normals() -> None:
    """A missing pixel is no point of the cloud, though its neighbours could give it a normal (and its four
    neighbours have none); the strided grid is the image's every k-th pixel."""
    yy, xx = np.mgrid[0:64, 0:64]
    depth = 0.8 + 0.001 * xx + 0.0005 * yy  # a tilted plane
    depth[20, 30] = np.nan
    depth[40, 10] = 0.0
    full = SceneCloud.from_depth(depth, CAM.fx, CAM.fy, 31.5, 31.5)
    assert np.isfinite(full.points).all() and np.isfinite(full.normals).all()
    assert len(full.points) == 62 * 62 - 2 * 5  # the border has no normal; a missing pixel: 1 point, 4 normals
    assert (full.normals[:, 2] < 0).all()  # facing the camera
    strided = SceneCloud.from_depth(depth, CAM.fx, CAM.fy, 31.5, 31.5, 2)
    grid = strided._grid
    assert np.array_equal(grid.xyz[..., 2], np.where(depth > 0, depth, np.nan)[::2, ::2], equal_nan=True)


def test_hypotheses_are_refined_best_first_within_the_budget() -> None:
    _, R_gt, scene, model, space = _setup("bracket")
    rng = np.random.default_rng(5)
    poses = [_perturbed(R_gt, rng, deg=4.0, mm=4.0) for _ in range(3)]
    R, t = np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses])
    score = np.array([0.2, 0.9, 0.5])
    _, t1, status, score1 = refine_hypotheses(R, t, score, model, scene, space, ICPSettings(budget_ms=None))
    assert status == ["refined"] * 3 and (np.linalg.norm(t1 - T_GT, axis=1) < 1e-3).all()
    assert np.array_equal(score1, score)  # ICP alone keeps the network's scores
    R2, t2, status, _ = refine_hypotheses(R, t, score, model, scene, space, ICPSettings(budget_ms=0))
    assert status == ["budget"] * 3 and np.array_equal(t2, t) and np.array_equal(R2, R)


@pytest.mark.parametrize(("settings", "message"), [
    ({"radius": 0}, "icp.radius must be a positive number"),
    ({"iterations": 2.5}, "icp.iterations must be a positive integer"),
    ({"budget_ms": -1}, "icp.budget_ms must be >= 0 or null"),
    ({"max_rotaton_deg": 5}, r"icp: unknown keys \['max_rotaton_deg'\]"),
])
def test_bad_settings_are_one_clear_error(settings: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ICPSettings.from_config(settings)


def test_the_default_convergence_ends_where_a_tight_one_does() -> None:
    # stopping at steps of a hundredth of a degree and millimetre ends within hundredths of the pose a
    # ten-thousandth would reach; bad tolerances are refused naming the key
    _, R_gt, scene, model, space = _setup("bracket")
    rng = np.random.default_rng(7)
    for _ in range(3):
        R0, t0 = _perturbed(R_gt, rng, deg=6.0, mm=6.0)
        loose = refine_pose(R0, t0, model, scene, space)
        tight = refine_pose(R0, t0, model, scene, space, ICPSettings(converged=(1e-6, 1e-7)))
        assert np.linalg.norm(loose.t - tight.t) * 1000 < 0.05
        assert rotation_change_deg(tight.R, loose.R, space) < 0.05
    for bad in ([1e-4], [0.0, 1e-5], [True, 1e-5], "1e-4", [float("nan"), 1e-5]):
        with pytest.raises(ValueError, match=r"icp.converged must be two positive numbers \[radians, metres\]"):
            ICPSettings(converged=bad)
