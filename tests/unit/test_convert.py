"""Ground-truth conversion: IPA / Siléane folders -> Siléane JSON -> same poses and occlusions."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from opnet.datasets import (
    IPADataset,
    IPAParameters,
    SileaneDataset,
    open_dataset,
    record_to_ground_truth,
    write_ipa_scene,
    write_parameters,
    write_sileane_ground_truth,
)
from opnet.datasets.convert import convert_dataset, main
from opnet.datasets.record import SceneRecord
from opnet.datasets.sileane_json import read_gt_json
from opnet.geometry import Camera, quaternion_to_matrix

CAMERA = Camera.from_fov(50.0, 16, 12, 0.5, 1.5)


def ipa_folder(root: Path) -> Path:
    write_parameters(root, IPAParameters.from_camera(CAMERA, number_cycles=2, shape_drop_limit=3))
    rng = np.random.default_rng(3)
    for cycle in (0, 1):
        for n in range(3):
            rec = SceneRecord(
                name="ignored",
                depth=np.full((12, 16), 1.0, np.float32),
                camera=CAMERA,
                R_cam_obj=quaternion_to_matrix(rng.normal(size=(n, 4))),
                t_cam_obj=rng.normal(size=(n, 3)),
                visibility=rng.uniform(-0.1, 1.3, n),
                instance_id=np.arange(1, n + 1),
            )
            write_ipa_scene(root, cycle, rec, (np.eye(3), np.zeros(3)))
    return root


def test_ipa_folder_to_json_keeps_poses_and_occlusions(tmp_path: Path) -> None:
    root = ipa_folder(tmp_path / "ipa")
    assert main([str(root), str(tmp_path / "out")]) == 0
    ds = IPADataset(root)
    files = sorted((tmp_path / "out").glob("*.json"))
    assert [f.stem for f in files] == [ds.scene_name(i) for i in range(len(ds))] and len(files) == 6
    for i, f in enumerate(files):
        gt, rec = read_gt_json(f), ds[i]
        np.testing.assert_array_equal(gt.R, rec.R_cam_obj)
        np.testing.assert_array_equal(gt.t, rec.t_cam_obj)
        np.testing.assert_array_equal(gt.occlusion_rate, 1.0 - np.clip(rec.visibility, 0.0, 1.0))
        np.testing.assert_array_equal(gt.segmentation_id, rec.instance_id)
    assert read_gt_json(files[-1]).occlusion_rate.min() >= 0.0 and len(read_gt_json(files[0])) == 0


def test_write_sileane_ground_truth_from_records(tmp_path: Path) -> None:
    ds = IPADataset(ipa_folder(tmp_path / "ipa"))
    records = [ds[i] for i in range(len(ds))]
    files = write_sileane_ground_truth(records, tmp_path / "out")
    assert [f.name for f in files] == [f"{r.name}.json" for r in records]
    gt = read_gt_json(files[2])
    expected = record_to_ground_truth(records[2])
    np.testing.assert_array_equal(gt.t, expected.t)
    np.testing.assert_array_equal(gt.occlusion_rate, expected.occlusion_rate)
    with pytest.raises(ValueError, match="two scenes are named"):
        write_sileane_ground_truth([records[0], records[0]], tmp_path / "dup")


def test_sileane_folder_to_camera_frame_json(tmp_path: Path, bunny_sample: Path) -> None:
    root = tmp_path / "bunny"
    (root / "gt").mkdir(parents=True)
    (root / "gt" / "bunny_3_070.json").write_bytes(
        (bunny_sample / "gt" / "bunny_3_070.json").read_bytes()
    )
    (root / "camera_params.txt").write_text(
        "width 506\nheight 474\nfu 1152.31\nfv 1152.31\ncu 139.459\ncv 237.001\n"
        "clip_start 0.87599\nclip_end 1.70602\nlocation -0.1 0 1.5\nrotation 0 1 0 0\n"
    )
    files = convert_dataset(root, tmp_path / "out")
    cam, world = read_gt_json(files[0]), read_gt_json(bunny_sample / "gt" / "bunny_3_070.json")
    # 180° about x at (-0.1, 0, 1.5): X_cam = (x + 0.1, -y, 1.5 - z)
    np.testing.assert_allclose(cam.t, (world.t - [-0.1, 0, 1.5]) * [1, -1, -1], atol=1e-12)
    np.testing.assert_array_equal(cam.occlusion_rate, world.occlusion_rate)
    np.testing.assert_array_equal(cam.segmentation_id, world.segmentation_id)
    with pytest.raises(ValueError, match="camera frame only"):
        convert_dataset(ipa_folder(tmp_path / "ipa"), tmp_path / "x", frame="world")


def test_open_dataset_detects_layouts(tmp_path: Path) -> None:
    assert isinstance(open_dataset(ipa_folder(tmp_path / "ipa")), IPADataset)
    (tmp_path / "sil").mkdir()
    (tmp_path / "sil" / "camera_params.txt").write_text(
        "width 4\nheight 3\nfu 1\nfv 1\ncu 1\ncv 1\nclip_start 1\nclip_end 2\n"
        "location 0 0 0\nrotation 1 0 0 0\n"
    )
    (tmp_path / "sil" / "gt").mkdir()
    assert isinstance(open_dataset(tmp_path / "sil"), SileaneDataset)
    (tmp_path / "none").mkdir()
    with pytest.raises(ValueError, match="not a dataset folder"):
        open_dataset(tmp_path / "none")
    with pytest.raises(FileNotFoundError, match="missing"):
        open_dataset(tmp_path / "missing")


def test_command_line_reports_errors(tmp_path: Path) -> None:
    done = subprocess.run(
        [sys.executable, "-m", "opnet.datasets.convert", str(tmp_path), str(tmp_path / "out")],
        capture_output=True, text=True, check=False, timeout=120,
    )  # fmt: skip
    assert (
        done.returncode == 2
        and "not a dataset folder" in done.stderr
        and "Warning" not in done.stderr
    )
