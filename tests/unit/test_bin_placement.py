"""Bins that move: each pile's bin drawn over a working area of the floor, in a yaw range, tilted,
while the camera stays where the cell's camera is (``scene.bin_area``, ``bin_yaw_deg``, ``bin_tilt_deg``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from opnet.objects import builtin_object
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.layout import homogeneous, make_rig, rotation_about, sample_layout, view_layout

AREA = (-0.06, -0.03, 0.04, 0.05)
YAW = (-20.0, 70.0)


def _yaw_deg(T: np.ndarray) -> float:
    return math.degrees(math.atan2(T[1, 0], T[0, 0]))


def test_placements_cover_the_working_area_and_the_yaw_range_evenly() -> None:
    cfg = SceneConfig(resolution=128, bin_area=AREA, bin_yaw_deg=YAW, camera_jitter_m=0.0, camera_jitter_deg=0.0)
    rig = make_rig(builtin_object("zbracket"), 6, 1, cfg)
    rng = np.random.default_rng(3)
    layouts = [sample_layout(rig, cfg, rng) for _ in range(4000)]
    xy = np.array([L.T_world_bin[:2, 3] for L in layouts])
    yaw = np.array([_yaw_deg(L.T_world_bin) for L in layouts])
    x0, y0, x1, y1 = AREA
    assert (xy[:, 0] >= x0).all() and (xy[:, 0] <= x1).all() and (xy[:, 1] >= y0).all() and (xy[:, 1] <= y1).all()
    # a 4 x 4 histogram of the placements: every cell holds its share (1/16) within 25 %
    hist, _, _ = np.histogram2d(xy[:, 0], xy[:, 1], bins=4, range=[[x0, x1], [y0, y1]])
    assert hist.min() > 0.75 * 4000 / 16 and hist.max() < 1.25 * 4000 / 16, hist
    counts, _ = np.histogram(yaw, bins=6, range=YAW)
    assert (yaw >= YAW[0] - 1e-9).all() and (yaw <= YAW[1] + 1e-9).all()
    assert counts.min() > 0.8 * 4000 / 6 and counts.max() < 1.2 * 4000 / 6, counts
    # level bins: no tilt, on the ground; the camera never moves with the bin
    assert all(np.allclose(L.T_world_bin[2], [0, 0, 1, 0]) for L in layouts)
    assert all(np.allclose(L.T_world_cam, rig.T_world_cam) for L in layouts)


def test_the_old_jitter_draws_are_unchanged_without_an_area() -> None:
    """Datasets made before the working area keep their bytes: the same draws, the same poses."""
    cfg = SceneConfig(resolution=128, bin_jitter_m=0.02, bin_jitter_deg=30.0)
    rig = make_rig(builtin_object("zbracket"), 6, 1, cfg)
    got = sample_layout(rig, cfg, np.random.default_rng(11))
    rng = np.random.default_rng(11)  # the formula of the first generator
    dx, dy = rng.uniform(-1.0, 1.0, 2) * 0.02
    yaw = math.radians(30.0) * rng.uniform(-1.0, 1.0)
    T_bin = homogeneous(rotation_about(np.array([0.0, 0.0, 1.0]), yaw), np.array([dx, dy, 0.0]))
    axis, angle = rng.standard_normal(3), math.radians(1.0) * rng.uniform(0.0, 1.0)
    T_jitter = homogeneous(rotation_about(axis, angle), rng.uniform(-1.0, 1.0, 3) * 0.005)
    assert np.array_equal(got.T_world_bin, T_bin) and np.array_equal(got.T_world_cam, T_jitter @ rig.T_world_cam)
    assert got.T_world_ground is None


def test_tilted_bins_stay_above_the_ground_and_the_ground_stays_level() -> None:
    cfg = SceneConfig(resolution=128, bin_area=AREA, bin_tilt_deg=6.0)
    rig = make_rig(builtin_object("zbracket"), 6, 1, cfg)
    rng = np.random.default_rng(5)
    tilts = []
    hx, hy = (s / 2 + rig.bin.thickness for s in rig.bin.sides)
    under = np.array([[x, y, -rig.bin.thickness, 1.0] for x in (-hx, hx) for y in (-hy, hy)])
    for _ in range(500):
        L = sample_layout(rig, cfg, rng)
        tilts.append(math.degrees(math.acos(np.clip(L.T_world_bin[2, 2], -1, 1))))
        low = (under @ L.T_world_bin.T)[:, 2]
        assert low.min() >= -rig.bin.thickness - 1e-9 and low.min() <= -rig.bin.thickness + 1e-9  # touches, not below
        assert np.allclose(L.T_world_ground[2], [0, 0, 1, 0])  # the ground: level, at the bin's place
        assert np.allclose(L.T_world_ground[:2, 3], L.T_world_bin[:2, 3], atol=0.02)
        view = view_layout(rig, cfg, L, rng)  # another view of the pile: the ground still level
        assert np.allclose(np.linalg.inv(view.T_world_cam) @ view.T_world_ground,
                           np.linalg.inv(view.T_world_cam) @ view.T_world_bin @ view.T_bin_ground)
    assert max(tilts) <= 6.0 + 1e-9 and np.percentile(tilts, 90) > 4.5


def test_the_automatic_camera_sees_the_bin_anywhere_in_the_area() -> None:
    cfg = SceneConfig(resolution=256, bin_area=(-0.1, -0.1, 0.1, 0.1), bin_yaw_deg=(0.0, 90.0), camera_jitter_m=0.0,
                      camera_jitter_deg=0.0)  # fmt: skip
    rig = make_rig(builtin_object("zbracket"), 6, 1, cfg)
    T_cam_world = np.linalg.inv(rig.T_world_cam)
    rng = np.random.default_rng(0)
    a, b = (s / 2 + rig.bin.thickness for s in rig.bin.sides)
    rim = np.array([[x, y, rig.bin.wall_height, 1.0] for x in (-a, a) for y in (-b, b)])
    for _ in range(200):
        L = sample_layout(rig, cfg, rng)
        p = (rim @ (T_cam_world @ L.T_world_bin).T)[:, :3]
        uv = rig.camera.project(p)
        assert (uv >= -0.5).all() and (uv <= rig.camera.width - 0.5).all()
        assert (p[:, 2] > rig.camera.clip_start).all()


@pytest.mark.parametrize(("values", "match"), [
    ({"bin_area": (-3.0, -3.0, 3.0, 3.0)}, r"^scene config: bin_area=\[-3.0, -3.0, 3.0, 3.0\]: its corner \(-3, -3\) m lies "
                                            r"outside the camera's view"),
    ({"bin_area": (0.1, 0.0, -0.1, 0.1)}, r"^scene config: bin_area=.*x0 <= x1"),
    ({"bin_area": (0.0, 0.0, 0.1)}, r"^scene config: bin_area="),
    ({"bin_area": (0.0, 0.0, 0.1, math.nan)}, r"^scene config: bin_area="),
    ({"bin_yaw_deg": (30.0, 10.0)}, r"^scene config: bin_yaw_deg=.*the yaw range is empty"),
    ({"bin_yaw_deg": (0.0, 720.0)}, r"^scene config: bin_yaw_deg=.*at most 360"),
    ({"bin_yaw_deg": (True, 5.0)}, r"^scene config: bin_yaw_deg="),
    ({"bin_tilt_deg": 40.0}, r"^scene config: bin_tilt_deg=40.0"),
    ({"bin_tilt_deg": True}, r"^scene config: bin_tilt_deg=True"),
])  # fmt: skip
def test_bad_placement_settings_are_one_line_naming_the_key(values: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match) as info:
        make_rig(builtin_object("zbracket"), 6, 1, SceneConfig(resolution=128, camera_height=0.3, **values))
    assert "\n" not in str(info.value)


def test_placement_settings_round_trip_through_the_generation_record() -> None:
    cfg = SceneConfig(bin_area=[-0.1, 0.0, 0.1, 0.2], bin_yaw_deg=[0, 90], bin_tilt_deg=3)
    d = cfg.to_dict()
    assert d["bin_area"] == [-0.1, 0.0, 0.1, 0.2] and d["bin_yaw_deg"] == [0.0, 90.0]
    assert SceneConfig.from_dict(d) == cfg
    assert not {"bin_area", "bin_yaw_deg", "bin_tilt_deg"} & set(SceneConfig().to_dict())


def test_a_generated_dataset_writes_each_piles_bin_where_the_area_and_yaw_put_it(tmp_path) -> None:
    """Real physics and rendering: the bin pose of every written scene (row 0 of its ground truth) lies in
    the area and the yaw range, as seen by the cell's unmoved camera; its depth shows the bin there."""
    from conftest import small_builtin_dataset

    from opnet.datasets.ipa_csv import read_ipa_csv
    from opnet.datasets.ipa import scene_paths

    area, yaw = (-0.04, -0.02, 0.05, 0.03), (10.0, 80.0)
    root = small_builtin_dataset(tmp_path / "moved", "zbracket", 6, 2, 0, bin_area=area, bin_yaw_deg=yaw,
                                 bin_tilt_deg=4.0, camera_jitter_m=0.0, camera_jitter_deg=0.0)  # fmt: skip
    cfg = SceneConfig(resolution=128, bin_area=area, bin_yaw_deg=yaw, bin_tilt_deg=4.0)
    T_world_cam = make_rig(builtin_object("zbracket"), 2, 6, cfg).T_world_cam
    centres = []
    for cycle in range(6):
        gt = read_ipa_csv(scene_paths(root, cycle, 2)["csv"])
        T_cam_bin = homogeneous(gt.R_cam_bin, gt.t_cam_bin)
        T_world_bin = T_world_cam @ T_cam_bin
        x, y = T_world_bin[:2, 3]
        assert area[0] - 1e-3 <= x <= area[2] + 1e-3 and area[1] - 1e-3 <= y <= area[3] + 1e-3
        tilt = math.degrees(math.acos(np.clip(T_world_bin[2, 2], -1, 1)))
        assert tilt <= 4.0 + 1e-6
        # yaw of the bin's x axis projected on the ground
        assert yaw[0] - tilt - 1e-6 <= _yaw_deg(T_world_bin) <= yaw[1] + tilt + 1e-6
        centres.append((x, y))
    assert np.ptp(np.array(centres), axis=0).min() > 0.01  # the bin really moves from pile to pile


def test_the_cell_experiment_composes_into_moving_bin_scenes_and_a_bin_finder_roi(tmp_path) -> None:
    from conftest import compose_cfg

    from opnet.data.roi import parse_roi

    camera = tmp_path / "camera.yaml"
    camera.write_text("fx: 600\nfy: 600\ncx: 319.5\ncy: 239.5\nwidth: 640\nheight: 480\nclip_start: 1.2\nclip_end: 1.8\n")
    cfg = compose_cfg("train", ["experiment=cell", "object=zbracket", f"scene.camera_file={camera}",
                                "scene.camera_height=1.5", "scene.camera_tilt_deg=0", "scene.camera_azimuth_deg=0",
                                "scene.clip=[1.2,1.8]", "scene.bin_area=[-0.2,-0.2,0.2,0.2]",
                                "scene.bin_inner=0.3", "scene.bin_inner_y=0.4", "scene.bin_wall_height=0.1",
                                "scene.bin_wall_thickness=0.005", "scene.bin_clearance=0", "data.roi=auto:0.6"])  # fmt: skip
    scene = SceneConfig.from_dict(dict(cfg.data.generate.scene))
    assert scene.bin_area == (-0.2, -0.2, 0.2, 0.2) and scene.yaw_range_deg == (-180.0, 180.0)
    assert scene.clip == (1.2, 1.8) and scene.outside_clip == "clamp"
    assert parse_roi(cfg.data.roi) == "auto:0.6"
    rig = make_rig(builtin_object("zbracket"), 10, 2, scene)  # the area is in the camera's view
    assert (rig.camera.clip_start, rig.camera.clip_end) == (1.2, 1.8)
