"""scripts/experiments/real_ipd/search_ab.py: a folder that is no run, or --report without evaluations, is one line."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from opnet.paths import REPO_ROOT
from opnet.studies.ipd import SEARCH_DECODING

spec = importlib.util.spec_from_file_location("search_ab", REPO_ROOT / "scripts" / "experiments" / "real_ipd" / "search_ab.py")
search_ab = importlib.util.module_from_spec(spec)
spec.loader.exec_module(search_ab)


def test_a_folder_without_checkpoints_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert search_ab.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a run folder of scripts/experiments/real_ipd/real_ipd.py" in err


def test_report_without_evaluations_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    (tmp_path / "checkpoints").mkdir()
    assert search_ab.main([str(tmp_path), "--report", "--out", str(tmp_path / "ab.md")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "holds no evaluation" in err and not (tmp_path / "ab.md").exists()


def test_every_arm_names_its_overrides_and_the_last_is_the_recipe() -> None:
    names = [a[0] for a in search_ab.ARMS]
    assert names[0] == "none" and names[-1] == "recipe" and len(set(names)) == len(names)
    assert search_ab.ARMS[-1][2] == ["refine=search", *SEARCH_DECODING]


def test_each_variant_is_the_recipe_with_one_more_override() -> None:
    recipe = search_ab.ARMS[-1][2]
    for name, _, overrides in search_ab.VARIANTS:
        assert overrides[:-1] == recipe and overrides[-1] not in recipe, name
    assert not {v[0] for v in search_ab.VARIANTS} & {a[0] for a in search_ab.ARMS}


def test_a_generated_run_that_is_no_run_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    (tmp_path / "run" / "checkpoints").mkdir(parents=True)
    assert search_ab.main([str(tmp_path / "run"), "--generated-run", str(tmp_path / "gone")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--generated-run" in err and "not a run folder" in err
