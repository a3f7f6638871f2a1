"""opnet.studies, what the scripts share: mean ± sample sd, a run's summary, the train.py command and a
logged command's failure."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

from opnet.studies import mean_sd, mean_sd_text, merge_csv, read_summary, run_logged, train_command


def test_mean_and_sample_sd() -> None:
    assert mean_sd([0.7, 0.8, 0.9]) == pytest.approx((0.8, 0.1))
    assert mean_sd([0.5]) == (0.5, 0.0)
    assert math.isnan(mean_sd([0.5], single=float("nan"))[1])
    assert mean_sd_text([0.85, 0.9, 0.95]) == "0.900 ± 0.050"
    assert mean_sd_text([1, 2], digits=1) == "1.5 ± 0.7"


def test_read_summary_of_a_run_and_of_an_eval_folder(tmp_path: Path) -> None:
    assert read_summary(tmp_path) is None
    (tmp_path / "test").mkdir()
    (tmp_path / "test" / "summary.json").write_text(json.dumps({"ap": 0.5}))
    (tmp_path / "summary.json").write_text(json.dumps({"ap": 0.25}))
    assert read_summary(tmp_path) == {"ap": 0.5}
    assert read_summary(tmp_path, ".") == {"ap": 0.25}


def test_train_command_runs_train_py_into_the_run_folder(tmp_path: Path) -> None:
    assert train_command(["seed=1"], tmp_path / "run") == [sys.executable, "train.py", "seed=1",
                                                         f"hydra.run.dir={tmp_path / 'run'}"]


def test_a_failed_command_exits_naming_its_log(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    log = tmp_path / "logs" / "fail.log"
    with pytest.raises(SystemExit, match=f"exit 3; see {log}"):
        run_logged([sys.executable, "-c", "print('said'); raise SystemExit(3)"], log)
    assert log.read_text() == "said\n" and "$ -c" in capsys.readouterr().out


def test_merge_csv_replaces_the_rows_of_a_key(tmp_path: Path) -> None:
    path = tmp_path / "t.csv"
    merge_csv(path, ("k", "v"), [{"k": "a", "v": 1}, {"k": "b", "v": 2}], ("k",))
    rows = merge_csv(path, ("k", "v"), [{"k": "a", "v": 3}], ("k",))
    assert [(r["k"], str(r["v"])) for r in rows] == [("b", "2"), ("a", "3")]
