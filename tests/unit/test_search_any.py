"""The search for any part (``search.mode: flips``): a compact part whose hypothesis is upside down, end over
end or a quarter turn off, and a few degrees and millimetres out, is brought back by the depth agreement;
the right pose is never left; a symmetric part's turns that are its symmetries are not tried twice."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from opnet.geometry.camera import Camera
from opnet.geometry.pose_numpy import PoseSpaceArrays, pose_distance
from opnet.metrics.records import HypothesisSet
from opnet.objects.library import builtin_object
from opnet.objects.model import ObjectModel
from opnet.refine import ICPSettings, ModelCloud, SearchSettings, refine_image
from opnet.refine.icp import _rotation
from opnet.refine.search import ambiguity_turns, is_flat, resolve_mode, search_any, search_any_many
from opnet.synthesis.layout import homogeneous
from opnet.synthesis.rendering import SceneRenderer

CAM = Camera(900.0, 900.0, 255.5, 255.5, 512, 512, 0.3, 2.0)


def _block() -> ObjectModel:
    """A 70 x 40 x 30 mm block with a 15 mm knob near one end of its top and a notch in one side: no
    rotational symmetry, not flat."""
    body = trimesh.creation.box((0.07, 0.04, 0.03))
    knob = trimesh.creation.box((0.015, 0.015, 0.015), homogeneous(np.eye(3), [0.02, 0.005, 0.0225]))
    tab = trimesh.creation.box((0.02, 0.01, 0.01), homogeneous(np.eye(3), [-0.025, -0.025, -0.01]))
    mesh = trimesh.util.concatenate([body, knob, tab])
    mesh.vertices -= (mesh.bounds[0] + mesh.bounds[1]) / 2
    return ObjectModel.from_mesh("block", mesh)


@pytest.fixture(scope="module")
def block_scene():
    obj = _block()
    R_gt = _rotation(np.array([2.6, 0.3, 0.4]))
    t_gt = np.array([0.01, -0.015, 0.7])
    # a floor under the part, 25 degrees off the image plane (a tilted camera), and a neighbour beside it
    floor = trimesh.creation.box((0.5, 0.5, 0.002))
    T_floor = homogeneous(_rotation(np.array([np.radians(155.0), 0.0, 0.0])), t_gt + np.array([0.0, 0.0, 0.03]))
    renderer = SceneRenderer(obj.mesh, CAM)
    renderer.begin_cycle(T_floor, None)
    T = np.stack([homogeneous(R_gt, t_gt), homogeneous(R_gt @ _rotation(np.array([0, 0, 1.2])), t_gt + [0.09, 0.03, 0.0])])
    depth = renderer.render(T).depth
    renderer.close()
    model = ModelCloud.from_mesh(obj.mesh, 600, obj.diameter)
    return obj, R_gt, t_gt, depth, model, PoseSpaceArrays.of(obj.pose_space)


def _off(R: np.ndarray, t: np.ndarray, G: np.ndarray, centre: np.ndarray, deg: float, mm: float):
    """The pose turned by the model-frame turn G about the centroid, then a few degrees and mm off."""
    Rg = R @ G
    tg = R @ centre + t - Rg @ centre
    return _rotation(np.radians(deg) * np.array([0.6, -0.8, 0.0])) @ Rg, tg + np.array([mm, -mm, 0.5 * mm]) / 1000


def test_a_compact_part_is_searched_by_flips_and_a_plate_by_turns() -> None:
    assert resolve_mode(SearchSettings(), ModelCloud.from_mesh(_block().mesh, 400, 0.1).points) == "flips"
    plate = trimesh.creation.box((0.12, 0.12, 0.002))
    assert is_flat(ModelCloud.from_mesh(plate, 400, 0.17).points)
    assert resolve_mode(SearchSettings(mode="flips"), ModelCloud.from_mesh(plate, 400, 0.17).points) == "flips"


@pytest.mark.parametrize("which", [1, 2, 5, 11])
def test_the_search_brings_back_a_flipped_part_and_icp_polishes_it(block_scene, which: int) -> None:
    obj, R_gt, t_gt, depth, model, space = block_scene
    G, centre = ambiguity_turns(model.points, space)
    assert len(G) == 24 and np.allclose(G[0], np.eye(3))  # no symmetry: every turn is another pose
    R0, t0 = _off(R_gt, t_gt, G[which], centre, 6.0, 4.0)
    assert pose_distance(space, R0, t0, R_gt, t_gt) > 0.3 * obj.diameter  # far from right
    hyps = HypothesisSet(R0[None], t0[None], np.array([0.8]))
    out, status = refine_image(hyps, depth, CAM, model, space, ICPSettings(budget_ms=None, search=SearchSettings()))
    assert status == ["searched"]
    assert pose_distance(space, out.R[0], out.t[0], R_gt, t_gt) < 0.3 * space.delta  # well within δ
    assert out.score[0] > 0.8


def test_the_search_never_leaves_the_right_pose(block_scene) -> None:
    obj, R_gt, t_gt, depth, model, space = block_scene
    R, t, score = search_any(R_gt, t_gt, model, depth, CAM, space, SearchSettings())
    assert pose_distance(space, R, t, R_gt, t_gt) < 0.002 and score > 0.8


@pytest.mark.parametrize("keep", [0, 3])
def test_many_hypotheses_in_one_batch_get_what_each_gets_alone(block_scene, keep: int) -> None:
    _, R_gt, t_gt, depth, model, space = block_scene
    turns = ambiguity_turns(model.points, space)
    G, centre = turns
    starts = [_off(R_gt, t_gt, G[w], centre, d, d) for w, d in ((1, 5.0), (0, 2.0), (7, 8.0), (11, 3.0))]
    R = np.stack([[starts[i][0], starts[(i + 1) % 4][0]] for i in range(4)])  # (4 hypotheses, 2 starts)
    t = np.stack([[starts[i][1], starts[(i + 1) % 4][1]] for i in range(4)])
    settings = SearchSettings(keep=keep)
    Rb, tb, score = search_any_many(R, t, model, depth, CAM, space, settings, turns)
    for n in range(4):
        Ra, ta, sa = search_any(R[n], t[n], model, depth, CAM, space, settings, turns)
        assert np.allclose(Rb[n], Ra, atol=1e-9) and np.allclose(tb[n], ta, atol=1e-10) and np.isclose(score[n], sa)
    assert keep == 0 or (score > 0.8).sum() >= 3  # with the local search most come back to the part


@pytest.mark.parametrize(("name", "expected"), [("bracket", 24), ("zbracket", 12), ("shaft", 6), ("pin", 3)])
def test_a_symmetric_parts_turns_are_tried_once_each(name: str, expected: int) -> None:
    """Turns equal under the part's symmetry are left out: a revolution part (the shaft) keeps the six
    directions of its axis, one whose ends are alike too (the pin) three, a half-turn symmetry (the z-bracket) half of them; no
    symmetry (the bracket) keeps all 24."""
    obj = builtin_object(name)
    space = PoseSpaceArrays.of(obj.pose_space)
    G, _ = ambiguity_turns(ModelCloud.from_mesh(obj.mesh, 400, obj.diameter).points, space)
    assert len(G) == expected


def test_the_ring_screws_half_turn_is_not_tried_twice(meshes_dir) -> None:
    from opnet.objects import load_object

    obj = load_object("ring_screw", mesh=meshes_dir / "IPARingScrew.stl", symmetry="cyclic2")
    G, _ = ambiguity_turns(ModelCloud.from_mesh(obj.mesh, 400, obj.diameter).points, PoseSpaceArrays.of(obj.pose_space))
    assert len(G) == 12


@pytest.mark.parametrize(("values", "message"), [
    ({"mode": "any"}, "search.mode must be one of auto, turn, flips"),
    ({"keep": -1}, "search.keep must be an integer in 0..100"),
    ({"local_deg": 0}, "search.local_deg must be a positive number"),
    ({"local_rounds": True}, "search.local_rounds must be an integer"),
])
def test_bad_flips_settings_are_one_clear_error(values: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        SearchSettings(**values)
