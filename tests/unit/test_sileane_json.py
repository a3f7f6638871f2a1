"""Siléane JSON reader/writer: round trips, the official sample, and errors that name file and problem."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from opnet.datasets.sileane_json import (
    SceneFileWarning,
    read_gt_json,
    read_results_json,
    read_scene_pairs,
    scene_files,
    write_gt_json,
    write_results_json,
)
from opnet.geometry import quaternion_to_matrix
from opnet.metrics import GroundTruthSet, HypothesisSet

ROT = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
HYP = {"R": ROT, "t": [0.1, 0.2, 0.3], "score": 0.9}
GT = {"R": ROT, "t": [0.1, 0.2, 0.3], "occlusion_rate": 0.25, "segmentation_id": 7}


def rotations(n: int, seed: int = 0) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return quaternion_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_round_trip_is_exact(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    gt = GroundTruthSet(rotations(5), rng.normal(size=(5, 3)), rng.random(5), np.array([65535, 64599, 3, 2, 1]))
    hyps = HypothesisSet(rotations(4, 2), rng.normal(size=(4, 3)), rng.normal(size=4), visibility=rng.random(4))
    write_gt_json(tmp_path / "gt" / "s.json", gt)
    write_results_json(tmp_path / "res" / "s.json", hyps)
    gt2, hyps2 = read_gt_json(tmp_path / "gt" / "s.json"), read_results_json(tmp_path / "res" / "s.json")
    for a, b in [(gt.R, gt2.R), (gt.t, gt2.t), (gt.occlusion_rate, gt2.occlusion_rate), (hyps.score, hyps2.score)]:
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(gt2.segmentation_id, [65535, 64599, 3, 2, 1])
    np.testing.assert_array_equal(hyps2.visibility, hyps.visibility)
    assert not list(tmp_path.rglob(".*"))  # no temporary files left behind


def test_rows_of_R_are_rows(tmp_path: Path) -> None:
    """`R[i]` of the file is row i of the matrix (x_world = R x_obj + t)."""
    hyps = read_results_json(write(tmp_path / "r.json", json.dumps([HYP])))
    np.testing.assert_array_equal(hyps.R[0] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])


def test_empty_results_list_is_valid(tmp_path: Path) -> None:
    hyps = read_results_json(write(tmp_path / "r.json", "[]"))
    assert len(hyps) == 0 and hyps.R.shape == (0, 3, 3)
    write_results_json(tmp_path / "w.json", HypothesisSet.empty())
    assert json.loads((tmp_path / "w.json").read_text()) == []
    assert len(read_gt_json(write(tmp_path / "g.json", "[]"))) == 0


def test_missing_segmentation_ids_default_to_1_to_n(tmp_path: Path) -> None:
    entry = {k: v for k, v in GT.items() if k != "segmentation_id"}
    gt = read_gt_json(write(tmp_path / "g.json", json.dumps([entry, entry])))
    np.testing.assert_array_equal(gt.segmentation_id, [1, 2])


@pytest.mark.parametrize(
    ("text", "reader", "message"),
    [
        ('[{"R": ', read_results_json, "malformed JSON"),
        ('{"R": 1}', read_results_json, "expected a JSON list"),
        ("[3]", read_results_json, "entry 0: expected a JSON object"),
        (json.dumps([{"R": ROT, "t": [0, 0, 0]}]), read_results_json, "entry 0: missing key 'score'"),
        (json.dumps([HYP, {"t": [0, 0, 0], "score": 1}]), read_results_json, "entry 1: missing key 'R'"),
        (json.dumps([{"R": ROT, "score": 1}]), read_results_json, "missing key 't'"),
        (json.dumps([{"R": ROT, "t": [0, 0, 0]}]), read_gt_json, "missing key 'occlusion_rate'"),
        (json.dumps([{**HYP, "R": ROT[:2]}]), read_results_json, "'R' must be numbers of shape (3, 3)"),
        (json.dumps([{**HYP, "t": [0, 0]}]), read_results_json, "'t' must be numbers of shape (3,)"),
        (json.dumps([{**HYP, "score": "high"}]), read_results_json, "'score' must be numbers"),
        (json.dumps([{**HYP, "score": True}]), read_results_json, "'score' must be numbers"),
        (json.dumps([{**HYP, "R": [[1, 0, 0], [0, 1, 0], [0, 0, 1.01]]}]), read_results_json, "not a rotation matrix"),
        (json.dumps([{**HYP, "R": [[1, 0, 0], [0, 1, 0], [0, 0, -1]]}]), read_results_json, "det(R) = -1"),
        ('[{"R": [[1,0,0],[0,1,0],[0,0,1]], "t": [NaN, 0, 0], "score": 1}]', read_results_json, "NaN is not a finite"),
        ('[{"R": [[1,0,0],[0,1,0],[0,0,1]], "t": [0, 0, 0], "score": Infinity}]', read_results_json, "Infinity"),
        (json.dumps([{**GT, "segmentation_id": 1.5}]), read_gt_json, "'segmentation_id' must be an integer"),
        (json.dumps([GT, {k: v for k, v in GT.items() if k != "segmentation_id"}]), read_gt_json, "entry 1: missing key"),
    ],
)
def test_bad_input_names_file_and_problem(tmp_path: Path, text: str, reader, message: str) -> None:
    path = write(tmp_path / "scene_007.json", text)
    with pytest.raises(ValueError) as err:
        reader(path)
    assert str(path) in str(err.value) and message in str(err.value)


def test_tolerates_official_rounding(tmp_path: Path) -> None:
    """The official data is orthonormal to ~1e-6; 1e-5 noise must still read."""
    R = (np.asarray(ROT) + 1e-5 * np.random.default_rng(0).normal(size=(3, 3))).tolist()
    assert len(read_results_json(write(tmp_path / "r.json", json.dumps([{**HYP, "R": R}])))) == 1


def test_missing_file_is_file_not_found(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nope.json"):
        read_results_json(tmp_path / "nope.json")


def test_writer_refuses_nan_and_keeps_old_file(tmp_path: Path) -> None:
    path = tmp_path / "r.json"
    path.write_text("[]")
    bad = HypothesisSet(np.eye(3)[None], np.array([[np.nan, 0, 0]]), np.array([1.0]))
    with pytest.raises(ValueError, match="NaN"):
        write_results_json(path, bad)
    assert path.read_text() == "[]" and len(list(tmp_path.iterdir())) == 1


def test_scene_files_accepts_upper_case_and_rejects_clashes(tmp_path: Path) -> None:
    write(tmp_path / "b.JSON", "[]")
    write(tmp_path / "a.json", "[]")
    write(tmp_path / "notes.txt", "")
    assert list(scene_files(tmp_path)) == ["a", "b"]
    write(tmp_path / "a.JSON", "[]")
    with pytest.raises(ValueError, match="scene 'a' appears twice"):
        scene_files(tmp_path)
    with pytest.raises(FileNotFoundError, match="folder not found"):
        scene_files(tmp_path / "missing")


def test_scene_pairs_missing_and_orphan_files(tmp_path: Path) -> None:
    gt_dir, res_dir = tmp_path / "gt", tmp_path / "res"
    gt_dir.mkdir(), res_dir.mkdir()
    for name in ("s1", "s2"):
        write(gt_dir / f"{name}.json", json.dumps([GT]))
    write(res_dir / "s1.json", json.dumps([HYP]))
    write(res_dir / "extra.json", json.dumps([HYP]))
    pairs, messages = pairs_and_warnings(gt_dir, res_dir, skip_missing=False)
    assert any("s2" in m and "no hypotheses" in m for m in messages)
    assert any("extra" in m and "without ground truth" in m for m in messages)
    assert list(pairs) == ["s1", "s2"] and len(pairs["s2"][1]) == 0 and len(pairs["s1"][1]) == 1
    pairs, messages = pairs_and_warnings(gt_dir, res_dir, skip_missing=True)
    assert list(pairs) == ["s1"] and any("s2" in m and "skipped" in m for m in messages)


def pairs_and_warnings(gt_dir: Path, res_dir: Path, skip_missing: bool) -> tuple[dict, list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        pairs = read_scene_pairs(gt_dir, res_dir, skip_missing=skip_missing)
    return pairs, [str(w.message) for w in caught if issubclass(w.category, SceneFileWarning)]


@pytest.mark.shared
def test_reads_the_official_sample(bunny_sample: Path) -> None:
    gt = read_gt_json(bunny_sample / "gt" / "bunny_3_070.json")
    hyps = read_results_json(bunny_sample / "results" / "bunny_3_070.json")
    assert len(gt) == 70 and gt.segmentation_id[:2].tolist() == [65535, 64599]
    assert (gt.occlusion_rate == 1.0).sum() == 10 and (gt.occlusion_rate <= 0.5).sum() == 17
    assert len(hyps) == 13 and hyps.score[0] == pytest.approx(167.828)
    pairs = read_scene_pairs(bunny_sample / "gt", bunny_sample / "results")
    assert len(pairs) == 11 and [len(g) for g, _ in pairs.values()] == list(range(70, 81))
