"""opnet-compare-runs (:mod:`opnet.tools.compare_runs`): arms of a multirun that differ only in their seed
become one cell, mean ± sd."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import yaml

from opnet.tools import compare_runs


def _arm(root: Path, name: str, param: str, obj: str, seed: int, ap: float) -> None:
    run = root / name
    (run / ".hydra").mkdir(parents=True)
    (run / "test").mkdir()
    choices = {"parameterization": param, "object": obj}
    (run / ".hydra" / "hydra.yaml").write_text(yaml.safe_dump({"hydra": {"runtime": {"choices": choices}}}))
    (run / ".hydra" / "config.yaml").write_text(yaml.safe_dump({"seed": seed, "task_name": "train"}))
    diagnostics = {"to_find": 200, "matched": int(200 * ap), "t_err_mm_p50": 2.0 + seed, "r_err_deg_p50": 3.0}
    (run / "test" / "summary.json").write_text(json.dumps({"ap": ap, "map": ap, "f1": ap, "diagnostics": diagnostics}))


def test_seeds_of_a_multirun_are_aggregated_into_mean_and_sample_sd(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    # seed=0,1,2 for vanilla and eve on one object, one run of ap on another: 7 arms, 3 cells
    for k, (param, aps) in enumerate((("vanilla", (0.7, 0.8, 0.9)), ("eve", (0.85, 0.9, 0.95)))):
        for seed, ap in enumerate(aps):
            _arm(tmp_path, f"{3 * k + seed}_{param}_bunny_s{seed}", param, "bunny", seed, ap)
    _arm(tmp_path, "6_ap_pin", "ap", "pin", 0, 0.5)
    assert compare_runs.main([str(tmp_path)]) == 0
    md = (tmp_path / "comparison.md").read_text()
    assert "| vanilla | 0.800 ± 0.100 (3) | – | 0.800 |" in md  # sample sd of 0.7, 0.8, 0.9
    assert "| eve | 0.900 ± 0.050 (3) | – | 0.900 |" in md
    assert "| ap | – | 0.500 | 0.500 |" in md  # a single run is its value, without a spread
    assert md.index("| vanilla |") < md.index("| eve |") < md.index("| ap |")  # the paper's order
    rows = list(csv.DictReader((tmp_path / "comparison.csv").open()))
    assert len(rows) == 7 and {r["seed"] for r in rows} == {"0", "1", "2"}
    first = next(r for r in rows if r["run"] == "0_vanilla_bunny_s0")
    assert float(first["found"]) == pytest.approx(0.7) and float(first["t_err_mm_p50"]) == pytest.approx(2.0)
    assert (tmp_path / "comparison.png").stat().st_size > 1000
    assert "0.800 ± 0.100 (3)" in capsys.readouterr().out


def test_a_folder_without_finished_arms_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert compare_runs.main([str(tmp_path)]) == 2
    assert "no finished arm" in capsys.readouterr().err
