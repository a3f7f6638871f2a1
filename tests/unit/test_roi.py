"""Region of interest (opnet.data.roi): a crop before the framing moves no part off its pixels,
scales visibilities exactly, and bad boxes are one-line errors."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from opnet.data.preprocess import to_network_input
from opnet.data.roi import ROIScenes, crop_image, crop_record, parse_roi, resolve_box, roi_tag
from opnet.datasets.record import SceneRecord
from opnet.geometry.camera import Camera
from opnet.synthesis.layout import homogeneous
from opnet.synthesis.rendering import SceneRenderer

CAM = Camera(300.0, 300.0, 159.5, 119.5, 320, 240, 0.5, 1.5)
PLATE = trimesh.creation.box(extents=(0.06, 0.04, 0.01))


@pytest.fixture(scope="module")
def scene() -> SceneRecord:
    """Two plates at 1 m: one at (-0.12, 0.05) m, one at (0.1, -0.06) m."""
    renderer = SceneRenderer(PLATE, CAM)
    t = np.array([[-0.12, 0.05, 1.0], [0.1, -0.06, 1.0]])
    out = renderer.render(np.stack([homogeneous(np.eye(3), x) for x in t]))
    renderer.close()
    return SceneRecord("s", out.depth, CAM, out.segmentation, np.stack([np.eye(3)] * 2), t, out.visibility,
                       np.array([1, 2]), "plate")


def test_a_part_lands_on_the_same_pixels_before_and_after_the_crop(scene: SceneRecord) -> None:
    box = (100, 60, 300, 200)
    cropped = crop_record(scene, box)
    for k, t in enumerate(scene.t_cam_obj):
        u, v = CAM.project(t)
        uc, vc = cropped.camera.project(t)
        assert (uc, vc) == pytest.approx((u - box[0], v - box[1]))
        if 0 <= uc < cropped.camera.width and 0 <= vc < cropped.camera.height:
            assert cropped.segmentation[int(round(vc)), int(round(uc))] == scene.segmentation[int(round(v)), int(round(u))] == k + 1
            assert cropped.depth[int(round(vc)), int(round(uc))] == scene.depth[int(round(v)), int(round(u))]
    # and through the framing into the network input: the origin's input pixel shows the plate's depth
    image, net_cam = to_network_input(cropped.depth, cropped.camera, size=128, fit="image")
    u, v = net_cam.project(scene.t_cam_obj[1])
    assert image[int(v), int(u)] == pytest.approx(net_cam.normalize_depth(0.995), abs=0.01)


def test_visibility_is_scaled_by_the_share_of_pixels_inside(scene: SceneRecord) -> None:
    u, _ = CAM.project(scene.t_cam_obj[0])
    box = (int(round(u)), 0, 320, 240)  # cuts plate 1 through its centre column, keeps plate 2 whole
    cropped = crop_record(scene, box)
    inside = (scene.segmentation[:, box[0]:] == 1).sum() / (scene.segmentation == 1).sum()
    assert cropped.visibility[0] == pytest.approx(scene.visibility[0] * inside)
    assert 0.4 < inside < 0.6 and cropped.visibility[1] == pytest.approx(scene.visibility[1])
    gone = crop_record(scene, (200, 0, 320, 240))  # plate 1 entirely outside
    assert gone.visibility[0] == 0.0


def test_auto_boxes_the_largest_region_inside_the_working_volume() -> None:
    depth = np.full((240, 320), 2.0, np.float32)  # the floor, beyond the far clip plane
    depth[50:100, 120:200] = 1.0  # the bin
    depth[200:204, 10:300] = 1.0  # a thin bar of the cell: not the bin
    x0, y0, x1, y1 = resolve_box("auto", depth, CAM)
    m = round(0.02 * 320)
    assert abs(x0 - (120 - m)) <= 1 and abs(y0 - (50 - m)) <= 1 and abs(x1 - (200 + m)) <= 1 and abs(y1 - (100 + m)) <= 1
    with pytest.raises(ValueError, match="no bin found between the clip planes"):
        resolve_box("auto", np.full((240, 320), np.nan, np.float32), CAM)
    assert crop_image(depth, CAM, None)[1] is CAM


@pytest.mark.parametrize(("value", "message"), [
    ([0, 0, 0, 10], "an empty box"),
    ([5, 5, 400, 100], "outside the 320 x 240 image"),
    # a negative origin is no empty box, reversed corners are named as such, a 2 x 2 box feeds the network nothing
    ([-1, 0, 30, 30], r"=\[-1, 0, 30, 30\]: the box starts at pixel \(-1, 0\), outside the image; pixels count from 0"),
    ([50, 60, 10, 20], r"=\[50, 60, 10, 20\]: the corners are reversed; give \[x0, y0, x1, y1\] with the top-left"),
    ([0, 0, 2, 2], r"=\[0, 0, 2, 2\]: a box of 2 x 2 pixels; the network needs at least 16 a side"),
    ("-10,0,50,50", r"=\[-10, 0, 50, 50\]: the box starts at pixel \(-10, 0\)"),  # as --roi gives it
    ("middle", "expected null, auto, auto:<metres> or"),
    ([1.5, 0, 10, 10], "whole pixel numbers"),
])
def test_bad_boxes_are_one_line_errors(value: object, message: str) -> None:
    with pytest.raises(ValueError, match=message) as e:
        resolve_box(parse_roi(value), None, CAM)
    assert "\n" not in str(e.value) and str(e.value).startswith("data.roi=")


def test_cropped_datasets_keep_their_keys_and_cache_apart(scene: SceneRecord) -> None:
    class Source(list):
        camera = CAM

        def scenes(self) -> list:
            return ["a"]

    wrapped = ROIScenes(Source([scene]), (10, 20, 110, 220))
    assert wrapped.scenes() == ["a"] and len(wrapped) == 1
    assert wrapped.camera == wrapped[0].camera and wrapped.camera.width == 100 and wrapped.camera.cx == CAM.cx - 10
    assert roi_tag(None) == "" and roi_tag((10, 20, 110, 220)) == "_roi10-20-110-220" and roi_tag("auto") == "_roiauto_f3"
    assert parse_roi("10,20,110,220") == (10, 20, 110, 220)
