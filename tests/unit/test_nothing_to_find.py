"""A split with nothing to find: its AP stays 1.0 (the official convention, recall 1 when nothing is
to be found) but is reported as a convention, with its false positives, not as a score; scenes with
nothing to find among others are counted, in the printed summary and in summary.json. Scenes are
real Siléane ground-truth and results files on disk, read as eval.py and opnet-evaluate read them."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from opnet.cli.console import result_summary
from opnet.cli.evaluate import main as evaluate_main
from opnet.datasets.sileane_json import read_scene_pairs, write_gt_json, write_results_json
from opnet.metrics.bregier import evaluate_scenes
from opnet.metrics.diagnostics import diagnose
from opnet.metrics.records import GroundTruthSet, HypothesisSet
from opnet.objects import builtin_object

NOTE_ALL = "nothing to find in this split: AP is reported as 1.0 by convention"


@pytest.fixture(scope="module")
def pin():
    return builtin_object("pin")


def _write_scenes(root: Path, scenes: dict[str, tuple[int, int, int]]) -> tuple[Path, Path]:
    """``root/gt`` and ``root/results``: per scene (parts to find, parts hidden past the occlusion
    limit, false positives); every part to find has an exact hypothesis, every false positive lies a
    metre from every part."""
    for name, (visible, hidden, false) in scenes.items():
        n = visible + hidden
        t = np.array([[0.1 * k, 0.0, 1.0] for k in range(n)]).reshape(-1, 3)
        R = np.repeat(np.eye(3)[None], n, axis=0)
        write_gt_json(root / "gt" / f"{name}.json",
                      GroundTruthSet(R, t, np.array([0.1] * visible + [0.9] * hidden), np.arange(1, n + 1)))
        far = np.array([[0.05 * k, 1.0, 2.0] for k in range(false)]).reshape(-1, 3)
        hyp_t = np.concatenate([t[:visible], far])
        m = len(hyp_t)
        write_results_json(root / "results" / f"{name}.json",
                           HypothesisSet(np.repeat(np.eye(3)[None], m, axis=0), hyp_t, np.linspace(0.9, 0.1, m)))
    return root / "gt", root / "results"


def _evaluate(root: Path, scenes: dict[str, tuple[int, int, int]], obj) -> tuple[dict, list[str]]:
    """The summary dict of summary.json and the lines eval.py prints, for these scenes."""
    pairs = read_scene_pairs(*_write_scenes(root, scenes))
    summary = evaluate_scenes(pairs, obj.pose_space)
    result = summary.to_dict()
    result["diagnostics"] = diagnose(pairs, obj.pose_space, obj.diameter).to_dict()
    result.update(split="test", scenes=len(pairs))
    result = json.loads(json.dumps(result))  # as written to summary.json
    return result, result_summary(result, str(root / "ap_table.md"), 1.0, verbose=False)


def _counts(summary: dict) -> tuple[int, int, int]:
    """(to find, scenes with nothing to find, their false positives) of a summary dict."""
    return summary["to_find"], summary["scenes_nothing_to_find"], summary["false_positives_nothing_to_find"]


def test_a_split_with_nothing_to_find_is_a_convention_not_a_score(tmp_path: Path, pin) -> None:
    scenes = {"empty_a": (0, 0, 50), "empty_b": (0, 0, 30), "hidden": (0, 2, 29)}  # 109 false positives
    result, lines = _evaluate(tmp_path, scenes, pin)
    assert result["ap"] == 1.0 and result["f1"] == 1.0  # the official numbers, kept
    assert _counts(result) == (0, 3, 109)
    assert f"  {NOTE_ALL}, 109 false positives" in lines
    assert not any("AP 1.0000" in line or "F1 1.0000" in line for line in lines), lines  # no score printed


def test_scenes_with_nothing_to_find_among_others_are_counted(tmp_path: Path, pin) -> None:
    result, lines = _evaluate(tmp_path, {"a": (2, 0, 0), "b": (2, 1, 0), "empty": (0, 0, 5)}, pin)
    assert _counts(result) == (4, 1, 5)
    scores = next(i for i, line in enumerate(lines) if line.startswith("  AP "))
    assert lines[scores + 1] == ("  1 of 3 scenes had nothing to find (recall 1 there by convention), "
                                 "5 false positives in them")
    assert not any(NOTE_ALL in line for line in lines)


def test_a_split_with_parts_everywhere_has_no_note(tmp_path: Path, pin) -> None:
    result, lines = _evaluate(tmp_path, {"a": (2, 0, 3), "b": (1, 1, 0)}, pin)
    assert _counts(result) == (3, 0, 0)
    assert lines[0] == "test 2 scenes, found 3 of 3 (100.0%)" and lines[1].startswith("  AP ")
    assert not any("nothing to find" in line for line in lines)


def test_opnet_evaluate_prints_and_writes_the_empty_case(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt, results = _write_scenes(tmp_path, {"empty_a": (0, 0, 4), "empty_b": (0, 0, 3)})
    out = tmp_path / "summary.json"
    assert evaluate_main(["--gt", str(gt), "--results", str(results), "--object", "pin", "--out", str(out)]) == 0
    assert f"{NOTE_ALL}, 7 false positives" in capsys.readouterr().out
    written = json.loads(out.read_text())
    assert written["ap"] == 1.0 and _counts(written) == (0, 2, 7)


def test_the_evaluators_table_gives_no_scores_for_a_split_with_nothing_to_find(tmp_path: Path, pin,
                                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """opnet-evaluate and ap_table.md printed F1 1.0 and R@P99 1.0 beside the note (935 false positives)."""
    gt, results = _write_scenes(tmp_path, {"empty_a": (0, 0, 4), "empty_b": (0, 0, 3)})
    assert evaluate_main(["--gt", str(gt), "--results", str(results), "--object", "pin"]) == 0
    printed = capsys.readouterr().out
    assert f"{NOTE_ALL}, 7 false positives" in printed
    for metric in ("AP", "MAP", "F1", "R@P50", "R@P99"):
        assert not re.search(rf"^  {re.escape(metric)} +1\.0", printed, re.M), printed
    table = evaluate_scenes(read_scene_pairs(gt, results), pin.pose_space).table()
    assert "1 by convention" in table and not re.search(r"^  F1 ", table, re.M)
    some = evaluate_scenes(read_scene_pairs(*_write_scenes(tmp_path / "some", {"a": (1, 0, 0), "e": (0, 0, 2)})),
                           pin.pose_space).table()
    assert re.search(r"^  F1     \d\.\d+$", some, re.M)  # scores where something was to find
