"""A benchmark run again does not train a run it finished: same overrides, its last step reached, tested."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml


def _run(root: Path, overrides: list[str], last_step: int, tested: bool = True) -> Path:
    (root / ".hydra").mkdir(parents=True)
    (root / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump([*overrides, f"hydra.run.dir={root}"]))
    (root / "learning_curve.csv").write_text(f"epoch,step,train_minutes\n0,{last_step // 2},1.0\n1,{last_step},2.0\n")
    if tested:
        (root / "test").mkdir()
        (root / "test" / "summary.json").write_text(json.dumps({"ap": 0.5}))
    return root


def test_a_finished_run_is_recognised_only_with_its_overrides_steps_and_test(tmp_path: Path) -> None:
    from opnet.studies.training import finished

    ov = ["object=pin", "trainer.max_steps=100"]
    assert finished(_run(tmp_path / "a", ov, 100), ov, 100)
    assert not finished(tmp_path / "a", ["object=bunny", "trainer.max_steps=100"], 100)  # another run's settings
    assert not finished(tmp_path / "a", ov, 200)  # stopped short of the steps asked for
    assert not finished(_run(tmp_path / "b", ov, 100, tested=False), ov, 100)  # crashed before its test
    assert not finished(tmp_path / "none", ov, 100)


def test_train_skips_a_finished_run_and_trains_an_unfinished_one(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from opnet.studies import training

    calls = []
    monkeypatch.setattr(training, "run_train", lambda overrides, run_dir, log: calls.append(run_dir))
    full = ["object=pin", "trainer.max_steps=100", "trainer.max_epochs=100000", "trainer.enable_progress_bar=false",
            "callbacks.learning_curve.test_every=1"]
    done = _run(tmp_path / "done", full, 100)
    training.train(["object=pin"], done, 100)
    assert calls == []
    training.train(["object=pin"], done, 150)  # more steps asked for: trained
    assert calls == [done]
