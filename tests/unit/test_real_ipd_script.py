"""scripts/experiments/real_ipd/real_ipd.py: its A/B table is made from the arms' own files, and a bad --holes is one line."""

from __future__ import annotations

import csv
import importlib.util
from pathlib import Path

import pytest

from opnet.paths import REPO_ROOT

spec = importlib.util.spec_from_file_location("real_ipd", REPO_ROOT / "scripts" / "experiments" / "real_ipd" / "real_ipd.py")
real_ipd = importlib.util.module_from_spec(spec)
spec.loader.exec_module(real_ipd)


def _arm(folder: Path, name: str, command: str, synthetic: float, ap: float, change: str,
         search: float | None = None) -> None:
    arm = folder / name
    arm.mkdir(parents=True)
    (arm / "README.md").write_text(f"# x\n\nThe recipe of `scripts/experiments/real_ipd/real_ipd.py` (`{command}`): ...\n\n"
                                   f"On generated piles of another seed (the training's test split): AP {synthetic:.3f}.\n")
    (arm / "change.txt").write_text(change + "\n")
    with (arm / "real_ipd.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=real_ipd.ROW_FIELDS)
        w.writeheader()
        for refine, value in (("none", ap), ("icp", ap + 0.01), *((("search", search),) if search is not None else ())):
            w.writerow({k: 0 for k in real_ipd.ROW_FIELDS} | {"visibility": "official visib_fract", "refine": refine,
                                                               "ap": value, "found": 0.2, "no_hypothesis": 0.5,
                                                               "position": 0.3})


def test_ab_table_has_one_row_per_arm_in_name_order(tmp_path: Path) -> None:
    _arm(tmp_path, "1_b", "python scripts/experiments/real_ipd/real_ipd.py --clutter 8 --run-dir x/y --out /tmp/z", 0.25, 0.043, "+ clutter",
         search=0.4)
    _arm(tmp_path, "0_a", "python scripts/experiments/real_ipd/real_ipd.py --cycles 200", 0.291, 0.0, "before")
    (tmp_path / "notes").mkdir()  # a folder without results is no arm
    lines = real_ipd.ab_table(tmp_path).splitlines()
    rows = [x for x in lines if x.startswith("| 0_a") or x.startswith("| 1_b")]
    assert [r.split(" | ")[0] for r in rows] == ["| 0_a", "| 1_b"]
    assert rows[1] == ("| 1_b | + clutter | `python scripts/experiments/real_ipd/real_ipd.py --clutter 8` | 0.250 | **0.043** | 0.053 | 0.400 | "
                       "20.0 | 50.0 | 30.0 |")  # run and output folders left out of the shown command
    assert rows[0].split(" | ")[4:7] == ["**0.000**", "0.010", ""]  # an arm made before the search: no search cell


@pytest.mark.parametrize("holes", ["0.02", "0.02:0.01", "a:b"])
def test_bad_holes_is_one_line(holes: str, capsys: pytest.CaptureFixture) -> None:
    assert real_ipd.main(["--holes", holes, "--stage", "report"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: --holes '{holes}'")


def _run(folder: Path, seed: int, aps: tuple[float, float, float, float], matched: int) -> Path:
    import json

    run = folder / f"run_s{seed}"
    (run / "tensorboard").mkdir(parents=True)
    (run / "tensorboard" / "hparams.yaml").write_text(
        f"cfg:\n  parameterization:\n    _target_: opnet.parameterizations.eve.EVEParameterization\n  seed: {seed}\n")
    (run / "test").mkdir()
    (run / "test" / "summary.json").write_text(json.dumps({"ap": aps[0]}))
    for name, ap in zip(("official", "official_icp", "official_search"), aps[1:], strict=True):
        (run / "eval_real" / name).mkdir(parents=True)
        (run / "eval_real" / name / "summary.json").write_text(
            json.dumps({"ap": ap, "diagnostics": {"matched": matched, "to_find": 15}}))
    return run


def test_seeds_table_gives_each_run_and_mean_and_sd(tmp_path: Path) -> None:
    runs = [_run(tmp_path, 0, (0.3, 0.2, 0.2, 0.6), 9), _run(tmp_path, 1, (0.4, 0.0, 0.1, 0.4), 6)]
    lines = real_ipd.seeds_table(runs).splitlines()
    assert any(x.endswith("| 0 | EVE | 0.300 | 0.200 | 0.200 | 0.600 | 60.0 |") for x in lines)
    assert lines[-1] == ("| mean ± sd (2 runs) | | | 0.350 ± 0.071 | 0.100 ± 0.141 | 0.150 ± 0.071 | 0.500 ± 0.141 | "
                         "50.0 ± 14.1 |")


def test_seeds_without_evaluations_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert real_ipd.main(["--seeds", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not one: " in err
