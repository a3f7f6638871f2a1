"""Scene settings and the dataset set-up: camera representable in parameter.json, bin in view, clip planes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from opnet.datasets.ipa_params import IPAParameters
from opnet.objects import builtin_object
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.cycle import cycle_rngs
from opnet.synthesis.layout import (
    BinGeometry,
    bin_fill,
    inverse_pose,
    make_rig,
    random_rotation,
    sample_layout,
)


@pytest.mark.parametrize(("resolution", "width", "height"), [(512, None, None), (300, 260, 200)])
def test_camera_is_exactly_what_parameter_json_describes(resolution: int, width: int | None, height: int | None) -> None:
    cfg = SceneConfig(resolution=resolution, width=width, height=height, fov_deg=47.5)
    rig = make_rig(builtin_object("bracket"), 20, 7, cfg)
    cam, p = rig.camera, rig.params
    assert (cam.width, cam.height) == cfg.image_size
    assert cam.fx == cam.fy == pytest.approx(resolution / (2 * math.tan(math.radians(47.5) / 2)), rel=1e-12)
    # a centred crop of the square canvas: principal point at the canvas centre (pixel-centre convention)
    assert (cam.cx, cam.cy) == (resolution / 2 - 0.5 - p.pixel_offset_x, resolution / 2 - 0.5 - p.pixel_offset_y)
    assert cam.cx == (cam.width - 1) / 2 and cam.cy == (cam.height - 1) / 2
    assert (p.number_cycles, p.shape_drop_limit) == (7, 20)
    again = IPAParameters.from_camera(cam, 7, 20, resolution_big=resolution).camera()
    assert again.cx == cam.cx and again.cy == cam.cy and again.fx == pytest.approx(cam.fx, rel=1e-12)


def test_the_whole_bin_is_in_view_and_inside_the_clip_planes() -> None:
    cfg = SceneConfig(resolution=256, camera_jitter_m=0.0, camera_jitter_deg=0.0, bin_jitter_m=0.0, bin_jitter_deg=0.0)
    rig = make_rig(builtin_object("shaft"), 15, 1, cfg)
    T_cam_world = inverse_pose(rig.T_world_cam)
    a, t, h = rig.bin.outer / 2, rig.bin.thickness, rig.bin.wall_height
    corners = np.array([[sx * a, sy * a, z] for sx in (-1, 1) for sy in (-1, 1) for z in (h, -t)])
    p = corners @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    uv = rig.camera.project(p)
    assert (uv >= 0).all() and (uv[:, 0] <= rig.camera.width - 1).all() and (uv[:, 1] <= rig.camera.height - 1).all()
    # the floor and the wall tops lie between the clip planes, with room for a part above the walls
    assert rig.camera.clip_start < p[:, 2].min() - 0.5 * builtin_object("shaft").diameter
    assert p[:, 2].max() < rig.camera.clip_end


def test_automatic_bin_grows_with_the_number_of_parts() -> None:
    obj = builtin_object("bracket")
    small, large = (make_rig(obj, n, 1, SceneConfig()).bin for n in (2, 60))
    assert small.inner == pytest.approx(2 * obj.diameter)  # room for one part to turn
    assert large.inner > small.inner and large.inner ** 2 >= 60 * 0.04 * 0.02 / 1.5
    assert make_rig(obj, 2, 1, SceneConfig(bin_inner=0.5, bin_wall_height=0.1)).bin == BinGeometry(0.5, 0.1, 0.01)


def test_bin_max_fill_widens_the_floor_of_a_bin_the_drops_would_overfill() -> None:
    """75 compact parts in 4 layers overfill walls of 1.5 D (their piles stand above the walls); with
    ``bin_max_fill`` the automatic floor widens until the parts' convex hulls fill that share, the
    walls (and so the pile's height) as they were; with a floor given, the walls rise instead."""
    obj = builtin_object("zbracket")
    bulk = {"bin_layers": 4.0, "bin_wall_factor": 1.5}
    plain = make_rig(obj, 75, 1, SceneConfig(**bulk)).bin
    hull = obj.mesh.convex_hull.volume
    assert bin_fill(obj, 75, plain) == pytest.approx(75 * hull / (plain.inner ** 2 * plain.wall_height))
    assert bin_fill(obj, 75, plain) > 0.3
    wider = make_rig(obj, 75, 1, SceneConfig(**bulk, bin_max_fill=0.3)).bin
    assert wider.wall_height == plain.wall_height and wider.inner > plain.inner and wider.inner_y is None
    assert bin_fill(obj, 75, wider) == pytest.approx(0.3)
    # a rectangular floor keeps its given side and widens the other
    oblong = make_rig(obj, 75, 1, SceneConfig(**bulk, bin_inner_y=0.2, bin_max_fill=0.3)).bin
    assert oblong.sides[1] == 0.2 and bin_fill(obj, 75, oblong) == pytest.approx(0.3)
    # a floor given: the walls rise until the share holds
    raised = make_rig(obj, 75, 1, SceneConfig(**bulk, bin_inner=plain.inner, bin_max_fill=0.3)).bin
    assert raised.inner == plain.inner and raised.wall_height > plain.wall_height
    assert bin_fill(obj, 75, raised) == pytest.approx(0.3)
    # already below the share: the bin as it was; floor and walls given: those
    assert make_rig(obj, 75, 1, SceneConfig(**bulk, bin_max_fill=0.99)).bin == plain
    given = make_rig(obj, 75, 1, SceneConfig(**bulk, bin_max_fill=0.3, bin_inner=0.2, bin_wall_height=0.05)).bin
    assert (given.inner, given.wall_height) == (0.2, 0.05)


def test_bin_boxes_bound_the_inner_volume() -> None:
    b = BinGeometry(0.3, 0.1, 0.02)
    mesh = b.mesh()
    np.testing.assert_allclose(mesh.bounds, [[-0.17, -0.17, -0.02], [0.17, 0.17, 0.1]])
    assert b.inside(np.array([[0.0, 0.0, 0.01], [0.149, -0.149, 0.05]])).all()
    assert not b.inside(np.array([[0.151, 0.0, 0.01], [0.0, 0.0, -0.01]])).any()


def test_a_rectangular_bin_bounds_its_own_sides() -> None:
    b = BinGeometry(0.3, 0.1, 0.02, inner_y=0.5)
    np.testing.assert_allclose(b.mesh().bounds, [[-0.17, -0.27, -0.02], [0.17, 0.27, 0.1]])
    assert b.outer == pytest.approx(0.54)
    assert b.inside(np.array([[0.149, 0.249, 0.05]])).all()
    assert not b.inside(np.array([[0.151, 0.0, 0.05], [0.0, 0.251, 0.05]])).any()
    rig = make_rig(builtin_object("pin"), 3, 1, SceneConfig(bin_inner=0.2, bin_inner_y=0.35, bin_wall_height=0.05))
    assert rig.bin.sides == (0.2, 0.35)


def test_a_perforated_bin_keeps_its_outline_and_opens_the_share_of_its_holes() -> None:
    hole, pitch = 0.012, 0.02
    solid, sheet = BinGeometry(0.3, 0.1, 0.002), BinGeometry(0.3, 0.1, 0.002, hole_size=hole, hole_pitch=pitch)
    np.testing.assert_allclose(sheet.mesh().bounds, solid.mesh().bounds, atol=1e-9)
    # looking down through the floor: rays at random points of the floor pass where the holes are
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.14, 0.14, (4000, 2))
    origins = np.column_stack([xy, np.full(len(xy), 0.05)])
    hits = sheet.mesh().ray.intersects_any(origins, np.tile([0.0, 0.0, -1.0], (len(xy), 1)))
    assert abs((1.0 - hits.mean()) - (hole / pitch) ** 2) < 0.04  # open share 0.36
    assert solid.mesh().ray.intersects_any(origins, np.tile([0.0, 0.0, -1.0], (len(xy), 1))).all()


@pytest.mark.parametrize("values, match", [
    ({"bin_hole_size": 0.02, "bin_hole_pitch": 0.015}, "bin_hole_pitch"),
    ({"bin_inner_y": -0.1}, "bin_inner_y"),
    ({"bin_clearance": -1.0}, "bin_clearance"),
])  # fmt: skip
def test_bad_bin_settings_name_the_key(values: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SceneConfig(**values)


def test_layout_jitter_is_bounded_and_seeded() -> None:
    cfg = SceneConfig(camera_jitter_m=0.004, camera_jitter_deg=2.0, bin_jitter_m=0.01, bin_jitter_deg=5.0)
    rig = make_rig(builtin_object("pin"), 5, 1, cfg)
    layouts = [sample_layout(rig, cfg, cycle_rngs(3, c)[0]) for c in range(20)]
    for lay in layouts:
        assert np.abs(lay.T_world_bin[:2, 3]).max() <= 0.01 and lay.T_world_bin[2, 3] == 0.0
        yaw = math.degrees(math.atan2(lay.T_world_bin[1, 0], lay.T_world_bin[0, 0]))
        assert abs(yaw) <= 5.0
        tilt = math.degrees(math.acos(np.clip(-lay.T_world_cam[2, 2], -1, 1)))  # optical axis vs straight down
        assert tilt <= 2.0 + 1e-9
    assert len({round(lay.T_world_bin[0, 3], 12) for lay in layouts}) == 20
    np.testing.assert_array_equal(sample_layout(rig, cfg, cycle_rngs(3, 4)[0]).T_world_cam, layouts[4].T_world_cam)


def test_random_rotations_are_uniform_enough() -> None:
    rng = np.random.default_rng(0)
    R = np.stack([random_rotation(rng) for _ in range(4000)])
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    # uniform on SO(3): every column is uniform on the sphere, E[R] = 0 and E[R_zz^2] = 1/3
    assert np.abs(R.mean(0)).max() < 0.05
    assert R[:, 2, 2].var() == pytest.approx(1 / 3, abs=0.03)


@pytest.mark.parametrize(
    ("values", "match"),
    [({"resolution": 4}, "resolution"), ({"collision": "mesh"}, "collision"), ({"fov_deg": 0}, "fov_deg"),
     ({"clip": [2.0, 1.0]}, "near below far"), ({"clip": "auto"}, "clip"), ({"clip": [0.5, 1.0, 2.0]}, "clip"),
     ({"clip": [0.5, "camera"]}, "without scene.camera_file"), ({"clip": [None, "camera"]}, "one of each"), ({"settle_checks": 0}, "settle_checks"),
     ({"bin_inner": -1.0}, "bin_inner"), ({"height": 511}, "height"),
     ({"bin_max_fill": 0.0}, "^scene config: bin_max_fill=0.0, expected null or a fraction"),
     ({"bin_max_fill": 1.5}, "bin_max_fill"),
     # bounds before anything is made: a micrometre perforation hung the generator, a 1000 km clearance passed,
     # a 100 m bin side was refused naming the written parameter.json instead of the key
     ({"bin_hole_size": 5e-7, "bin_hole_pitch": 1e-6}, "^scene config: bin_hole_size=5e-07, expected 0 .solid. or at least"),
     ({"bin_clearance": 1e6}, "^scene config: bin_clearance=1000000.0, expected at most 20 metres"),
     ({"bin_inner_y": 100.0}, "^scene config: bin_inner_y=100.0, expected at most 20 metres")],
)
def test_bad_scene_settings_name_the_key(values: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SceneConfig(**values)


@pytest.mark.parametrize(("values", "match"), [
    # booleans are no numbers (true passed as 1 m, 1 degree), text no TypeError, a size no fraction
    ({"bin_clearance": True}, r"^scene config: bin_clearance=True, expected a number$"),
    ({"bin_inner_y": True}, r"^scene config: bin_inner_y=True, expected a number$"),
    ({"bin_inner_y": "abc"}, r"^scene config: bin_inner_y='abc', expected a number$"),
    ({"camera_tilt_deg": True}, r"^scene config: camera_tilt_deg=True, expected a number$"),
    ({"camera_azimuth_deg": False}, r"^scene config: camera_azimuth_deg=False, expected a number$"),
    ({"bin_hole_size": True}, r"^scene config: bin_hole_size=True, expected a number$"),
    ({"bin_hole_pitch": True}, r"^scene config: bin_hole_pitch=True, expected a number$"),
    ({"resolution": 64.5}, r"^scene config: resolution=64.5, expected a whole number$"),
    ({"max_redrops": "many"}, r"^scene config: max_redrops='many', expected a whole number$"),
])  # fmt: skip
def test_scene_numbers_of_another_type_name_the_key(values: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        SceneConfig(**values)
    assert SceneConfig(resolution=64.0).resolution == 64 and type(SceneConfig(resolution=64.0).resolution) is int


def test_a_working_area_beyond_a_depth_cameras_range_is_refused_naming_it() -> None:
    """The automatic camera rises to see the whole area: a 200 m area put it 232 m up, and the generator wrote
    the dataset's first files before the written parameter.json was refused, naming itself."""
    with pytest.raises(ValueError, match=r"^scene config: bin_area=\[-100.0, -100.0, 100.0, 100.0\]: the camera 232 m "
                                         r"above the floor would need a far clip plane 239 m away, beyond a depth "
                                         r"camera's 50 m"):  # fmt: skip
        make_rig(builtin_object("zbracket"), 3, 1, SceneConfig(bin_area=(-100.0, -100.0, 100.0, 100.0)))
    assert make_rig(builtin_object("zbracket"), 3, 1, SceneConfig(bin_area=(-1.0, -1.0, 1.0, 1.0))).camera.clip_end < 50


def test_object_without_mesh_is_refused() -> None:
    from opnet.objects.model import ObjectModel

    obj = builtin_object("pin")
    meshless = ObjectModel(obj.name, obj.symmetry, obj.centroid, obj.covariance, obj.diameter, None)
    with pytest.raises(ValueError, match="no mesh"):
        make_rig(meshless, 3, 1, SceneConfig())
