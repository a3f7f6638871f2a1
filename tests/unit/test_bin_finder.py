"""The bin finder (``data.roi=auto`` / ``auto:S``): a rendered wire basket, moved and turned under a tilted
camera among other things in the cell, is found within a few pixels; a frame without a bin is a one-line error."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from opnet.data.bin_finder import NoBinError, find_bin
from opnet.data.roi import FINDER_REVISION, crop_record, parse_roi, resolve_box, roi_tag
from opnet.datasets.record import SceneRecord
from opnet.geometry.camera import Camera
from opnet.synthesis.layout import BinGeometry, homogeneous, inverse_pose, rotation_about, tilted
from opnet.synthesis.rendering import SceneRenderer

# a Photoneo-like camera at a fifth of its pixels, 1.6 m over the basket floor, 20 degrees off vertical
CAM = Camera(480.0, 480.0, 205.3, 157.1, 412, 308, 1.3, 1.85)
BASKET = BinGeometry(0.3, 0.1, 0.002, inner_y=0.5, hole_size=0.012, hole_pitch=0.018)
T_WORLD_CAM = tilted(homogeneous(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 1.6])), 20.0, -30.0)
PLACEMENTS = [(0.0, 0.0, 0.0), (0.15, -0.1, 30.0), (-0.2, 0.12, 75.0), (0.05, 0.2, 140.0), (-0.12, -0.15, -50.0)]


def _frame(x: float, y: float, yaw_deg: float, distractor: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Depth of the basket standing 0.6 m above the ground (beyond the far plane) at (x, y) turned by yaw,
    with a bar of the cell's frame in the working volume; and the basket centre in the camera frame."""
    T_world_bin = homogeneous(rotation_about(np.array([0.0, 0.0, 1.0]), math.radians(yaw_deg)), np.array([x, y, 0.0]))
    T_cam_bin = inverse_pose(T_WORLD_CAM) @ T_world_bin
    statics = BASKET.mesh()
    renderer = SceneRenderer(trimesh.creation.box(extents=(0.01, 0.01, 0.01)), CAM, statics, ground_size=4.0,
                             ground_depth=0.6)  # fmt: skip
    bar = None
    if distractor:  # a bar of the cell 0.1 m above the floor level, fixed in the world, off to one side
        bar = trimesh.creation.box(extents=(0.04, 0.9, 0.04))
        bar.apply_transform(inverse_pose(T_world_bin) @ homogeneous(np.eye(3), np.array([0.45, 0.0, 0.1])))
    renderer.begin_cycle(T_cam_bin, bar, T_cam_bin)
    depth = renderer.render(np.zeros((0, 4, 4))).depth
    renderer.close()
    centre = (T_cam_bin @ np.array([0.0, 0.0, (BASKET.wall_height - BASKET.thickness) / 2, 1.0]))[:3]
    return depth, centre


@pytest.mark.parametrize(("x", "y", "yaw"), PLACEMENTS)
def test_auto_s_centres_its_metric_box_on_the_moved_and_turned_bin(x: float, y: float, yaw: float) -> None:
    depth, centre = _frame(x, y, yaw)
    found = find_bin(depth, CAM, 0.75)
    assert np.abs(found.centre[:2] - centre[:2]).max() < 0.015 and abs(found.centre[2] - centre[2]) < 0.04
    u, v = CAM.project(centre[None])[0]
    x0, y0, x1, y1 = found.box
    # within 5 pixels (1.2 % of the image width) of the bin's centre, along each axis where the box was not
    # moved back inside the image
    if x0 > 0 and x1 < CAM.width:
        assert abs((x0 + x1) / 2 - u) <= 5.0, (found.box, u)
    if y0 > 0 and y1 < CAM.height:
        assert abs((y0 + y1) / 2 - v) <= 5.0, (found.box, v)
    # a fixed metric size: 0.75 m at the bin centre's depth, whatever the placement
    assert x1 - x0 == pytest.approx(0.75 * CAM.fx / centre[2], rel=0.03)


@pytest.mark.parametrize(("x", "y", "yaw"), PLACEMENTS[:3])
def test_auto_boxes_the_bins_own_region_not_the_rest_of_the_cell(x: float, y: float, yaw: float) -> None:
    depth, centre = _frame(x, y, yaw)
    x0, y0, x1, y1 = resolve_box(parse_roi("auto"), depth, CAM)
    u, v = CAM.project(centre[None])[0]
    assert x0 < u < x1 and y0 < v < y1
    # the bar (fixed in the cell, 0.45 m off) is left out: the box is about the basket's size
    assert x1 - x0 < 1.35 * BASKET.outer * CAM.fx / centre[2] + 20


def test_a_frame_without_a_bin_is_a_one_line_error_naming_it() -> None:
    depth = np.full((CAM.height, CAM.width), 2.4, np.float32)  # only the ground, beyond the far plane
    record = SceneRecord("cycle_0003/007", depth, CAM, None, np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0),
                         np.zeros(0, np.int64), "plate")  # fmt: skip
    for roi in ("auto", "auto:0.75"):
        with pytest.raises(NoBinError, match=rf"^data.roi={roi}: cycle_0003/007: no bin found between the clip planes") as e:
            crop_record(record, parse_roi(roi))
        assert "\n" not in str(e.value)
    depth[:3, :3] = 1.5  # a few pixels of something are no bin either
    with pytest.raises(NoBinError, match="no bin found"):
        find_bin(depth, CAM, 0.75)


@pytest.mark.parametrize(("value", "expected"), [("auto:0.75", "auto:0.75"), ("auto: 1.50", "auto:1.5"), ("auto", "auto")])
def test_auto_values_parse_and_tag(value: str, expected: str) -> None:
    assert parse_roi(value) == expected
    assert roi_tag(parse_roi(value)) == "_roi" + expected.replace(":", "") + f"_f{FINDER_REVISION}"


@pytest.mark.parametrize("value", ["auto:", "auto:-1", "auto:nan", "auto:abc", "auto:100"])
def test_bad_auto_sizes_are_one_line_errors(value: str) -> None:
    with pytest.raises(ValueError, match=r"^data.roi=.*auto:S takes the side S of the box in metres"):
        parse_roi(value)


@pytest.mark.parametrize("roi", ["auto:1e-9", "auto:0.001", "auto:0.009"])
def test_an_auto_square_under_a_centimetre_is_refused_with_its_bounds(roi: str) -> None:
    """``auto:1e-9`` passed validation and ended in an OverflowError; ``auto:0.001`` ran 4x longer."""
    with pytest.raises(ValueError, match=rf"^data.roi='{roi}': auto:S takes .* in \[0.01, 20\]"):
        parse_roi(roi)


def test_an_auto_square_of_fewer_pixels_than_the_network_needs_is_refused_before_the_search() -> None:
    """3 cm at about 1.5 m are 10 pixels of this camera: less than a pixel per output cell; it was cropped."""
    depth, _ = _frame(0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match=r"^data.roi=auto:0.03: the 0.03 m square spans 9.\d pixels at the bin's "
                                         r"depth .*at least 16"):
        resolve_box(parse_roi("auto:0.03"), depth, CAM)
    assert resolve_box(parse_roi("auto:0.06"), depth, CAM)[2] > 0  # 19 pixels: taken


def _basket_and_far_plane() -> tuple[np.ndarray, np.ndarray, float, float]:
    """The basket alone (no bar), its centre, a depth just inside the far plane (where a floor reaching into
    the working volume lies) and the basket's outline, m^2."""
    depth, centre = _frame(0.0, 0.0, 0.0, distractor=False)
    footprint = math.prod(side + 2 * BASKET.thickness for side in BASKET.sides)
    return depth, centre, CAM.clip_end - 0.03, footprint


@pytest.mark.parametrize("share", [0.8, 0.95])
def test_a_perforated_basket_counts_by_its_outline_against_a_solid_surface_in_the_volume(share: float) -> None:
    # a floor or table reaching into the working volume at a corner of the frame (a tilted camera's far side),
    # solid, a little smaller than the basket's outline but larger than its bars: the basket is the bin
    depth, centre, z, footprint = _basket_and_far_plane()
    side = int(round(math.sqrt(share * footprint) * CAM.fx / z))
    depth[-side:, -side:] = z
    found = find_bin(depth, CAM, 0.75)
    assert np.abs(found.centre[:2] - centre[:2]).max() < 0.015
    # a solid surface clearly larger than the basket is what fills the volume most
    big = int(round(1.5 * side))
    depth[-big:, -big:] = z
    assert find_bin(depth, CAM, 0.75).centre[2] > centre[2] + 0.1


def test_a_surface_wider_than_the_crop_gives_way_to_the_basket_however_large() -> None:
    # the ground reaching into the working volume across the far side of the frame (a tilted camera), more
    # surface than the basket's outline: a bin fits in its crop (auto:S), a band wider than S is no bin
    depth, centre, z, footprint = _basket_and_far_plane()
    rows = int(math.ceil(2.0 * footprint / (CAM.width * z / CAM.fx) * CAM.fy / z))  # twice the outline's surface
    depth[:rows] = z
    assert rows * CAM.width * (z / CAM.fx) ** 2 > 1.9 * footprint and CAM.width * z / CAM.fx > 0.75
    found = find_bin(depth, CAM, 0.75)
    assert np.abs(found.centre[:2] - centre[:2]).max() < 0.015
    # without a basket the band is what there is (the largest region stays): found, not refused
    empty = np.full_like(depth, 2.4)
    empty[:rows] = z
    assert find_bin(empty, CAM, 0.75).centre[2] > centre[2] + 0.1


def test_of_a_basket_and_a_patch_of_floor_about_as_large_the_nearer_is_the_bin() -> None:
    # a compact patch of the floor at the far plane with a little more surface than the basket's outline (the
    # basket at the far side of a tilted camera): the bin stands above the floor, nearer the camera
    depth, centre, z, footprint = _basket_and_far_plane()
    side = int(round(math.sqrt(1.15 * footprint) * CAM.fx / z))
    depth[-side:, -side:] = z
    assert np.abs(find_bin(depth, CAM, 0.75).centre[:2] - centre[:2]).max() < 0.015
