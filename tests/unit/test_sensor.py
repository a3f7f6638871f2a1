"""The depth-sensor model (opnet.synthesis.sensor): geometry of shadows, noise law, quantization,
edges, grazing dropout, determinism, presets and config errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import compose_cfg
from opnet.geometry.camera import Camera
from opnet.synthesis.sensor import SensorModel, projector_shadow, sensor_rng

CAM = Camera(fx=100.0, fy=100.0, cx=49.5, cy=29.5, width=100, height=60, clip_start=0.5, clip_end=1.5)


def _step_scene() -> np.ndarray:
    """A plane at 1 m with a box top at 0.8 m over columns 40..59 (all rows)."""
    z = np.full((60, 100), 1.0)
    z[:, 40:60] = 0.8
    return z


def test_ideal_sensor_returns_the_depth_and_draws_nothing() -> None:
    z = _step_scene().astype(np.float32)
    z[0, 0] = np.nan
    rng = np.random.default_rng(0)
    state = rng.bit_generator.state
    out = SensorModel().apply(z, CAM, rng)
    assert np.array_equal(out, z, equal_nan=True)
    assert rng.bit_generator.state == state
    assert SensorModel(name="whatever").is_ideal and not SensorModel(baseline_m=0.05).is_ideal


def test_projector_shadow_lies_on_the_far_side_with_the_analytic_width() -> None:
    # projector b to +x: the box's edge (the left side of pixel 40, u = 39.5, z 0.8) lies at projector
    # column 39.5 - fx b / 0.8; plane pixels (z 1.0) whose column u - fx b / 1.0 falls beyond it are in
    # shadow: the pixel centres in [39.5 - w, 39.5), w = fx b (1 / 0.8 - 1 / 1.0)
    for baseline in (0.1, 0.2, 0.3, 0.4):
        shadow = projector_shadow(_step_scene(), CAM.fx, baseline)
        width = CAM.fx * baseline * (1 / 0.8 - 1 / 1.0)
        expected = [u for u in range(40) if 39.5 - width <= u]
        assert np.flatnonzero(shadow.any(axis=0)).tolist() == expected, baseline
        assert shadow[:, expected].all() and not shadow[:, 40:].any()  # whole columns; the box is lit


def test_projector_lights_the_ground_through_a_perforated_sheet() -> None:
    # a sheet at 0.8 m with 6-pixel holes every 12 pixels over a ground at 1.2 m: the camera sees the
    # ground through the holes; the projector (b = 0.1 m) lights it where its own ray passes a hole
    z = np.full((10, 400), 0.8)
    holes = (np.arange(400) % 12) < 6
    z[:, holes] = 1.2
    shadow = projector_shadow(z, CAM.fx, 0.1)
    assert not shadow[:, ~holes].any()  # the sheet is lit
    # ground pixel u is lit iff no sheet pixel's footprint covers its projector column u - fx b / 1.2;
    # sheet pixel u' covers u' - fx b / 0.8 +- 0.5, so the one over u is u' = round(u + 4.17) = u + 4
    u = np.flatnonzero(holes)[5:-5]
    assert CAM.fx * 0.1 * (1 / 0.8 - 1 / 1.2) == pytest.approx(4.1667, abs=1e-4)
    assert np.array_equal(~shadow[:, u], np.broadcast_to(holes[u + 4], (10, len(u))))
    assert 0.2 < (~shadow[0, u]).mean() < 0.8  # some of the ground is lit, some is not
    # where the sheet ends (ground left of u = 100), only the band beside its edge is in shadow:
    # the ground pixels whose column u - 8.33 reaches the sheet's footprint, 100 - 12.5 - 0.5
    edge = np.full((10, 400), 0.8)
    edge[:, :100] = 1.2
    assert np.flatnonzero(projector_shadow(edge, CAM.fx, 0.1).any(axis=0)).tolist() == [96, 97, 98, 99]


def test_axial_noise_follows_the_nguyen_law() -> None:
    z = np.full((400, 400), 1.0)
    cam = Camera(fx=400.0, fy=400.0, cx=199.5, cy=199.5, width=400, height=400, clip_start=0.5, clip_end=1.5)
    s = SensorModel(name="n", noise_a_m=0.002, noise_b_m=0.004, noise_z0_m=0.5)
    out = s.apply(z, cam, np.random.default_rng(1))
    expected = 0.002 + 0.004 * 0.5**2  # 3 mm
    assert abs(np.std(out - 1.0) / expected - 1.0) < 0.02
    assert abs(np.mean(out - 1.0)) < 1e-4


def test_disparity_quantization_gives_levels_fb_over_kq() -> None:
    z = np.linspace(0.9, 1.1, 100)[None, :].repeat(60, axis=0)
    s = SensorModel(name="q", baseline_m=0.1, disparity_step_px=0.5)
    out = s.apply(z, CAM, np.random.default_rng(0)).astype(np.float64)
    k = CAM.fx * 0.1 / (out * 0.5)
    assert np.allclose(k, np.rint(k), atol=1e-3)  # every depth is fb / (k q)
    assert len(np.unique(np.rint(k))) == len(np.unique(np.rint(CAM.fx * 0.1 / (z * 0.5))))


def test_far_side_of_depth_edges_loses_the_band_width() -> None:
    s = SensorModel(name="e", edge_missing_px=2, edge_jump_m=0.05)
    out = s.apply(_step_scene(), CAM, np.random.default_rng(0))
    missing_cols = np.flatnonzero(np.isnan(out).all(axis=0)).tolist()
    assert missing_cols == [38, 39, 60, 61]  # two plane pixels beside the box on each side, the box keeps its own


def test_mixed_pixels_lie_between_the_two_surfaces() -> None:
    s = SensorModel(name="m", mixed_pixel_prob=1.0, edge_jump_m=0.05)
    out = s.apply(_step_scene(), CAM, np.random.default_rng(0))
    edge = out[:, [39, 40, 59, 60]]
    assert np.all((edge >= 0.8 - 1e-6) & (edge <= 1.0 + 1e-6))
    assert np.mean((edge > 0.81) & (edge < 0.99)) > 0.8  # alpha ~ U(0, 1): 90 % expected
    assert np.array_equal(out[:, :38], _step_scene()[:, :38].astype(np.float32))  # flat parts untouched


def test_grazing_dropout_ramps_with_the_incidence_angle() -> None:
    cam = Camera(fx=200.0, fy=200.0, cx=99.5, cy=99.5, width=200, height=200, clip_start=0.1, clip_end=50)
    s = SensorModel(name="g", grazing_start_deg=40.0, grazing_end_deg=80.0)
    for tilt, expected in ((20.0, 0.0), (60.0, 0.5), (85.0, 1.0)):
        # the plane through (0, 0, 1) with normal (sin t, 0, cos t): z = 1 / (1 + x tan t), x = (u - cx) / fx
        u = (np.arange(200) - cam.cx) / cam.fx
        z = np.tile(1.0 / (1.0 + u * math.tan(math.radians(tilt))), (200, 1))
        z = np.where(z > 0, z, np.nan)
        centre = s.apply(z, cam, np.random.default_rng(0))[:, 95:105]
        # near the image centre the viewing ray is the optical axis: incidence = tilt
        assert abs(np.isnan(centre).mean() - expected) < 0.12, tilt


def test_same_scene_seed_same_output_other_scene_other_noise() -> None:
    s = SensorModel(name="d", noise_a_m=0.001, dropout_rate=0.1, lateral_px=0.7)
    a = s.apply(_step_scene(), CAM, sensor_rng(0, 3, 5))
    b = s.apply(_step_scene(), CAM, sensor_rng(0, 3, 5))
    c = s.apply(_step_scene(), CAM, sensor_rng(0, 3, 6))
    assert np.array_equal(a, b, equal_nan=True) and not np.array_equal(a, c, equal_nan=True)


@pytest.mark.parametrize("preset", ["ideal", "structured_light", "tof"])
def test_every_preset_builds_and_damages_a_pile_moderately(preset: str) -> None:
    cfg = compose_cfg("generate", [f"sensor={preset}"])
    from omegaconf import OmegaConf

    s = SensorModel.from_dict(OmegaConf.to_container(cfg.sensor, resolve=True))
    assert s.name == preset and s.is_ideal == (preset == "ideal")
    rng = np.random.default_rng(0)
    z = 0.7 + 0.05 * np.round(rng.random((12, 20)), 0).repeat(5, 0).repeat(5, 1)  # blocks 5 cm tall
    out = s.apply(z, CAM, sensor_rng(0, 0, 1))
    missing = np.isnan(out).mean()
    assert (missing == 0) if preset == "ideal" else (0.005 < missing < 0.6), missing
    assert 0.7 - 0.04 < np.nanmin(out) and np.nanmax(out) < 0.75 + 0.04  # between the surfaces, noise and steps aside


@pytest.mark.parametrize(("values", "message"), [
    ({"baseline_m": -0.1}, "sensor.baseline_m=-0.1"),
    ({"dropout_rate": 1.5}, "sensor.dropout_rate=1.5"),
    ({"grazing_start_deg": 80, "grazing_end_deg": 70}, "sensor.grazing_end_deg=70"),
    ({"disparity_step_px": 0.125}, "sensor.disparity_step_px=0.125"),
    ({"noise_a_m": float("nan")}, "sensor.noise_a_m=nan"),
    ({"baseline": 0.1}, "unknown keys ['baseline']"),
])
def test_bad_sensor_settings_name_the_key(values: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        SensorModel.from_dict(values)
