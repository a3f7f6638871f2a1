"""`opnet-evaluate`: the official regression target through the installed command, and clean
one-line errors (exit status 2) on bad input."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from opnet.cli.evaluate import main

ROT = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
GOLDEN = {"ap": 0.797872, "map": 0.798151, "f1": 0.882159}


def command() -> list[str]:
    exe = shutil.which("opnet-evaluate")
    return [exe] if exe else [sys.executable, "-m", "opnet.cli.evaluate"]


@pytest.fixture()
def tiny(tmp_path: Path) -> Path:
    """Two scenes, s1 with a perfect hypothesis, s2 with nothing to find; results for s1 only."""
    (tmp_path / "gt").mkdir()
    (tmp_path / "res").mkdir()
    gt = {"R": ROT, "t": [0.0, 0.0, 0.0], "occlusion_rate": 0.1, "segmentation_id": 1}
    (tmp_path / "gt" / "s1.json").write_text(json.dumps([gt]))
    (tmp_path / "gt" / "s2.json").write_text(json.dumps([gt]))
    (tmp_path / "res" / "s1.json").write_text(json.dumps([{"R": ROT, "t": [0.0, 0.0, 0.0], "score": 1.0}]))
    return tmp_path


def run_main(capsys: pytest.CaptureFixture[str], *args: str | Path) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.slow
@pytest.mark.shared
def test_official_sample_through_the_command(bunny_sample: Path, tmp_path: Path) -> None:
    summary, plot = tmp_path / "out" / "summary.json", tmp_path / "pr.png"
    proc = subprocess.run(
        [*command(), "--gt", bunny_sample / "gt", "--results", bunny_sample / "results",
         "--poseutils", bunny_sample / "poseutils.json", "--max-occlusion", "0.5", "--out", summary, "--plot", plot],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "0.797872" in proc.stdout and "bunny_3_075" in proc.stdout
    data = json.loads(summary.read_text())
    assert {k: round(data[k], 6) for k in GOLDEN} == GOLDEN and round(data["recall_at_p50"], 4) == 0.7982
    assert round(data["per_scene"]["bunny_3_071"], 4) == 0.9286 and data["num_scenes"] == 11
    assert data["curve"]["thresholds"][0] is None and len(data["curve"]["precision"]) > 11
    assert plot.read_bytes()[:4] == b"\x89PNG"


def test_missing_results_count_as_empty_or_are_skipped(tiny: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out_json = tiny / "summary.json"
    code, out, err = run_main(capsys, "--gt", tiny / "gt", "--results", tiny / "res", "--object", "bracket",
                              "--out", out_json)
    assert code == 0 and "s2" in err and "no hypotheses" in err
    data = json.loads(out_json.read_text())
    assert data["per_scene"] == {"s1": 1.0, "s2": 0.0} and data["ap"] == pytest.approx(0.5)
    code, out, err = run_main(capsys, "--gt", tiny / "gt", "--results", tiny / "res", "--object", "bracket",
                              "--out", out_json, "--skip-missing")
    assert code == 0 and "skipped" in err
    assert json.loads(out_json.read_text())["per_scene"] == {"s1": 1.0}


def test_results_without_ground_truth_are_ignored(tiny: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tiny / "res" / "s2.json").write_text("[]")
    (tiny / "res" / "orphan.JSON").write_text("[]")
    code, out, err = run_main(capsys, "--gt", tiny / "gt", "--results", tiny / "res", "--object", "zbracket")
    assert code == 0 and "orphan" in err and "without ground truth" in err and "orphan" not in out


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("[{", "malformed JSON"),
        (json.dumps([{"R": ROT, "t": [0, 0, 0]}]), "missing key 'score'"),
        (json.dumps([{"R": [[1, 0, 0], [0, 1, 0], [0, 0, 2]], "t": [0, 0, 0], "score": 1}]), "not a rotation"),
        ('[{"R": [[1,0,0],[0,1,0],[0,0,1]], "t": [0, NaN, 0], "score": 1}]', "NaN"),
    ],
)
def test_bad_results_file_exits_2_naming_it(tiny: Path, capsys: pytest.CaptureFixture[str], content: str, message: str) -> None:
    bad = tiny / "res" / "s1.json"
    bad.write_text(content)
    code, out, err = run_main(capsys, "--gt", tiny / "gt", "--results", tiny / "res", "--object", "bracket")
    lines = err.strip().splitlines()
    assert code == 2 and str(bad) in lines[-1] and message in lines[-1] and "Traceback" not in err


def test_empty_results_list_is_valid(tiny: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tiny / "res" / "s1.json").write_text("[]")
    (tiny / "res" / "s2.json").write_text("[]")
    code, out, err = run_main(capsys, "--gt", tiny / "gt", "--results", tiny / "res", "--object", "pin", "--quiet")
    assert code == 0 and "AP     0.000000" in out and err == ""


def test_unknown_object_lists_the_available_ones(tiny: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run_main(capsys, "--gt", tiny / "gt", "--results", tiny / "res", "--object", "teapot")
    assert code == 2 and "unknown object 'teapot'" in err and "bracket" in err and "ring_screw" in err


def test_bad_poseutils_and_missing_folder(tiny: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pu = tiny / "poseutils.json"
    pu.write_text(json.dumps({"type": "AffinePoseUtils", "Lambda": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}))
    code, _, err = run_main(capsys, "--gt", tiny / "gt", "--results", tiny / "res", "--poseutils", pu)
    assert code == 2 and str(pu) in err and "distance_threshold" in err
    code, _, err = run_main(capsys, "--gt", tiny / "nowhere", "--results", tiny / "res", "--object", "bracket")
    assert code == 2 and "nowhere" in err and "not found" in err


def test_diagnose_counts_the_hypotheses_the_ap_counts_and_turns_the_orientation_misses(
        tiny: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """--diagnose: where the misses went and the turns of the orientation misses, printed and in --out;
    with --max-nb-results 1 only the best-scored hypothesis is there (here the one turned over)."""
    over = [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]]  # a half turn about x
    (tiny / "res" / "s1.json").write_text(json.dumps([{"R": over, "t": [0.0, 0.0, 0.0], "score": 0.9},
                                                      {"R": ROT, "t": [0.0, 0.0, 0.0], "score": 0.5}]))
    args = ["--gt", tiny / "gt", "--results", tiny / "res", "--object", "bracket", "--quiet", "--diagnose"]
    code, out, _ = run_main(capsys, *args, "--out", tiny / "all.json")
    summary = json.loads((tiny / "all.json").read_text())
    assert code == 0 and summary["diagnostics"]["matched"] == 1 and summary["orientation_misses"]["count"] == 0
    assert "Orientation misses: none" in out
    code, out, _ = run_main(capsys, *args, "--max-nb-results", "1", "--out", tiny / "best.json")
    summary = json.loads((tiny / "best.json").read_text())
    assert code == 0 and summary["diagnostics"]["matched"] == 0 and summary["diagnostics"]["orientation"] == 1
    turns = summary["orientation_misses"]
    assert turns["histogram"] == [0, 0, 0, 0, 0, 1] and turns["modes"][0]["axis"] == pytest.approx([1, 0, 0])
    assert "100% a 180° turn about (+1.00, +0.00, +0.00)" in out


@pytest.mark.shared
def test_object_from_config_with_shared_mesh(bunny_sample: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`--object bunny` builds Λ and δ from conf/object/bunny.yaml (the mesh in ../shared): close
    to, but not exactly, the official poseutils.json (centroid offset, principal axes)."""
    code, out, err = run_main(capsys, "--gt", bunny_sample / "gt", "--results", bunny_sample / "results",
                              "--object", "bunny", "--quiet")
    assert code == 0, err
    ap = float(out.split("AP")[1].split()[0])
    assert ap == pytest.approx(GOLDEN["ap"], abs=0.01)


def test_broken_object_config_names_the_yaml(
    tiny: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    conf = tiny / "conf"
    (conf / "object").mkdir(parents=True)
    (conf / "object" / "broken.yaml").write_text("name: broken\nmesh: ${paths.nowhere}/x.stl\n")
    (conf / "object" / "odd.yaml").write_text("name: odd\ncolour: red\n")
    monkeypatch.setattr("opnet.cli.evaluate.config_dir", lambda: conf)
    for name, message in (("broken", "cannot read object config"), ("odd", "unknown keys")):
        code, _, err = run_main(capsys, "--gt", tiny / "gt", "--results", tiny / "res", "--object", name)
        assert code == 2 and f"{name}.yaml" in err and message in err and "Traceback" not in err
