"""Validation at the edges: impossible values are refused where they are read, with the file named
(rotations scaled by 3 or reflected, visibilities of -5 or 50, segmentation ids of 1e30,
deeply nested JSON, millimetre clip planes, a principal point 100000 px away, a BOM in a CSV)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from opnet.datasets.ipa_csv import IPAGroundTruth, read_ipa_csv, write_ipa_csv
from opnet.datasets.ipa_params import IPAParameters, read_parameters, write_parameters
from opnet.datasets.sileane_json import read_gt_json, read_results_json
from opnet.geometry.camera import Camera
from opnet.synthesis.layout import random_rotation


def _gt(n: int = 3, scale: float = 1.0, visibility: float = 0.8, t_z: float = 1.0) -> IPAGroundTruth:
    rng = np.random.default_rng(0)
    R = np.stack([random_rotation(rng) for _ in range(n)])
    t = np.tile([0.01, -0.02, t_z], (n, 1))
    return IPAGroundTruth(np.arange(1, n + 1), np.ones(n, np.int64), np.asarray(R) * scale, t,
                         np.full(n, visibility), np.full(n, visibility))


def test_valid_csv_reads_back(tmp_path: Path) -> None:
    write_ipa_csv(tmp_path / "ok.csv", _gt())
    assert len(read_ipa_csv(tmp_path / "ok.csv").instance_id) == 3


@pytest.mark.parametrize(("gt", "message"), [
    (_gt(scale=3.0), "not orthonormal"),
    (_gt(visibility=50.0), "visibility_score_o = 50 is outside"),
    (_gt(visibility=-5.0), "visibility_score_o = -5 is outside"),
    (_gt(t_z=1000.0), "translation .* implausible"),
])  # fmt: skip
def test_impossible_ground_truth_in_a_csv_is_refused(gt: IPAGroundTruth, message: str, tmp_path: Path) -> None:
    path = tmp_path / "gt.csv"
    write_ipa_csv(path, gt)
    with pytest.raises(ValueError, match=rf"gt.csv: line 2: .*{message}"):
        read_ipa_csv(path)


def test_reflection_in_a_csv_is_refused(tmp_path: Path) -> None:
    gt = _gt()
    gt.R_cam_obj[1] = gt.R_cam_obj[1] @ np.diag([1.0, 1.0, -1.0])
    write_ipa_csv(tmp_path / "gt.csv", gt)
    with pytest.raises(ValueError, match=r"gt.csv: line 3: .*det\(R\) = -1, a reflection"):
        read_ipa_csv(tmp_path / "gt.csv")


def test_csv_id_beyond_the_segmentation_range_is_refused(tmp_path: Path) -> None:
    gt = _gt()
    gt.instance_id[0] = 300
    write_ipa_csv(tmp_path / "gt.csv", gt)
    with pytest.raises(ValueError, match="id 300 exceeds 254"):
        read_ipa_csv(tmp_path / "gt.csv")


def test_utf8_bom_in_a_csv_is_accepted(tmp_path: Path) -> None:
    write_ipa_csv(tmp_path / "gt.csv", _gt())
    (tmp_path / "bom.csv").write_bytes(b"\xef\xbb\xbf" + (tmp_path / "gt.csv").read_bytes())
    assert len(read_ipa_csv(tmp_path / "bom.csv").instance_id) == 3


def _entry(**over: object) -> dict:
    e = {"R": np.eye(3).tolist(), "t": [0.0, 0.0, 1.0], "occlusion_rate": 0.2, "segmentation_id": 7}
    e.update(over)
    return e


@pytest.mark.parametrize(("entry", "message"), [
    (_entry(segmentation_id=1e30), "'segmentation_id' = 1e\\+30 is outside 0..65535"),
    (_entry(segmentation_id=-1), "is outside 0..65535"),
    (_entry(occlusion_rate=1.5), "'occlusion_rate' = 1.5 is outside \\[0, 1\\]"),
    (_entry(t=[0.0, 0.0, 1e300]), "translation .* implausible"),
    (_entry(R=(3 * np.eye(3)).tolist()), "not orthonormal"),
])  # fmt: skip
def test_impossible_siléane_ground_truth_is_refused(entry: dict, message: str, tmp_path: Path) -> None:
    path = tmp_path / "scene.json"
    path.write_text(json.dumps([_entry(), entry]))
    with pytest.raises(ValueError, match=rf"scene.json: entry 1: .*{message}"):
        read_gt_json(path)


def test_deeply_nested_json_is_a_clear_error(tmp_path: Path) -> None:
    path = tmp_path / "deep.json"
    path.write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(ValueError, match="deep.json: JSON nested too deeply"):
        read_results_json(path)


def _params(**over: object) -> IPAParameters:
    values = dict(perspective_angle=60.0, clip_start=0.5, clip_end=1.5, resolution_x=128, resolution_y=128,
                  resolution_big=128, pixel_offset_x=0, pixel_offset_y=0, number_cycles=1, shape_drop_limit=5)
    values.update(over)
    return IPAParameters(**values)


@pytest.mark.parametrize(("over", "message"), [
    ({"pixel_offset_x": 100000}, "principal point .* implausibly far outside"),
    ({"clip_start": 500.0, "clip_end": 1500.0}, "clip_end = 1500 m is implausible .*millimetres"),
    ({"resolution_x": 100000, "resolution_big": 100000}, "implausible"),
])  # fmt: skip
def test_implausible_camera_in_parameter_json_names_the_file(over: dict, message: str, tmp_path: Path) -> None:
    write_parameters(tmp_path, _params(**over))  # the writer writes what it is given
    with pytest.raises(ValueError, match=rf"parameter.json: .*{message}"):
        read_parameters(tmp_path)


def test_plausible_camera_passes() -> None:
    cam = Camera(500.0, 500.0, -20.0, 300.0, 640, 480, 0.3, 2.0)  # off-centre principal points are fine
    assert cam.check_plausible("x") is cam
