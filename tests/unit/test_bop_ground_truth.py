"""Ground truth that must not thin out or swell unseen: a BOP instance whose visible mask is missing
is an error naming the file (a scene without any ``mask_visib`` folder keeps every instance, without
segmentation), and the dataset check reports missing masks, duplicate instances and camera
rotations that are no rotation. Every split here is written to disk in the BOP format."""

from __future__ import annotations

import json
import logging
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from opnet.data.roi import crop_record
from opnet.datasets.bop import BOPDataset, write_bop_split
from opnet.datasets.check import check_dataset, main as check_main
from opnet.datasets.ground_truth import record_to_ground_truth
from opnet.datasets.record import SceneRecord
from opnet.geometry.camera import Camera
from opnet.metrics.bregier import instances_to_find

CAMERA = Camera(100.0, 100.0, 31.5, 23.5, 64, 48, 0.5, 1.5)
#: three parts side by side at 0.95 m, their silhouettes in columns [x0, x1)
COLUMNS = ((8, 20), (24, 40), (44, 56))
#: a region of interest holding every silhouette whole
ROI = (2, 2, 62, 46)


def _record(name: str) -> SceneRecord:
    seg = np.zeros((CAMERA.height, CAMERA.width), np.int32)
    for k, (x0, x1) in enumerate(COLUMNS):
        seg[10:38, x0:x1] = k + 1
    n = len(COLUMNS)
    return SceneRecord(name=name, depth=np.full((CAMERA.height, CAMERA.width), 1.0, np.float32), camera=CAMERA,
                       segmentation=seg, R_cam_obj=np.repeat(np.eye(3)[None], n, axis=0),
                       t_cam_obj=np.array([[x, 0.0, 0.95] for x in (-0.05, 0.0, 0.05)]),
                       visibility=np.full(n, 0.9), instance_id=np.arange(1, n + 1))


def _split(root: Path, images: int = 2) -> Path:
    """A BOP dataset ``root`` (models_info.json of obj_id 1) with split ``root/test``: scene 0,
    ``images`` images of three instances of object 1, their visible masks written."""
    (root / "models").mkdir(parents=True)
    (root / "models" / "models_info.json").write_text(json.dumps({"1": {"diameter": 50.0}}))
    return write_bop_split(((0, im, _record(f"000000_{im:06d}")) for im in range(images)), root / "test", obj_id=1)


def _edit_json(path: Path, image: str, edit) -> None:
    doc = json.loads(path.read_text())
    edit(doc[image])
    path.write_text(json.dumps(doc))


def _to_find_in_roi(record: SceneRecord) -> int:
    """The parts to find once the record is cropped to :data:`ROI` (what training and evaluation see)."""
    return int(instances_to_find(record_to_ground_truth(crop_record(record, ROI))).sum())


# ------------------------------------------------------------------------------------------ reader


def test_every_instance_with_its_mask_is_ground_truth(tmp_path: Path) -> None:
    record = BOPDataset(_split(tmp_path), 1)[1]
    assert record.num_objects == 3 and sorted(np.unique(record.segmentation)) == [0, 1, 2, 3]
    assert _to_find_in_roi(record) == 3


def test_a_deleted_mask_is_an_error_naming_it_not_a_part_less_to_find(tmp_path: Path) -> None:
    split = _split(tmp_path)
    mask = split / "000000" / "mask_visib" / "000001_000001.png"
    mask.unlink()
    dataset = BOPDataset(split, 1)
    assert dataset[0].num_objects == 3  # the other image is whole
    with pytest.raises(FileNotFoundError, match=rf"^{mask}: file not found: the visible mask of instance 1 of "
                                                r"image 1 in scene_gt.json"):
        dataset[1]  # used to read: the part without silhouette left the parts to find in a crop (3 -> 2)


def test_a_scene_without_mask_folder_keeps_every_instance_and_says_so(tmp_path: Path,
                                                                      caplog: pytest.LogCaptureFixture) -> None:
    split = _split(tmp_path)
    shutil.rmtree(split / "000000" / "mask_visib")  # the BOP format makes the folder optional
    with caplog.at_level(logging.WARNING, logger="opnet.datasets.bop"):
        record = BOPDataset(split, 1)[1]
    assert "1 of 1 scene folder(s) have no mask_visib folder" in caplog.text
    assert record.segmentation is None and record.num_objects == 3
    assert np.allclose(record.visibility, 0.9)
    assert _to_find_in_roi(record) == 3  # an all-zero segmentation used to crop every part away (3 -> 0)


# ----------------------------------------------------------------------------------------- checker


@pytest.mark.parametrize("fast", [True, False])
def test_check_passes_a_whole_split(fast: bool, tmp_path: Path) -> None:
    report = check_dataset(_split(tmp_path), fast=fast, object_id=1)
    assert report.ok, report.summary()


@pytest.mark.parametrize("fast", [True, False])
def test_check_reports_a_missing_mask(fast: bool, tmp_path: Path) -> None:
    split = _split(tmp_path)
    mask = split / "000000" / "mask_visib" / "000000_000002.png"
    mask.unlink()
    report = check_dataset(split, fast=fast, object_id=1)
    assert [p.path for p in report.problems] == [mask], report.summary()
    assert report.problems[0].message.startswith("file not found")


@pytest.mark.parametrize("fast", [True, False])
def test_check_reports_a_duplicate_instance(fast: bool, tmp_path: Path) -> None:
    split = _split(tmp_path)
    gt = split / "000000" / "scene_gt.json"
    _edit_json(gt, "1", lambda entries: entries.append(dict(entries[0])))
    info = split / "000000" / "scene_gt_info.json"  # the reader needs one info entry per instance
    _edit_json(info, "1", lambda entries: entries.append(dict(entries[0])))
    masks = split / "000000" / "mask_visib"
    shutil.copy(masks / "000001_000000.png", masks / "000001_000003.png")
    report = check_dataset(split, fast=fast, object_id=1)
    assert [str(p) for p in report.problems] == [
        f"{gt}: image 1: instance 3 duplicates instance 0 (obj_id 1, the same pose): one part listed twice"]


def test_a_near_duplicate_is_no_duplicate(tmp_path: Path) -> None:
    split = _split(tmp_path)
    gt = split / "000000" / "scene_gt.json"

    def near_copy(entries: list) -> None:
        entries.append({**entries[0], "cam_t_m2c": [entries[0]["cam_t_m2c"][0] + 0.5, *entries[0]["cam_t_m2c"][1:]]})

    _edit_json(gt, "0", near_copy)
    _edit_json(split / "000000" / "scene_gt_info.json", "0", lambda entries: entries.append(dict(entries[0])))
    masks = split / "000000" / "mask_visib"
    shutil.copy(masks / "000000_000000.png", masks / "000000_000003.png")
    assert check_dataset(split, fast=True, object_id=1).ok


@pytest.mark.parametrize(("R", "why"), [
    (np.diag([2.0, 2.0, 2.0]).reshape(-1).tolist(), r"\(\|R\^T R - I\| = 3 > 0.0001, not orthonormal\)"),
    (np.diag([1.0, 1.0, -1.0]).reshape(-1).tolist(), r"\(det\(R\) = -1, a reflection\)"),
    ([1.0, 0.0, 0.0, 0.0, 1.0, 0.0], None),
])
def test_check_reports_a_camera_rotation_that_is_no_rotation(R: list[float], why: str | None, tmp_path: Path,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    split = _split(tmp_path)
    cam = split / "000000" / "scene_camera.json"
    good = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # a turn about z: fine
    _edit_json(cam, "0", lambda entry: entry.update(cam_R_w2c=good.reshape(-1).tolist(), cam_t_w2c=[0.0, 0.0, 900.0]))
    _edit_json(cam, "1", lambda entry: entry.update(cam_R_w2c=R, cam_t_w2c=[0.0, 0.0, 900.0]))
    report = check_dataset(split, fast=True, object_id=1)
    assert len(report.problems) == 1 and report.problems[0].path == cam, report.summary()
    if why is not None:
        assert report.problems[0].message.startswith("image 1: 'cam_R_w2c' is not a rotation matrix (")
        assert re.search(why, report.problems[0].message)
    else:
        assert report.problems[0].message.startswith("image 1: 'cam_R_w2c' must be 9 finite numbers")
    assert check_main([str(split), "--object-id", "1"]) == 1
    out = capsys.readouterr().out
    assert "1 problem(s)" in out and f"{cam}: image 1: 'cam_R_w2c'" in out


@pytest.mark.parametrize("clip", [["1.5", "0.5"], ["0.5", "0.5"], ["nan", "1.5"], ["0.5", "500"]])
def test_check_refuses_its_own_clip_option_not_every_camera(clip: list[str], tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    """Reversed planes used to be reported against every image's scene_camera.json (exit 1), as if the
    split's cameras were wrong: the option is, one line naming it, exit 2, before any scene is read."""
    split = _split(tmp_path)
    assert check_main([str(split), "--object-id", "1", "--clip", *clip]) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and captured.err.startswith("error: --clip=[") and captured.err.count("\n") == 1
    assert "scene_camera.json" not in captured.err
    assert check_main([str(split), "--object-id", "1", "--clip", "0.5", "1.5"]) == 0
