"""Sim-to-real depth augmentation: determinism, range, order, intensity, sensor dropout, configs."""

from __future__ import annotations

import numpy as np
import pytest
from hydra.utils import instantiate
from hypothesis import given, settings
from hypothesis import strategies as st
from omegaconf import OmegaConf

from opnet.data.augment import DepthAugmenter
from opnet.data.preprocess import RESIZE_INTERPOLATIONS
from opnet.paths import config_dir

ALL_ON = {"p_elastic": 1.0, "p_blur": 1.0, "p_noise": 1.0, "p_dropout": 1.0}
ONLY = {"p_elastic": 0.0, "p_blur": 0.0, "p_noise": 0.0, "p_dropout": 0.0}


def _scene() -> np.ndarray:
    """A 128 x 128 bin-like depth image: a sloped floor with two nearer boxes."""
    _, u = np.mgrid[0:128, 0:128]
    image = (0.6 + 0.001 * u).astype(np.float32)
    image[30:60, 30:60] = 0.3
    image[80:100, 20:110] = 0.4
    return image


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), level=st.sampled_from([0.0, 0.5, 1.0, None]))
def test_output_is_float32_in_unit_range_without_nan(seed: int, level: float | None) -> None:
    image = _scene() if level is None else np.full((128, 128), level, np.float32)
    out = DepthAugmenter(**ALL_ON)(image, np.random.default_rng(seed))
    assert out.shape == image.shape and out.dtype == np.float32
    assert np.isfinite(out).all() and out.min() >= 0.0 and out.max() <= 1.0


def test_same_seed_same_output_other_seed_other_output() -> None:
    augment = DepthAugmenter(**ALL_ON)
    a = augment(_scene(), np.random.default_rng(7))
    b = augment(_scene(), np.random.default_rng(7))
    c = augment(_scene(), np.random.default_rng(8))
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_order_is_random_and_each_step_obeys_its_probability() -> None:
    augment = DepthAugmenter(**{**ALL_ON, "p_noise": 0.0})
    calls: list[str] = []
    for name in ("elastic", "blur", "noise", "dropout"):
        setattr(augment, name, lambda img, rng, name=name: (calls.append(name), img)[1])
    orders = set()
    for seed in range(40):
        calls.clear()
        augment(_scene(), np.random.default_rng(seed))
        assert sorted(calls) == ["blur", "dropout", "elastic"]
        orders.add(tuple(calls))
    assert len(orders) == 6  # every permutation of the three steps occurs


def test_intensity_varies_between_draws() -> None:
    augment = DepthAugmenter(**{**ONLY, "p_noise": 1.0}, noise_std=(0.001, 0.02))
    flat = np.full((128, 128), 0.5, np.float32)
    stds = [float((augment(flat, np.random.default_rng(s)) - 0.5).std()) for s in range(12)]
    assert max(stds) > 3 * min(stds)
    assert 0.0005 < min(stds) and max(stds) < 0.025


def test_elastic_displacement_stays_small() -> None:
    augment = DepthAugmenter(**{**ONLY, "p_elastic": 1.0})
    image = _scene()
    out = augment(image, np.random.default_rng(3))
    changed = np.abs(out - image) > 0.05  # only pixels near the box edges move between levels
    near_edges = np.zeros_like(changed)
    for box in ((slice(30, 60), slice(30, 60)), (slice(80, 100), slice(20, 110))):
        grown = tuple(slice(s.start - 6, s.stop + 6) for s in box)
        near_edges[grown] = True
    assert changed.any() and not (changed & ~near_edges).any()


def test_dropout_makes_holes_at_far_side_of_edges_and_refills_them() -> None:
    augment = DepthAugmenter(
        **{**ONLY, "p_dropout": 1.0}, dropout_rate=(0, 0), edge_dropout_rate=(1, 1)
    )
    image = np.full((32, 32), 0.8, np.float32)
    image[:, :16] = 0.2  # near half on the left, far half on the right
    out = augment(image, np.random.default_rng(0))
    np.testing.assert_array_equal(out[:, :16], image[:, :16])  # the near side keeps its depth
    assert (out[:, 16] < 0.8).all() and (out[:, 16] > 0.2).all()  # far edge dropped and re-filled
    np.testing.assert_array_equal(out[:, 17:], image[:, 17:])


def test_random_dropout_rate_is_respected() -> None:
    augment = DepthAugmenter(
        **{**ONLY, "p_dropout": 1.0}, dropout_rate=(0.1, 0.1), edge_dropout_rate=(0, 0)
    )
    _, u = np.mgrid[0:128, 0:128]
    image = (0.2 + 0.005 * u).astype(np.float32)  # a plane: re-filled holes are exact
    out = augment(image, np.random.default_rng(0))
    np.testing.assert_allclose(out, image, atol=1e-5)


def test_no_augmentation_is_identity() -> None:
    augment = DepthAugmenter(**ONLY)
    np.testing.assert_array_equal(augment(_scene(), np.random.default_rng(0)), _scene())


def test_draw_interpolation_uses_configured_names() -> None:
    augment = DepthAugmenter(resize_interpolations=["area", "cubic"])
    drawn = {augment.draw_interpolation(np.random.default_rng(s)) for s in range(30)}
    assert drawn == {RESIZE_INTERPOLATIONS["area"], RESIZE_INTERPOLATIONS["cubic"]}


@pytest.mark.parametrize(
    ("image", "match"),
    [
        (np.full((8, 8), np.nan, np.float32), "NaN"),
        (np.zeros((8, 8, 1), np.float32), r"\(H, W\)"),
        (np.zeros((8, 8), np.uint8), "float"),
    ],
)
def test_bad_images_raise(image: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        DepthAugmenter()(image, np.random.default_rng(0))


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"p_blur": 1.5}, "p_blur"),
        ({"noise_std": (0.02, 0.01)}, "noise_std"),
        ({"dropout_rate": (0.0, 2.0)}, "dropout_rate"),
        ({"motion_blur_size": (1, 3)}, "motion_blur_size"),
        ({"resize_interpolations": ["bilinear"]}, "resize_interpolations"),
        ({"elastic_sigma": 0.0}, "elastic_sigma"),
    ],
)
def test_bad_settings_raise(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        DepthAugmenter(**kwargs)


@pytest.mark.parametrize("name", ["default", "none"])
def test_augmentation_configs_instantiate(name: str) -> None:
    cfg = OmegaConf.load(config_dir() / "augmentation" / f"{name}.yaml")
    augment = instantiate(cfg)
    assert isinstance(augment, DepthAugmenter)
    out = augment(_scene(), np.random.default_rng(0))
    assert out.shape == (128, 128) and np.isfinite(out).all()
    if name == "none":
        np.testing.assert_array_equal(out, _scene())


def test_random_view_keeps_image_and_camera_consistent() -> None:
    """Zoom window and clip planes: a raised block appears where the new camera projects it, with
    the depth the new clip planes give; the scene's own pixels are not changed."""
    import cv2

    from opnet.data.sample import make_sample
    from opnet.datasets.record import SceneRecord
    from opnet.geometry import Camera

    cam = Camera.from_fov(50.0, 256, 256, 0.5, 1.5)
    depth = np.full((256, 256), 1.2, np.float32)
    depth[100:140, 150:190] = 0.9  # a block: its centre pixel (169.5, 119.5) at 0.9 m
    centre = np.array([(169.5 - cam.cx) * 0.9 / cam.fx, (119.5 - cam.cy) * 0.9 / cam.fy, 0.9])
    record = SceneRecord("s", depth, cam, R_cam_obj=np.eye(3)[None], t_cam_obj=centre[None],
                         visibility=np.ones(1), instance_id=np.ones(1, np.int64))  # fmt: skip
    views = DepthAugmenter(**ONLY, p_zoom=1.0, p_clip=1.0, zoom=(0.5, 0.8), clip_margin=(0.1, 0.5))
    plain = make_sample(record, 128, cv2.INTER_AREA)
    seen = 0
    for seed in range(5):
        s = make_sample(record, 128, cv2.INTER_AREA, views, np.random.default_rng(seed))
        c = s.camera
        assert c != plain.camera and c.fx > plain.camera.fx * 1.2  # zoomed in
        assert c.clip_start <= 0.9 - 0.1 - 1e-9 and c.clip_end >= 1.2 + 0.1 - 1e-9
        u, v = c.fx * centre[0] / centre[2] + c.cx, c.fy * centre[1] / centre[2] + c.cy
        expected = (0.9 - c.clip_start) / (c.clip_end - c.clip_start)
        if 3 <= u < 125 and 3 <= v < 125:
            assert s.image[0, int(round(v)), int(round(u))] == pytest.approx(expected, abs=1e-4)
            seen += 1
        np.testing.assert_allclose(s.t_cam_obj, centre[None], rtol=1e-6)
    assert seen >= 2
    with pytest.raises(ValueError, match="zoom"):
        DepthAugmenter(zoom=(0.5, 1.5))
