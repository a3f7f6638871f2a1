"""Assignment rules of each parameterization on small hand-built scenes with known answers."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from opnet.geometry import Camera
from opnet.objects import builtin_object
from opnet.parameterizations import (
    APParameterization,
    EVEParameterization,
    GroundTruthBatch,
    MPParameterization,
    SIParameterization,
    VanillaParameterization,
    ZParameterization,
)

# 128 x 128, clip [0.5, 1.5]; a 16 x 16 grid has 8-pixel cells: pixel u in cell floor((u + 0.5) / 8)
CAMERA = Camera.from_fov(60.0, 128, 128, 0.5, 1.5)
BRACKET = builtin_object("bracket")


def scene(
    pixels: list[tuple[float, float, float]],
    visibility: list[float],
    segmentation: np.ndarray | None = None,
) -> GroundTruthBatch:
    """One image, objects with origins at pixels (u, v) and depth z metres, identity rotation."""
    uvz = np.asarray(pixels, dtype=np.float64).reshape(-1, 3)
    u, v, z = uvz.T
    t = np.stack(((u - CAMERA.cx) * z / CAMERA.fx, (v - CAMERA.cy) * z / CAMERA.fy, z), -1)
    n = len(t)
    return GroundTruthBatch.from_arrays(
        [(np.tile(np.eye(3), (n, 1, 1)), t, visibility, np.arange(1, n + 1), segmentation)]
    )


def cell_values(param, target: torch.Tensor, channel: str) -> torch.Tensor:
    """(slots, S, S) values of one named channel of image 0."""
    c = ["p", "v", "x", "y", "z", "phi1", "phi2", "phi3"].index(channel)
    return param.split_slots(target)[0, :, c]


def occupied(param, target: torch.Tensor) -> dict[tuple[int, int, int], float]:
    """{(slot, row, col): visibility} of the filled cells of image 0."""
    p, v = cell_values(param, target, "p"), cell_values(param, target, "v")
    return {
        tuple(int(i) for i in idx): round(float(v[tuple(idx)]), 4) for idx in torch.nonzero(p > 0)
    }


def test_vanilla_origin_cell_and_highest_visibility_wins():
    param = VanillaParameterization(BRACKET)
    # objects 0 and 1 share cell (row 6, col 2); object 2 alone in (row 0, col 15);
    # object 3 outside the image
    gt = scene(
        [(20.0, 50.0, 1.0), (18.0, 52.0, 0.9), (127.0, 3.0, 1.2), (-5.0, 60.0, 1.0)],
        [0.6, 0.9, 0.4, 1.0],
    )
    target = param.encode(gt, CAMERA)
    assert occupied(param, target) == {(0, 6, 2): 0.9, (0, 0, 15): 0.4}
    assert param.assigned(gt, CAMERA).tolist() == [False, True, True, False]
    x, y, z = (cell_values(param, target, c)[0, 6, 2].item() for c in ("x", "y", "z"))
    assert x == pytest.approx((18.5 / 8) % 1, abs=1e-6) and y == pytest.approx(
        (52.5 / 8) % 1, abs=1e-6
    )
    assert z == pytest.approx(0.4, abs=1e-6)


def test_vanilla_ties_go_to_the_first_object_and_clip_range_is_required():
    param = VanillaParameterization(BRACKET)
    gt = scene(
        [(20.0, 50.0, 1.0), (21.0, 50.0, 1.0), (60.0, 60.0, 1.6), (60.0, 80.0, 0.45)],
        [0.7, 0.7, 1.0, 1.0],
    )
    assert param.assigned(gt, CAMERA).tolist() == [True, False, False, False]


def test_eve_neighbours_within_border_including_diagonals():
    param = EVEParameterization(BRACKET, averaging=False)
    # origin at sub-cell offset (x, y) = (0.1, 0.5) of cell (4, 4): also the left neighbour
    gt = scene([(4 * 8 + 0.8 - 0.5, 4 * 8 + 4 - 0.5, 1.0)], [0.8])
    assert set(occupied(param, param.encode(gt, CAMERA))) == {(0, 4, 4), (0, 4, 3)}
    # offset (0.9, 0.05): right, up and the diagonal up-right
    gt = scene([(4 * 8 + 7.2 - 0.5, 4 * 8 + 0.4 - 0.5, 1.0)], [0.8])
    assert set(occupied(param, param.encode(gt, CAMERA))) == {
        (0, 4, 4),
        (0, 4, 5),
        (0, 3, 4),
        (0, 3, 5),
    }
    # centred: the origin cell only
    gt = scene([(4 * 8 + 4 - 0.5, 4 * 8 + 4 - 0.5, 1.0)], [0.8])
    assert set(occupied(param, param.encode(gt, CAMERA))) == {(0, 4, 4)}


def test_eve_never_overwrites_an_origin_cell_and_conflicts_go_to_visibility():
    param = EVEParameterization(BRACKET, averaging=False)
    a = (4 * 8 + 0.8 - 0.5, 4 * 8 + 4 - 0.5, 1.0)  # cell (4, 4), extends left into (4, 3)
    b = (3 * 8 + 4 - 0.5, 4 * 8 + 4 - 0.5, 1.0)  # origin of cell (4, 3), low visibility
    c = (2 * 8 + 7.5 - 0.5, 4 * 8 + 4 - 0.5, 1.0)  # cell (4, 2), extends right into (4, 3)
    got = occupied(param, param.encode(scene([a, b, c], [0.9, 0.2, 0.5]), CAMERA))
    assert got == {(0, 4, 4): 0.9, (0, 4, 3): 0.2, (0, 4, 2): 0.5}
    # without b, the extensions of a and c compete for (4, 3): the higher visibility wins
    got = occupied(param, param.encode(scene([a, c], [0.9, 0.5]), CAMERA))
    assert got == {(0, 4, 4): 0.9, (0, 4, 3): 0.9, (0, 4, 2): 0.5}


def test_eve_position_is_relative_to_the_enlarged_image():
    param = EVEParameterization(BRACKET, averaging=False)
    u, v = 40.0, 90.0
    target = param.encode(scene([(u, v, 1.0)], [1.0]), CAMERA)
    m = CAMERA.fx * BRACKET.diameter / CAMERA.clip_start
    row, col = int((v + 0.5) // 8), int((u + 0.5) // 8)
    assert cell_values(param, target, "x")[0, row, col].item() == pytest.approx(
        (u + m) / (128 + 2 * m), abs=1e-6
    )
    assert cell_values(param, target, "y")[0, row, col].item() == pytest.approx(
        (v + m) / (128 + 2 * m), abs=1e-6
    )


def test_ap_reference_points_follow_the_symmetry_class():
    shaft, zbracket = builtin_object("shaft"), builtin_object("zbracket")
    extent = {"placement": "extent"}  # the ends of the extent (opnet's earlier placement)
    np.testing.assert_allclose(
        APParameterization(shaft, **extent).points.numpy(), [[0, 0, 0.0425], [0, 0, -0.0425]], atol=1e-9
    )
    np.testing.assert_allclose(
        sorted(APParameterization(zbracket, **extent).points[:, 0].tolist()), [-0.025, 0.025], atol=1e-9
    )
    pts = APParameterization(BRACKET, **extent).points.numpy()
    assert pts.shape == (2, 3) and abs(pts[0] @ pts[1]) < 1e-9  # on two orthogonal principal axes
    # on the part (default): the revolution axis keeps its points, at 0.6 of the half extent
    np.testing.assert_allclose(APParameterization(shaft).points.numpy(), [[0, 0, 0.0255], [0, 0, -0.0255]], atol=1e-9)


@pytest.mark.parametrize("name", ["bracket", "zbracket", "shaft", "pin"])
def test_ap_default_points_lie_on_the_part_and_permute_under_its_symmetry(name):
    obj = builtin_object(name)
    pts = APParameterization(obj).points.numpy()
    outside = ~obj.mesh.contains(pts)
    _, surface_distance, _ = obj.mesh.nearest.on_surface(pts)
    assert (surface_distance[outside] < 1e-6).all()  # inside the part or on its surface
    # the extent placement leaves the part for these meshes (why on_part is the default)
    assert APParameterization(obj, placement="extent").points.numpy().tolist() != pts.tolist()
    for R in obj.symmetry.group():  # a symmetry step maps the point set onto itself
        moved = pts @ R.T
        assert np.abs(moved[:, None] - pts[None]).sum(-1).min(1).max() < 1e-9


def test_ap_assigns_objects_with_origin_outside_and_keeps_origin_cells():
    shaft = builtin_object("shaft")  # points ±0.0425 e_z
    param = APParameterization(shaft, points=[[0.3, 0.0, 0.0]], averaging=False)
    # object 0: origin left of the image, its point 0.3 m to the right (identity rotation) is inside
    # object 1: its origin cell is where object 2's point lands; object 2 has higher visibility
    z = 1.0
    shift = 0.3 * CAMERA.fx / z  # pixels
    gt = scene([(-10.0, 20.0, z), (70.0, 100.0, z), (70.0 - shift, 100.0, z)], [0.6, 0.3, 0.9])
    got = occupied(param, param.encode(gt, CAMERA))
    assert param.assigned(gt, CAMERA).tolist() == [True, True, True]
    r0, c0 = int((20 + 0.5) // 8), int((-10 + shift + 0.5) // 8)
    r1, c1 = int((100 + 0.5) // 8), int((70 + 0.5) // 8)
    assert got[(0, r0, c0)] == 0.6
    assert got[(0, r1, c1)] == 0.3  # origin of 1 not overwritten by the point of 2
    assert (
        len(got) == 4
    )  # 0: its point only (origin outside); 1: origin and point; 2: origin only (its point lost)


def test_z_puts_objects_of_one_cell_into_their_depth_slabs():
    param = ZParameterization(BRACKET)
    # same cell, depths 0.55 (slab 0), 1.03 (slab 8), 1.5 (far plane: last slab)
    gt = scene([(60.0, 60.0, 0.55), (61.0, 61.0, 1.03), (59.0, 59.0, 1.5)], [0.3, 0.5, 0.7])
    target = param.encode(gt, CAMERA)
    assert occupied(param, target) == {(0, 7, 7): 0.3, (8, 7, 7): 0.5, (15, 7, 7): 0.7}
    z = cell_values(param, target, "z")
    assert z[0, 7, 7].item() == pytest.approx(0.05 * 16 % 1, abs=1e-5)
    assert z[8, 7, 7].item() == pytest.approx(0.53 * 16 % 1, abs=1e-5)
    assert z[15, 7, 7].item() == pytest.approx(1.0, abs=1e-6)
    assert param.out_channels == 16 * 8


def test_mp_ranks_by_visibility_into_slots_and_drops_the_rest():
    param = MPParameterization(BRACKET)  # 8 x 8 grid: 16-pixel cells
    gt = scene(
        [
            (20.0, 20.0, 1.0),
            (22.0, 25.0, 0.8),
            (18.0, 17.0, 1.2),
            (25.0, 28.0, 1.1),
            (100.0, 5.0, 1.0),
        ],
        [0.5, 0.9, 0.7, 0.2, 0.6],
    )
    target = param.encode(gt, CAMERA)
    assert occupied(param, target) == {
        (0, 1, 1): 0.9,
        (1, 1, 1): 0.7,
        (2, 1, 1): 0.5,
        (0, 0, 6): 0.6,
    }
    assert param.assigned(gt, CAMERA).tolist() == [True, True, True, False, True]


def test_mp_decodes_a_slot_only_where_the_previous_slots_are_present():
    param = MPParameterization(BRACKET)
    gt = scene([(20.0, 20.0, 1.0), (22.0, 25.0, 0.8)], [0.5, 0.9])
    target = param.encode(gt, CAMERA)
    assert len(param.decode(target, CAMERA)[0]) == 2
    param.split_slots(target)[0, 0, 0, 1, 1] = 0.05  # slot 0 below tau: slot 1 is not read
    assert len(param.decode(target, CAMERA)[0]) == 0


def test_mp_conditional_presence_weight():
    param = MPParameterization(BRACKET, conditional_presence_loss=True)
    target = param.encode(scene([(20.0, 20.0, 1.0), (22.0, 25.0, 0.8)], [0.5, 0.9]), CAMERA)
    w = param.presence_weight(target)[0]
    assert (
        w[0].min() == 1
        and w[1].sum() == 1
        and w[1, 1, 1] == 1
        and w[2, 1, 1] == 1
        and w[2].sum() == 1
    )
    assert MPParameterization(BRACKET).presence_weight(target).min() == 1


def test_si_fills_every_cell_showing_the_instance():
    param = SIParameterization(
        BRACKET, averaging=False
    )  # 32 x 32 grid: 4-pixel cells, sampled at pixel 4i + 2
    seg = np.zeros((128, 128), dtype=np.int64)
    seg[0:8, 0:8] = 1  # cells (0..1, 0..1)
    seg[40:43, 40:43] = 2  # covers pixel (42, 42) only: cell (10, 10)
    seg[100:101, 100:128] = 2  # row 100 is never sampled
    seg[60:64, 60:64] = 7  # an id without ground truth: ignored
    gt = scene([(4.0, 4.0, 1.0), (41.0, 41.0, 1.0), (90.0, 90.0, 1.0)], [0.8, 0.3, 0.9], seg)
    target = param.encode(gt, CAMERA)
    assert occupied(param, target) == {
        (0, 0, 0): 0.8,
        (0, 0, 1): 0.8,
        (0, 1, 0): 0.8,
        (0, 1, 1): 0.8,
        (0, 10, 10): 0.3,
    }
    assert param.assigned(gt, CAMERA).tolist() == [True, True, False]
    assert param.pose_weighting == "linear"


def test_si_needs_a_segmentation():
    with pytest.raises(ValueError, match="segmentation"):
        SIParameterization(BRACKET).encode(scene([(4.0, 4.0, 1.0)], [0.8]), CAMERA)


def test_invalid_settings_are_rejected():
    with pytest.raises(ValueError, match="score"):
        VanillaParameterization(BRACKET, score="pv")
    with pytest.raises(ValueError, match="threshold"):
        VanillaParameterization(BRACKET, threshold=1.5)
    with pytest.raises(ValueError, match="border"):
        EVEParameterization(BRACKET, border=0.7)
    with pytest.raises(ValueError, match="points"):
        APParameterization(BRACKET, points=[[1.0, 2.0]])
    with pytest.raises(ValueError, match="ap placement must be one of"):
        APParameterization(BRACKET, placement="surface")
    with pytest.raises(ValueError, match="cameras"):
        VanillaParameterization(BRACKET).encode(scene([(4.0, 4.0, 1.0)], [0.8]), [CAMERA, CAMERA])


@pytest.mark.parametrize("cls", [VanillaParameterization, EVEParameterization, APParameterization])
def test_parts_below_the_target_visibility_are_no_target(cls):
    # object 0 barely visible in its own cell, object 1 hidden under object 2 in a shared cell
    gt = scene([(20.0, 50.0, 1.0), (100.0, 20.0, 1.1), (101.0, 21.0, 1.0)], [0.04, 0.02, 0.7])
    paper, dense = cls(BRACKET), cls(BRACKET, min_target_visibility=0.05)
    assert paper.assigned(gt, CAMERA).tolist() == [True, False, True]
    assert dense.assigned(gt, CAMERA).tolist() == [False, False, True]
    target = dense.encode(gt, CAMERA)
    assert set(occupied(dense, target).values()) == {0.7}  # every filled cell is object 2's
    with pytest.raises(ValueError, match="min_target_visibility"):
        cls(BRACKET, min_target_visibility=1.0)
