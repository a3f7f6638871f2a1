"""Network input preprocessing: missing-depth fill, square canvas + resize + camera, segmentation."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from opnet.data.preprocess import (
    RESIZE_INTERPOLATIONS,
    fill_missing_depth,
    network_camera,
    resize_depth,
    resize_segmentation,
    square_canvas,
    to_network_input,
)
from opnet.geometry import Camera

SILEANE = Camera(1152.31, 1152.31, 139.459, 237.001, 506, 474, 0.87599, 1.70602)


# --- fill_missing_depth -------------------------------------------------------------------------


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    shape=st.tuples(st.integers(1, 40), st.integers(1, 40)),
    missing=st.floats(0.0, 0.95),
)
def test_fill_keeps_valid_pixels_and_stays_within_their_range(
    seed: int, shape: tuple[int, int], missing: float
) -> None:
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.5, 1.5, shape).astype(np.float32)
    depth[rng.random(shape) < missing] = np.nan
    valid = ~np.isnan(depth)
    if not valid.any():
        depth[0, 0] = 1.0
        valid[0, 0] = True
    out = fill_missing_depth(depth)
    assert out.dtype == np.float32 and out.shape == shape
    assert not np.isnan(out).any()
    np.testing.assert_array_equal(out[valid], depth[valid])
    # interpolation and constant extrapolation are convex combinations of valid values
    assert out.min() >= depth[valid].min() - 1e-6 and out.max() <= depth[valid].max() + 1e-6


def test_fill_is_linear_between_two_valid_pixels_on_a_line() -> None:
    row = np.full((1, 11), np.nan, np.float32)
    row[0, 2], row[0, 8] = 1.0, 4.0
    out = fill_missing_depth(row)[0]
    np.testing.assert_allclose(out[2:9], np.linspace(1.0, 4.0, 7), rtol=1e-6)
    np.testing.assert_allclose(out[:2], 1.0)  # constant beyond the last valid pixel
    np.testing.assert_allclose(out[9:], 4.0)


def test_fill_reproduces_a_plane_with_interior_holes() -> None:
    v, u = np.mgrid[0:64, 0:80]
    plane = (0.7 + 0.003 * u - 0.002 * v).astype(np.float32)
    holed = plane.copy()
    holed[10:30, 20:50] = np.nan  # a big hole
    holed[40:44, 5:75] = np.nan  # a wide slit
    holed[np.random.default_rng(0).random(plane.shape) < 0.2] = np.nan
    holed[0], holed[-1], holed[:, 0], holed[:, -1] = plane[0], plane[-1], plane[:, 0], plane[:, -1]
    np.testing.assert_allclose(fill_missing_depth(holed), plane, atol=1e-5)


def test_fill_of_rows_and_columns_without_valid_pixels() -> None:
    depth = np.full((5, 6), np.nan, np.float32)
    depth[2, 3] = 0.25  # its row and column are filled first, then everything else
    np.testing.assert_allclose(fill_missing_depth(depth), 0.25)


def test_fill_all_missing_uses_fill_value_or_raises() -> None:
    depth = np.full((4, 4), np.nan, np.float32)
    np.testing.assert_array_equal(fill_missing_depth(depth, fill_value=1.0), 1.0)
    with pytest.raises(ValueError, match="fill_value"):
        fill_missing_depth(depth)


@pytest.mark.parametrize(
    ("depth", "match"),
    [
        (np.ones((4, 4), np.uint16), "float dtype"),
        (np.ones((4, 4, 1), np.float32), r"\(H, W\)"),
        (np.array([[1.0, np.inf]], np.float32), "infinite"),
        (np.zeros((0, 3), np.float32), "non-empty"),
        ([[1.0, 2.0]], "numpy array"),
    ],
)
def test_fill_rejects_bad_depth(depth: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        fill_missing_depth(depth)


# --- to_network_input ---------------------------------------------------------------------------


@st.composite
def camera_and_pixel(draw: st.DrawFn) -> tuple[Camera, str, float, float]:
    width, height = draw(st.integers(60, 320)), draw(st.integers(60, 320))
    cx = draw(st.floats(0.2, 0.8)) * (width - 1)
    cy = draw(st.floats(0.2, 0.8)) * (height - 1)
    fx = draw(st.floats(80.0, 600.0))
    camera = Camera(fx, fx * draw(st.floats(0.9, 1.1)), cx, cy, width, height, 0.5, 1.5)
    fit = draw(st.sampled_from(["pad", "crop"]))
    x0, y0, side = square_canvas(camera, fit)
    margin = 2.0 * side / 128 + 3
    lo_u, hi_u = max(x0, 0) + margin, min(x0 + side, width) - 1 - margin
    lo_v, hi_v = max(y0, 0) + margin, min(y0 + side, height) - 1 - margin
    u = draw(st.floats(0.0, 1.0)) * (hi_u - lo_u) + lo_u
    v = draw(st.floats(0.0, 1.0)) * (hi_v - lo_v) + lo_v
    return camera, fit, u, v


@settings(max_examples=60, deadline=None)
@given(
    sample=camera_and_pixel(),
    z=st.floats(0.6, 1.2),
    name=st.sampled_from(list(RESIZE_INTERPOLATIONS)),
)
def test_projection_with_returned_camera_lands_on_the_same_content(
    sample: tuple[Camera, str, float, float], z: float, name: str
) -> None:
    camera, fit, u, v = sample
    side = square_canvas(camera, fit)[2]
    ui, vi = round(u), round(v)
    point = camera.backproject(float(ui), float(vi), z)  # the 3D point behind the patch centre
    r = math.ceil(1.5 * side / 128)  # the patch spans about 3 input pixels
    depth = np.full((camera.height, camera.width), 1.4, np.float32)
    depth[vi - r : vi + r + 1, ui - r : ui + r + 1] = z
    image, cam_in = to_network_input(depth, camera, 128, RESIZE_INTERPOLATIONS[name], fit=fit)
    assert cam_in == network_camera(camera, 128, fit)
    assert (cam_in.width, cam_in.height) == (128, 128)
    patch = image < camera.normalize_depth((z + 1.4) / 2)
    rows, cols = np.nonzero(patch)
    expected = cam_in.project(np.asarray(point))
    assert abs(cols.mean() - expected[0]) <= 1.0 and abs(rows.mean() - expected[1]) <= 1.0


@pytest.mark.parametrize("name", list(RESIZE_INTERPOLATIONS))
def test_network_input_is_a_filled_normalized_image(name: str) -> None:
    rng = np.random.default_rng(1)
    depth = rng.uniform(0.8, 1.8, (SILEANE.height, SILEANE.width)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.3] = np.nan
    depth[100:200, 300:400] = np.nan
    image, camera = to_network_input(depth, SILEANE, 128, RESIZE_INTERPOLATIONS[name])
    assert image.shape == (128, 128) and image.dtype == np.float32
    assert not np.isnan(image).any() and image.min() >= 0.0 and image.max() <= 1.0
    assert camera.width == camera.height == 128


def test_square_canvas_is_centred_on_the_principal_point() -> None:
    x0, y0, side = square_canvas(SILEANE, "pad")
    assert x0 <= 0 and y0 <= 0 and x0 + side >= SILEANE.width and y0 + side >= SILEANE.height
    assert (
        abs(x0 + (side - 1) / 2 - SILEANE.cx) <= 0.5
        and abs(y0 + (side - 1) / 2 - SILEANE.cy) <= 0.5
    )
    x0, y0, side = square_canvas(SILEANE, "crop")
    assert x0 >= 0 and y0 >= 0 and x0 + side <= SILEANE.width and y0 + side <= SILEANE.height
    # an IPA-like crop at (40, 60) of a 512 canvas centred on c = 255.5: the smallest centred
    # square holding the crop, 216 px to the principal point's left -> side 432, same centre
    ipa = Camera(500.0, 500.0, 255.5 - 40, 255.5 - 60, 400, 380, 0.5, 1.5)
    assert square_canvas(ipa, "pad") == (0, -20, 432)


def test_all_missing_depth_gives_the_far_plane() -> None:
    depth = np.full((SILEANE.height, SILEANE.width), np.nan, np.float32)
    depth[:10] = 0.0  # a zero depth (a common "no reading" value) is missing too
    image, _ = to_network_input(depth, SILEANE)
    np.testing.assert_array_equal(image, 1.0)


def test_network_input_normalizes_between_clip_planes() -> None:
    camera = Camera(300.0, 300.0, 99.5, 99.5, 200, 200, 0.5, 1.5)
    image, _ = to_network_input(np.full((200, 200), 0.75, np.float32), camera)
    np.testing.assert_allclose(image, 0.25, atol=1e-6)


@pytest.mark.parametrize(
    ("depth", "match"),
    [
        (np.ones((474, 506), np.int32), "float dtype"),
        (np.ones((474, 506, 1), np.float32), r"\(H, W\)"),
        (np.full((474, 506), np.inf, np.float32), "infinite"),
        (np.ones((506, 474), np.float32), "does not match"),
    ],
)
def test_network_input_rejects_bad_depth(depth: np.ndarray, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        to_network_input(depth, SILEANE)


def test_nan_aware_resize_does_not_smear_missing_pixels() -> None:
    depth = np.full((64, 64), 1.0, np.float32)
    depth[:, :32] = np.nan
    out = resize_depth(depth, 16, cv2.INTER_LINEAR)
    np.testing.assert_array_equal(out[:, 8:], 1.0)  # no NaN or zero bleeding into valid pixels
    assert np.isnan(out[:, :8]).all()


# --- resize_segmentation ------------------------------------------------------------------------


def test_segmentation_follows_the_same_canvas() -> None:
    seg = np.zeros((SILEANE.height, SILEANE.width), np.int32)
    depth = np.full(seg.shape, 1.6, np.float32)
    seg[200:260, 300:360] = 7
    depth[200:260, 300:360] = 1.0
    image, _ = to_network_input(depth, SILEANE)
    small = resize_segmentation(seg, SILEANE, 128)
    assert small.shape == (128, 128) and small.dtype == np.int32
    assert set(np.unique(small)) == {0, 7}
    near = image < SILEANE.normalize_depth(1.3)
    agreement = (near == (small == 7)).mean()
    assert agreement > 0.995


def test_segmentation_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="integer"):
        resize_segmentation(np.zeros((474, 506), np.float32), SILEANE, 32)
    with pytest.raises(ValueError, match="does not match"):
        resize_segmentation(np.zeros((10, 10), np.int32), SILEANE, 32)


def test_resize_interpolations_are_the_seven_opencv_options() -> None:
    assert set(RESIZE_INTERPOLATIONS) == {
        "nearest", "linear", "area", "cubic", "lanczos4", "nearest-exact", "linear-exact"
    }  # fmt: skip
    assert len(set(RESIZE_INTERPOLATIONS.values())) == 7


def test_framings_of_an_off_centre_camera() -> None:
    """Siléane's camera (principal point 250 px left of centre): the centred square wastes most of
    the input; the image-centred squares use all of it (padding only the short side, or cropping)."""
    from opnet.data.preprocess import framing_coverage, network_camera, square_canvas

    cam = Camera(4507.08, 4507.08, 399.557, 556.6, 1296, 1024, 0.76, 0.93)
    assert square_canvas(cam, "image") == (0, -136, 1296)
    assert square_canvas(cam, "image_crop") == (136, 0, 1024)
    pad_in, pad_img = framing_coverage(cam, "pad")
    assert pad_img == 1.0 and pad_in < 0.45  # all of the image, in less than half of the input
    img_in, img_img = framing_coverage(cam, "image")
    assert img_img == 1.0 and abs(img_in - 1024 / 1296) < 1e-9
    assert framing_coverage(cam, "image_crop") == (1.0, 1024 / 1296)
    crop_in, crop_img = framing_coverage(cam, "crop")
    assert crop_in == 1.0 and crop_img < 0.5
    # the input camera keeps the geometry: a point projects to the same content
    p = np.array([0.05, -0.02, 0.85])
    for fit in ("pad", "crop", "image", "image_crop"):
        x0, y0, side = square_canvas(cam, fit)
        u, v = cam.project(p)
        un, vn = network_camera(cam, 128, fit).project(p)
        assert np.allclose([(u + 0.5 - x0) * 128 / side - 0.5, (v + 0.5 - y0) * 128 / side - 0.5], [un, vn])
