"""SceneRenderer: pixel convention, depth, segmentation and visibility on constructed scenes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from opnet.geometry.camera import Camera
from opnet.objects import builtin_object
from opnet.synthesis.layout import homogeneous
from opnet.synthesis.rendering import SceneRenderer

# 64 x 48 image, principal point deliberately off-centre and on a half pixel in x
CAM = Camera(100.0, 100.0, 31.5, 23.0, 64, 48, 0.5, 2.0)
PLATE = trimesh.creation.box(extents=(0.2, 0.1, 0.001))  # 20 x 10 px at 1 m


def _at(x: float, y: float, z: float, R: np.ndarray | None = None) -> np.ndarray:
    return homogeneous(np.eye(3) if R is None else R, np.array([x, y, z]))


@pytest.fixture(scope="module")
def plate_renderer():
    r = SceneRenderer(PLATE, CAM)
    r.begin_cycle(np.eye(4))
    yield r
    r.close()


def test_pixel_coverage_follows_the_opencv_pixel_centre_convention(plate_renderer: SceneRenderer) -> None:
    # front face at z = 0.9995: it covers the pixels whose centres (integers) project inside it;
    # a half-pixel error in the principal point shifts the covered range by one column or row
    x, y, z = 0.013, -0.021, 1.0
    out = plate_renderer.render(_at(x, y, z)[None])
    front = z - 0.0005
    u0, u1 = CAM.fx * (x - 0.1) / front + CAM.cx, CAM.fx * (x + 0.1) / front + CAM.cx
    v0, v1 = CAM.fy * (y - 0.05) / front + CAM.cy, CAM.fy * (y + 0.05) / front + CAM.cy
    cols = np.flatnonzero(out.segmentation.any(axis=0))
    rows = np.flatnonzero(out.segmentation.any(axis=1))
    assert (cols.min(), cols.max()) == (np.ceil(u0), np.floor(u1))
    assert (rows.min(), rows.max()) == (np.ceil(v0), np.floor(v1))
    assert out.segmentation.max() == 1 and set(np.unique(out.segmentation)) == {0, 1}


def test_depth_is_z_depth_in_metres_and_nan_elsewhere(plate_renderer: SceneRenderer) -> None:
    tilt = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(0.3), -np.sin(0.3)], [0.0, np.sin(0.3), np.cos(0.3)]])
    T = _at(0.0, 0.0, 1.2, tilt)
    out = plate_renderer.render(T[None])
    hit = out.segmentation == 1
    assert np.isnan(out.depth[~hit]).all() and np.isfinite(out.depth[hit]).all()
    # back-projected pixels lie on the front face of the tilted plate (plane z_model = -0.0005)
    points = CAM.depth_to_points(out.depth)[hit]
    z_model = ((points - T[:3, 3]) @ T[:3, :3])[:, 2]
    np.testing.assert_allclose(z_model, -0.0005, atol=2e-6)


def test_isolated_object_fully_in_view_is_fully_visible() -> None:
    obj = builtin_object("bracket")
    cam = Camera.from_fov(50.0, 128, 128, 0.1, 1.0)
    r = SceneRenderer(obj.mesh, cam)
    r.begin_cycle(np.eye(4))
    out = r.render(_at(0.01, -0.02, 0.3)[None])
    r.close()
    assert out.solo_pixels[0] > 200
    assert out.visibility[0] > 0.98


@pytest.mark.parametrize(("half_width", "expected"), [(0.2, 0.5), (0.96, 1 / 3)])
def test_object_cut_by_the_image_border(half_width: float, expected: float) -> None:
    # a plate centred on the left image border (u = -0.5): half of its columns are outside; a
    # plate three images wide centred on the image: a third is inside (solo counted over windows)
    plate = trimesh.creation.box(extents=(2 * half_width, 0.1, 0.001))
    r = SceneRenderer(plate, CAM)
    r.begin_cycle(np.eye(4))
    x_centre = (-0.5 - CAM.cx) / CAM.fx * 0.9995 if expected == 0.5 else (CAM.width / 2 - 0.5 - CAM.cx) / CAM.fx
    out = r.render(_at(x_centre, 0.0, 1.0)[None])
    r.close()
    width_px = 2 * half_width * CAM.fx
    assert out.solo_pixels[0] == pytest.approx(width_px * 10, rel=0.1)  # the whole plate is counted
    # rasterization rounds each cut edge to a pixel centre: at most one column of ~40 (or ~190)
    assert out.visibility[0] == pytest.approx(expected, abs=1.0 / (width_px / 2) + 1e-9)


def test_occluded_object_visibility_matches_a_direct_pixel_count() -> None:
    obj = builtin_object("bracket")
    cam = Camera.from_fov(50.0, 128, 128, 0.1, 1.0)
    r = SceneRenderer(obj.mesh, cam)
    r.begin_cycle(np.eye(4))
    below, above = _at(0.0, 0.0, 0.32), _at(0.015, 0.01, 0.28)
    alone_below = r.render(below[None]).segmentation == 1
    alone_above = r.render(above[None]).segmentation == 1
    out = r.render(np.stack([below, above]))
    r.close()
    hidden = alone_below & alone_above
    assert 0.1 < hidden.sum() / alone_below.sum() < 0.9  # a real partial occlusion
    np.testing.assert_array_equal(out.segmentation == 1, alone_below & ~alone_above)
    assert out.visibility[0] == pytest.approx((alone_below & ~alone_above).sum() / alone_below.sum(), abs=1e-12)
    assert out.visibility[1] == 1.0


def test_bin_is_in_the_depth_but_not_in_the_segmentation() -> None:
    cam = Camera.from_fov(50.0, 96, 96, 0.1, 1.0)
    box = trimesh.creation.box(extents=(0.05, 0.05, 0.05))
    r = SceneRenderer(box, cam, bin_mesh=trimesh.creation.box(extents=(0.6, 0.6, 0.01)))
    r.begin_cycle(_at(0.0, 0.0, 0.5))  # the "bin" plate fills the view 0.5 m away
    out = r.render(_at(0.0, 0.0, 0.4)[None])
    r.close()
    assert np.isfinite(out.depth).all()
    assert set(np.unique(out.segmentation)) == {0, 1}
    np.testing.assert_allclose(out.depth[out.segmentation == 0], 0.495, atol=1e-5)


def test_solo_counts_are_cached_while_objects_rest() -> None:
    cam = Camera.from_fov(60.0, 128, 128, 0.1, 2.0)
    box = trimesh.creation.box(extents=(0.02, 0.02, 0.02))
    r = SceneRenderer(box, cam, solo_cache_mm=0.3, solo_cache_deg=0.3)
    r.begin_cycle(np.eye(4))
    poses = np.stack([_at(-0.1, 0.0, 0.5), _at(0.0, 0.0, 0.5), _at(0.1, 0.0, 0.5)])
    first = r.render(poses)
    assert first.solo_renders == 1  # one union pass counts all three silhouettes
    moved = poses.copy()
    moved[1, 0, 3] += 0.0001  # 0.1 mm: within the reuse tolerance
    assert r.render(moved).solo_renders == 0
    moved[2, 0, 3] += 0.01
    again = r.render(moved)
    assert again.solo_renders == 1
    np.testing.assert_array_equal(again.visibility, 1.0)
    r.close()
