"""The depth-agreement search (opnet.refine.search) against depth rendered by the real renderer: a
flat T-plate turned half a revolution about its normal and slid along its plane -- a pose ICP keeps,
since its surface fits the plane -- is brought back by the search, which ranks it by its agreement;
the search never leaves a right pose; bad settings are one clear error."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from opnet.geometry.camera import Camera
from opnet.geometry.pose_numpy import PoseSpaceArrays
from opnet.objects.model import ObjectModel
from opnet.refine import (
    ICPSettings,
    ModelCloud,
    SceneCloud,
    SearchSettings,
    model_refinement,
    refine_hypotheses,
    refine_pose,
    settings_from_config,
)
from opnet.refine.agreement import agreement, pose_agreement
from opnet.refine.icp import _rotation
from opnet.refine.search import model_axis, search_pose
from opnet.synthesis.layout import homogeneous
from opnet.synthesis.rendering import SceneRenderer

CAM = Camera(900.0, 900.0, 255.5, 255.5, 512, 512, 0.3, 2.0)
T_GT = np.array([0.01, -0.02, 0.8])


def _t_plate() -> ObjectModel:
    """A 120 x 120 x 2 mm T (bar 25 mm wide, stem 20 mm), its normal the model's y axis, no symmetry
    but the mirror a T has: none among rotations -- a turn about the normal is a different pose."""
    bar = trimesh.creation.box((0.12, 0.002, 0.025), homogeneous(np.eye(3), [0.0, 0.0, 0.0475]))
    stem = trimesh.creation.box((0.02, 0.002, 0.095), homogeneous(np.eye(3), [0.0, 0.0, -0.0125]))
    mesh = trimesh.util.concatenate([bar, stem])
    mesh.vertices -= (mesh.bounds[0] + mesh.bounds[1]) / 2  # the origin at the box's centre, as IPD's
    return ObjectModel.from_mesh("t_plate", mesh)


@pytest.fixture(scope="module")
def plate_scene() -> tuple[ObjectModel, np.ndarray, np.ndarray, ModelCloud, PoseSpaceArrays]:
    obj = _t_plate()
    # the plate seen 20 degrees off its normal (as the IPD camera sees the basket floor), over a sheet
    # 2 mm beneath it with 12 mm holes every 18 mm (the ground far behind shows through them)
    R_gt = _rotation(np.array([np.radians(-70.0), 0.0, 0.0])) @ _rotation(np.array([0.0, 0.6, 0.0]))
    bars = [trimesh.creation.box((0.36, 0.001, 0.006), homogeneous(np.eye(3), [0.0, 0.0, z])) for z in
            np.arange(-0.18, 0.19, 0.018)] + [trimesh.creation.box((0.006, 0.001, 0.36), homogeneous(np.eye(3),
            [x, 0.0, 0.0])) for x in np.arange(-0.18, 0.19, 0.018)]  # fmt: skip
    sheet = trimesh.util.concatenate(bars)  # a grid of 6 mm wires: 12 mm square holes
    renderer = SceneRenderer(obj.mesh, CAM)
    below = homogeneous(R_gt, T_GT + R_gt @ np.array([0.0, -0.0025, 0.0]))
    renderer.begin_cycle(below, sheet)
    depth = renderer.render(homogeneous(R_gt, T_GT)[None]).depth
    renderer.close()
    depth = np.where(np.isfinite(depth), depth, CAM.clip_end)  # the ground beyond the far plane, at it
    model = ModelCloud.from_mesh(obj.mesh, 800, obj.diameter)
    return obj, R_gt, depth, model, PoseSpaceArrays.of(obj.pose_space)


def _turned(R: np.ndarray, deg: float, shift_mm: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """R turned ``deg`` about the plate's normal (model y), its origin slid along the plate's plane."""
    n, e1 = R @ np.array([0.0, 1.0, 0.0]), R @ np.array([1.0, 0.0, 0.0])
    return _rotation(n * np.radians(deg)) @ R, T_GT + e1 * shift_mm[0] / 1000 + np.cross(n, e1) * shift_mm[1] / 1000


def _angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1) / 2, -1, 1))))


def test_the_axis_of_a_flat_part_is_its_normal() -> None:
    assert abs(model_axis(ModelCloud.from_mesh(_t_plate().mesh, 800, 0.15).points) @ [0, 1, 0]) > 0.999
    assert np.array_equal(model_axis(np.zeros((3, 3)), "z"), [0.0, 0.0, 1.0])


def test_agreement_is_highest_at_the_true_pose(plate_scene) -> None:
    obj, R_gt, depth, model, _ = plate_scene
    s = SearchSettings()
    right = pose_agreement(R_gt, T_GT, model, depth, CAM, s)
    assert right > 0.9
    for deg in (90.0, 180.0, 270.0):
        assert pose_agreement(*_turned(R_gt, deg, (0.0, 0.0)), model, depth, CAM, s) < right - 0.2
    # a point measured behind the model counts against it, a missing one neither way
    pts = np.array([[[0.0, 0.0, 0.5], [0.005, 0.0, 0.5]]])  # pixels (0, 0) and (1, 0)
    probe = np.array([[0.40, np.nan], [np.nan, np.nan]])
    cam = Camera(100.0, 100.0, 0.0, 0.0, 2, 2, 0.1, 2.0)
    assert agreement(pts, np.ones((1, 2), bool), probe, cam, 0.01, 1.0)[0] == 0.0  # occluded + missing
    assert agreement(pts, np.ones((1, 2), bool), probe + 0.2, cam, 0.01, 1.0)[0] == -0.5  # seen through
    assert agreement(pts, np.ones((1, 2), bool), probe + 0.1, cam, 0.01, 1.0)[0] == 0.5  # agrees


@pytest.mark.parametrize(("deg", "shift"), [(180.0, (8.0, -5.0)), (90.0, (-6.0, 6.0)), (35.0, (0.0, 9.0))])
def test_the_search_brings_back_a_turned_and_slid_plate_that_icp_keeps(plate_scene, deg, shift) -> None:
    obj, R_gt, depth, model, space = plate_scene
    R0, t0 = _turned(R_gt, deg, shift)
    scene = SceneCloud.from_depth(depth, CAM.fx, CAM.fy, CAM.cx, CAM.cy)
    icp = refine_pose(R0, t0, model, scene, space)
    assert _angle(R_gt, icp.R) > 20.0  # ICP fits the plane, not the turn
    R, t, score = search_pose(icp.R, icp.t, model, depth, CAM, model_axis(model.points), SearchSettings())
    step = SearchSettings().shift_step * model.diameter  # within a step of the grids (ICP polishes after)
    assert _angle(R_gt, R) < SearchSettings().turn_step_deg and np.linalg.norm(t - T_GT) < step
    assert score > 0.9


@pytest.mark.parametrize("fine", ["grid", "local"])
def test_the_search_never_leaves_the_right_pose(plate_scene, fine: str) -> None:
    """The grid keeps the right pose exactly (no turn, no shift wins ties); the local search may settle a
    fraction of a millimetre away, where the depth's pixels agree as well."""
    obj, R_gt, depth, model, _ = plate_scene
    R, t, _ = search_pose(R_gt, T_GT, model, depth, CAM, model_axis(model.points), SearchSettings(fine=fine))
    exact = fine == "grid"
    assert _angle(R_gt, R) < (1e-9 if exact else 0.5) and np.linalg.norm(t - T_GT) < (1e-12 if exact else 1e-3)


def test_refine_with_search_ranks_hypotheses_by_their_agreement(plate_scene) -> None:
    obj, R_gt, depth, model, space = plate_scene
    scene = SceneCloud.from_depth(depth, CAM.fx, CAM.fy, CAM.cx, CAM.cy)
    far = T_GT + np.array([0.4, 0.0, 0.0])  # nothing there: ICP skips it, its agreement is where it stands
    poses = [_turned(R_gt, 180.0, (5.0, 5.0)), (R_gt, far)]
    R, t = np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses])
    settings = ICPSettings(budget_ms=None, search=SearchSettings())
    R1, t1, status, score = refine_hypotheses(R, t, np.array([0.3, 0.9]), model, scene, space, settings, depth, CAM)
    assert status == ["searched", "no_depth"]
    assert _angle(R_gt, R1[0]) < 2.0 and np.linalg.norm(t1[0] - T_GT) * 1000 < 2.0
    assert score[0] > 0.9 and score[1] <= 0.0  # the refined plate now outranks the empty hypothesis
    with pytest.raises(ValueError, match="the search needs the depth image"):
        refine_hypotheses(R, t, np.array([0.3, 0.9]), model, scene, space, settings)


@pytest.mark.parametrize(("refine", "message"), [
    ({"method": "search", "search": {"axis": "w"}}, "search.axis must be one of auto, x, y, z"),
    ({"method": "search", "search": {"tolerance": 0}}, "search.tolerance must be a positive number"),
    ({"method": "search", "search": {"score": "best"}}, "search.score must be one of agreement"),
    ({"method": "search", "search": {"shift": 1.0, "shift_step": 0.001}}, "more than 101 x 101 shifts"),
    ({"method": "search", "search": {"turn_stp_deg": 5}}, r"search: unknown keys \['turn_stp_deg'\]"),
    ({"method": "search", "search": {"coarse": 0}}, "search.coarse must be a positive integer"),
    ({"method": "search", "search": {"fine": "fast"}}, "search.fine must be grid or local"),
    ({"method": "search", "search": {"merge": -1}}, "search.merge must be a number >= 0"),
    ({"method": "search", "search": {"anchor": -0.5}}, "search.anchor must be a number in 0..100"),
    ({"method": "search", "search": {"turn_tolerance": 0}}, "search.turn_tolerance must be a positive number or null"),
    ({"method": "search", "search": {"suppress_icp": -1}}, "search.suppress_icp must be a number >= 0"),
    ({"method": "search", "search": {"suppress_searched": "yes"}}, "search.suppress_searched must be true or false"),
    ({"method": "search", "search": {"coarse_stride": 0}}, "search.coarse_stride must be a positive integer"),
    ({"method": "search", "search": {"rank_points": -1}}, r"search.rank_points must be an integer in 0..20000"),
    ({"method": "search", "search": {"polish_share": 2}}, r"search.polish_share must be a number in 0..1"),
    ({"method": "icp", "icp": {"search": {}}}, r"icp: unknown keys \['search'\]"),
    ({"method": "serch"}, "expected none, icp or search"),
])
def test_bad_search_settings_are_one_clear_error(refine: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        settings_from_config(refine)


def test_search_config_reads_into_settings() -> None:
    settings = settings_from_config({"method": "search", "icp": {"budget_ms": None}, "search": {"turn_step_deg": 10}})
    assert settings.search == SearchSettings(turn_step_deg=10) and settings.budget_ms is None
    assert settings_from_config({"method": "icp"}).search is None


def test_searches_that_end_on_one_pose_leave_one_hypothesis(plate_scene) -> None:
    from opnet.metrics.records import HypothesisSet
    from opnet.refine import refine_image

    obj, R_gt, depth, model, space = plate_scene
    poses = [_turned(R_gt, 180.0, (5.0, 5.0)), _turned(R_gt, 20.0, (-6.0, 0.0)), _turned(R_gt, 90.0, (0.0, 7.0))]
    hyps = HypothesisSet(np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses]), np.array([0.9, 0.5, 0.2]))
    settings = ICPSettings(budget_ms=None, search=SearchSettings())
    out, status = refine_image(hyps, depth, CAM, model, space, settings)
    assert sorted(status) == ["searched", "suppressed", "suppressed"] and len(out.t) == 1
    assert np.linalg.norm(out.t[0] - T_GT) * 1000 < 2.0 and out.score[0] > 0.9
    kept, status = refine_image(hyps, depth, CAM, model, space,
                                ICPSettings(budget_ms=None, search=SearchSettings(suppress=0.0, merge=0.0)))
    assert status == ["searched"] * 3 and len(kept.t) == 3  # suppress 0 and merge 0: every hypothesis kept


@pytest.mark.parametrize(("coarse", "fine"), [(1, "grid"), (3, "grid"), (3, "local")])
def test_the_whole_grid_and_coarse_to_fine_find_the_same_pose(plate_scene, coarse: int, fine: str) -> None:
    obj, R_gt, depth, model, _ = plate_scene
    R0, t0 = _turned(R_gt, 140.0, (7.0, -4.0))
    settings = SearchSettings(coarse=coarse, fine=fine)
    R, t, score = search_pose(R0, t0, model, depth, CAM, model_axis(model.points), settings)
    assert _angle(R_gt, R) < settings.turn_step_deg and np.linalg.norm(t - T_GT) < settings.shift_step * model.diameter
    assert score > 0.9


def test_hypotheses_near_a_better_ones_origin_are_merged_before_the_search() -> None:
    from opnet.refine.pipeline import _merged

    t = np.array([[0.0, 0.0, 1.0], [0.005, 0.0, 1.0], [0.05, 0.0, 1.0], [0.004, 0.006, 1.0]])
    score = np.array([0.2, 0.9, 0.5, 0.1])
    # best first: 1 kept; 0 (5 mm from 1) and 3 (6 mm from 1) merged; 2 (45 mm away) kept
    assert _merged(t, score, 0.01).tolist() == [True, False, False, True]
    assert not _merged(t, score, 0.0).any()


def test_icp_on_a_thinned_neighbourhood_stops_short_on_a_plate_every_second_pixel_does_not(plate_scene) -> None:
    """``icp.local_points``: every k-th scene point near the hypothesis is fitted. On a flat plate 6 degrees
    and a few millimetres off in its plane, all 37,000 points bring it within a fifth of a degree; a few
    thousand leave degrees (why refine=search keeps all of them by default)."""
    obj, R_gt, depth, model, space = plate_scene
    scene = SceneCloud.from_depth(depth, CAM.fx, CAM.fy, CAM.cx, CAM.cy)
    R0, t0 = _turned(R_gt, 6.0, (3.0, -2.0))
    full = refine_pose(R0, t0, model, scene, space, ICPSettings(budget_ms=None))
    thin = refine_pose(R0, t0, model, scene, space, ICPSettings(budget_ms=None, local_points=3000))
    assert full.status == thin.status == "refined"
    assert _angle(R_gt, full.R) < 0.5 and np.linalg.norm(full.t - T_GT) < 5e-4
    assert _angle(R_gt, thin.R) < 6.0  # closer than it started, not as close
    # every 2nd pixel (refine=search's stride; points 1.8 mm apart here, 1.6 mm on the IPD Photoneo frames) is
    # as good as all of them
    strided = refine_pose(R0, t0, model, SceneCloud.from_depth(depth, CAM.fx, CAM.fy, CAM.cx, CAM.cy, 2), space,
                          ICPSettings(budget_ms=None))  # fmt: skip
    assert _angle(R_gt, strided.R) < 0.5 and np.linalg.norm(strided.t - T_GT) < 5e-4
    with pytest.raises(ValueError, match="icp.local_points must be an integer >= 0"):
        ICPSettings(local_points=-1)


def test_every_refine_option_composes_to_settings_and_search_fast_is_search_with_its_speed_keys() -> None:
    from hydra import compose, initialize_config_dir

    from opnet.paths import REPO_ROOT, config_dir

    settings = {}
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        for path in sorted((REPO_ROOT / "conf" / "refine").glob("*.yaml")):
            group = compose(config_name="eval", overrides=[f"refine={path.stem}"]).refine
            # refine=model: the checkpoint's own (opnet.refine.model_refinement), none for one recording none
            settings[path.stem] = settings_from_config(model_refinement(group, None)[0])
    assert {"none", "icp", "search", "search_fast", "model"} <= set(settings) and settings["none"] is None
    assert settings["model"] is None
    fast, full = settings["search_fast"], settings["search"]
    changed = {f.name for f in dataclasses.fields(full) if getattr(full, f.name) != getattr(fast, f.name)}
    assert changed == {"association", "polish_association", "iterations", "min_gain"}
    assert (fast.association, fast.polish_association) == ("projective", "nearest") and fast.search == full.search


@pytest.mark.parametrize("threads", [2, 3])
def test_threads_share_an_images_hypotheses_and_change_no_result(plate_scene, threads: int) -> None:
    from opnet.metrics.records import HypothesisSet
    from opnet.refine import refine_image

    _, R_gt, depth, model, space = plate_scene
    poses = [_turned(R_gt, a, s) for a, s in ((180.0, (5.0, 5.0)), (20.0, (-6.0, 0.0)), (90.0, (0.0, 7.0)),
                                             (0.0, (0.0, 0.0)), (45.0, (3.0, -3.0)))]  # fmt: skip
    hyps = HypothesisSet(np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses]),
                         np.array([0.9, 0.5, 0.2, 0.7, 0.4]))  # fmt: skip
    base = ICPSettings(budget_ms=None, search=SearchSettings(suppress=0.0, merge=0.0))
    one_timings, many_timings = {}, {}
    one, s1 = refine_image(hyps, depth, CAM, model, space, dataclasses.replace(base, threads=1), one_timings)
    many, s2 = refine_image(hyps, depth, CAM, model, space, dataclasses.replace(base, threads=threads), many_timings)
    assert s1 == s2 == ["searched"] * 5
    assert np.allclose(one.R, many.R, atol=1e-9) and np.allclose(one.t, many.t, atol=1e-10)
    assert np.array_equal(one.score, many.score)
    assert set(one_timings) == set(many_timings) == {"scene", "icp", "search", "polish", "rank"}
    with pytest.raises(ValueError, match="icp.threads must be a positive integer, got 0"):
        ICPSettings(threads=0)


def test_an_anchored_search_moves_only_where_the_depth_pays_for_it(plate_scene) -> None:
    """``anchor`` charges a candidate for how far it slid from the hypothesis: agreement alone brings a plate
    slid 6 mm back, a heavy anchor keeps it where the network put it, and a turn about the normal (which moves
    no origin) is found as before."""
    obj, R_gt, depth, model, _ = plate_scene
    axis = model_axis(model.points)
    R0, t0 = _turned(R_gt, 0.0, (6.0, 0.0))
    _, t_free, _ = search_pose(R0, t0, model, depth, CAM, axis, SearchSettings())
    _, t_held, _ = search_pose(R0, t0, model, depth, CAM, axis, SearchSettings(anchor=10.0))
    assert np.linalg.norm(t_free - T_GT) < 2e-3 and np.linalg.norm(t_held - t0) < 1e-9
    R_turn, t_turn, _ = search_pose(*_turned(R_gt, 180.0, (0.0, 0.0)), model, depth, CAM, axis, SearchSettings(anchor=10.0))
    assert _angle(R_gt, R_turn) < SearchSettings().turn_step_deg and np.linalg.norm(t_turn - T_GT) < 1e-9


@pytest.mark.parametrize(("mode", "used"), [("auto", 0.02), ("flips", 0.04)])
def test_a_flat_part_is_searched_and_ranked_at_its_turn_tolerance(plate_scene, monkeypatch, mode: str, used: float) -> None:
    """``turn_tolerance`` replaces ``tolerance`` in the search and the ranking of a part searched by turns (the plate:
    ``auto`` finds it flat) and nowhere else."""
    import opnet.refine.pipeline as pipeline

    obj, R_gt, depth, model, space = plate_scene
    seen: list[float] = []
    real = pipeline.score_poses

    def spy(R, t, model, depth, camera, settings):
        seen.append(settings.tolerance)
        return real(R, t, model, depth, camera, settings)

    monkeypatch.setattr(pipeline, "score_poses", spy)
    scene = SceneCloud.from_depth(depth, CAM.fx, CAM.fy, CAM.cx, CAM.cy)
    settings = ICPSettings(budget_ms=None, search=SearchSettings(tolerance=0.04, turn_tolerance=0.02, mode=mode))
    refine_hypotheses(R_gt[None], T_GT[None], np.array([0.5]), model, scene, space, settings, depth, CAM)
    assert seen == [used]


def _polished_and_searched(monkeypatch, plate_scene, search: SearchSettings, off: bool = False,
                           ) -> tuple[list[int], list[int], list[str]]:  # fmt: skip
    """How many poses each ICP call and each search got, and the statuses, for three hypotheses of the plate: two
    a few millimetres and degrees apart that search to one pose, and one turned 90 degrees (``off``: 120 mm off
    the plate, over the holed sheet) (threads: 1)."""
    import opnet.refine.pipeline as pipeline

    obj, R_gt, depth, model, space = plate_scene
    icp_calls: list[int] = []
    searched: list[int] = []
    real_icp, real_search = pipeline._refine_many, pipeline.search_poses

    def icp_spy(R, *args):
        icp_calls.append(len(R))
        return real_icp(R, *args)

    def search_spy(R, *args):
        searched.append(len(R))
        return real_search(R, *args)

    poses = [_turned(R_gt, 2.0, (1.0, 0.0)), _turned(R_gt, 0.0, (0.0, 1.0)),
             _turned(R_gt, 90.0, (120.0, 0.0) if off else (0.0, 6.0))]
    scene = SceneCloud.from_depth(depth, CAM.fx, CAM.fy, CAM.cx, CAM.cy)
    settings = ICPSettings(budget_ms=None, threads=1, search=search)
    with monkeypatch.context() as patch:
        patch.setattr(pipeline, "_refine_many", icp_spy)
        patch.setattr(pipeline, "search_poses", search_spy)
        _, t, status, _ = refine_hypotheses(np.stack([p[0] for p in poses]), np.stack([p[1] for p in poses]),
                                            np.array([0.9, 0.8, 0.2]), model, scene, space, settings, depth, CAM)
    kept = [k for k, s in enumerate(status) if s == "searched"]
    assert kept and np.linalg.norm(t[kept[0]] - T_GT) * 1000 < 2.0
    return icp_calls, searched, status


def test_duplicates_the_search_made_are_not_polished_with_suppress_searched(plate_scene, monkeypatch) -> None:
    """All three search to the true pose; with ``suppress_searched`` only the one the search found best is polished
    (the ICP calls: the first ICP of three, then the polish of one): one pose is left either way."""
    late = _polished_and_searched(monkeypatch, plate_scene, SearchSettings(merge=0.0))
    early = _polished_and_searched(monkeypatch, plate_scene, SearchSettings(merge=0.0, suppress_searched=True))
    assert late[0] == [3, 3] and early[0] == [3, 1] and late[1] == early[1] == [3]
    assert sorted(late[2]) == sorted(early[2]) == ["searched", "suppressed", "suppressed"]


def test_hypotheses_icp_brought_together_are_searched_once_with_suppress_icp(plate_scene, monkeypatch) -> None:
    """The two hypotheses a few millimetres and degrees apart are within 0.5 delta after ICP: the worse is dropped
    unsearched; the one turned 90 degrees is searched."""
    icp_calls, searched, status = _polished_and_searched(monkeypatch, plate_scene,
                                                         SearchSettings(merge=0.0, suppress_icp=0.5))
    assert searched == [2] and status[1] == "suppressed" and status[0] == "searched"


def test_a_strided_coarse_grid_scores_fewer_points_and_finds_the_same_pose(plate_scene, monkeypatch) -> None:
    import opnet.refine.search as search

    obj, R_gt, depth, model, _ = plate_scene
    R0, t0 = _turned(R_gt, 140.0, (7.0, -4.0))
    scored: list[int] = []
    real = search.agreement_xyz

    def spy(x, *args):
        scored.append(x.shape[-1])
        return real(x, *args)

    monkeypatch.setattr(search, "agreement_xyz", spy)
    found = {}
    for stride in (1, 3):
        scored.clear()
        settings = SearchSettings(coarse_stride=stride)
        R, t, score = search_pose(R0, t0, model, depth, CAM, model_axis(model.points), settings)
        assert _angle(R_gt, R) < settings.turn_step_deg and np.linalg.norm(t - T_GT) < settings.shift_step * model.diameter
        found[stride] = scored[0]
    assert found[3] == -(-found[1] // 3)  # every third facing point of the coarse grid's candidates


def test_a_searched_hypothesis_far_below_the_best_agreement_is_not_polished(plate_scene, monkeypatch) -> None:
    """With ``polish_share`` 0.8 the hypothesis over the holed sheet (its agreement far below the plate's) keeps its
    searched pose unpolished: one ICP call fewer; with 0 every searched hypothesis is polished."""
    icp_all, _, status_all = _polished_and_searched(monkeypatch, plate_scene, SearchSettings(merge=0.0), off=True)
    icp_some, _, status = _polished_and_searched(monkeypatch, plate_scene, SearchSettings(merge=0.0, polish_share=0.8),
                                                 off=True)  # fmt: skip
    assert icp_all == [3, 3] and status_all[2] == "searched"
    assert icp_some == [3, 2] and status[2] == "unpolished"


def test_the_ranking_is_measured_on_the_rank_points_where_set(plate_scene, monkeypatch) -> None:
    """``rank_points``: the Refiner samples a cloud of its own and the final agreements are measured on it (the
    search's on ICP's points); the export writes it for a recorded refinement that ranks on it."""
    import opnet.refine.pipeline as pipeline
    from opnet.deploy.export import icp_model_metadata
    from opnet.metrics.records import HypothesisSet
    from opnet.refine import Refiner

    obj, R_gt, depth, model, space = plate_scene
    assert Refiner.for_object(obj, ICPSettings(search=SearchSettings())).rank_model is None
    refiner = Refiner.for_object(obj, ICPSettings(budget_ms=None, search=SearchSettings(rank_points=1500)))
    assert len(refiner.rank_model.points) == 1500 and len(refiner.model.points) == ICPSettings().model_points
    counts: list[int] = []
    real = pipeline.score_poses

    def spy(R, t, model, depth, camera, settings):
        counts.append(len(model.points))
        return real(R, t, model, depth, camera, settings)

    monkeypatch.setattr(pipeline, "score_poses", spy)
    out, status = refiner(HypothesisSet(R_gt[None], T_GT[None], np.array([0.5])), depth, CAM)
    assert counts == [1500] and status == ["searched"] and out.score[0] > 0.9
    flat = icp_model_metadata(obj, "search_flat")  # the recorded refinement's points: 400 for ICP, 2000 to rank
    assert len(flat["points"]) == 400 and len(flat["rank_points"]) == 2000
    assert "rank_points" not in icp_model_metadata(obj, "search_fast")
    assert len(icp_model_metadata(obj, "search_fast")["points"]) == len(icp_model_metadata(obj)["points"]) == 600
