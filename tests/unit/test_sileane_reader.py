"""Siléane layout: camera_params.txt, depth and segmentation PNGs, world -> camera ground truth."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from opnet.datasets import SileaneDataset, open_dataset, read_camera_params
from opnet.datasets.sileane_json import write_gt_json
from opnet.metrics.records import GroundTruthSet

# the dataset page's camera: 180° about x (looking down), at (-0.1, 0, 1.5); small image
CAMERA_TXT = """# camera of a tiny test folder
width\t40
height  30
fu\t100.0
fv\t100.0
cu\t19.5   # comment after a value
cv\t14.0
clip_start\t0.8
clip_end\t1.7
location\t-0.1\t0\t1.5
rotation\t0 1 0 0
"""
# object 7 at world (0.05, 0.024, 0.3): camera (0.15, -0.024, 1.2), pixel (19.5 + 12.5, 14 - 2)
WORLD_T = np.array([[0.05, 0.024, 0.3], [-0.2, 0.1, 0.25]])
CAMERA_T = np.array([[0.15, -0.024, 1.2], [-0.1, -0.1, 1.25]])


def make_folder(root: Path, suffix: str = ".PNG") -> Path:
    (root / "depth").mkdir(parents=True)
    (root / "segmentation").mkdir()
    (root / "camera_params.txt").write_text(CAMERA_TXT)
    R_world = np.stack([np.eye(3), np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])])
    write_gt_json(
        root / "gt" / "bunny_1_002.json", GroundTruthSet(R_world, WORLD_T, [0.25, 1.0], [7, 65535])
    )
    depth = np.full((30, 40), 65535, np.uint16)
    depth[12, 32] = round(65535 * (1.2 - 0.8) / 0.9)
    seg = np.zeros((30, 40), np.uint16)
    seg[12, 32], seg[0, 0], seg[0, 1] = 7, 65535, 3  # 3 is no instance of the scene
    cv2.imwrite(str(root / "depth" / f"bunny_1_002{suffix}"), depth)
    cv2.imwrite(str(root / "segmentation" / f"bunny_1_002{suffix}"), seg)
    return root


def test_camera_params(tmp_path: Path) -> None:
    camera, R_world_cam, t_world_cam = read_camera_params(make_folder(tmp_path / "bunny"))
    assert (camera.fx, camera.fy, camera.cx, camera.cy, camera.width, camera.height) == (
        100,
        100,
        19.5,
        14,
        40,
        30,
    )
    assert (camera.clip_start, camera.clip_end) == (0.8, 1.7)
    np.testing.assert_allclose(R_world_cam, np.diag([1.0, -1.0, -1.0]), atol=1e-15)
    np.testing.assert_array_equal(t_world_cam, [-0.1, 0, 1.5])


@pytest.mark.parametrize("suffix", [".PNG", ".png"])
def test_reader_moves_ground_truth_and_pixels_consistently(tmp_path: Path, suffix: str) -> None:
    ds = SileaneDataset(make_folder(tmp_path / "bunny", suffix))
    assert ds.scenes() == ["bunny_1_002"] and len(ds) == 1
    rec = ds[0]
    assert rec.name == "bunny_1_002" and rec.object_name == "bunny"
    np.testing.assert_allclose(rec.t_cam_obj, CAMERA_T, atol=1e-12)
    np.testing.assert_allclose(rec.R_cam_obj[0], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(rec.visibility, [0.75, 0.0])
    assert rec.instance_id.tolist() == [7, 65535]
    # the object's pixel, back-projected (no half-pixel shift) and moved to world: the GT origin
    u, v = rec.camera.project(CAMERA_T[0])
    assert (u, v) == pytest.approx((32.0, 12.0))
    assert np.isnan(rec.depth).sum() == rec.depth.size - 1
    z = rec.depth[12, 32]
    p_world = ds.R_world_cam @ rec.camera.backproject(32.0, 12.0, float(z)) + ds.t_world_cam
    np.testing.assert_allclose(p_world, WORLD_T[0], atol=2e-5)  # up to the depth quantization
    assert rec.segmentation.dtype == np.int32
    assert (rec.segmentation[12, 32], rec.segmentation[0, 0], rec.segmentation[0, 1]) == (
        7,
        65535,
        0,
    )
    gt_cam = ds.read_ground_truth("bunny_1_002", frame="camera")
    np.testing.assert_allclose(gt_cam.t, CAMERA_T, atol=1e-12)
    np.testing.assert_array_equal(ds.read_ground_truth("bunny_1_002").t, WORLD_T)


def test_bad_camera_params(tmp_path: Path) -> None:
    path = tmp_path / "camera_params.txt"
    for text, expected in [
        (CAMERA_TXT.replace("fv\t100.0\n", ""), r"missing key\(s\) \['fv'\]"),
        (
            CAMERA_TXT.replace("location\t-0.1\t0\t1.5", "location\t-0.1 0"),
            "line 10: 'location' needs 3",
        ),
        (CAMERA_TXT.replace("fu\t100.0", "fu\tabc"), "line 4: 'fu'"),
        (CAMERA_TXT.replace("width\t40", "width\t40.5"), "integers"),
        (CAMERA_TXT.replace("clip_end\t1.7", "clip_end\t0.5"), "clip_start < clip_end"),
    ]:
        path.write_text(text)
        with pytest.raises(ValueError, match=expected) as err:
            read_camera_params(path)
        assert str(path) in str(err.value)


def test_missing_images_and_camera_give_clear_errors(tmp_path: Path) -> None:
    root = make_folder(tmp_path / "bunny")
    (root / "depth" / "bunny_1_002.PNG").unlink()
    with pytest.raises(FileNotFoundError, match="bunny_1_002.PNG"):
        SileaneDataset(root)[0]
    (root / "camera_params.txt").unlink()
    ds = open_dataset(root)
    assert isinstance(ds, SileaneDataset) and ds.camera is None
    with pytest.raises(FileNotFoundError, match="camera_params.txt"):
        ds[0]


def test_ground_truth_only_sample(bunny_sample: Path) -> None:
    ds = open_dataset(bunny_sample)
    assert isinstance(ds, SileaneDataset) and len(ds) == 11 and ds.scenes()[0] == "bunny_3_070"
    gt = ds.read_ground_truth("bunny_3_070")
    assert len(gt) == 70 and (gt.occlusion_rate == 1.0).sum() == 10
    with pytest.raises(FileNotFoundError, match="camera_params.txt"):
        ds[0]
