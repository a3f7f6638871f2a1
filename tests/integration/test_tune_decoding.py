"""opnet-tune-decoding --write: the tuned decoding travels in a checkpoint that every command reads."""

from __future__ import annotations

from pathlib import Path

import pytest

from opnet.cli.build import load_checkpoint
from opnet.tools import tune_decoding as tune


def test_a_written_checkpoint_decodes_with_the_tuned_settings_and_keeps_its_weights(checkpoint: Path,
                                                                                    tmp_path: Path) -> None:
    system, _ = load_checkpoint(checkpoint)
    before = tune.current_settings(system.parameterization)
    settings = {**before, "averaging": True, "score": "p" if before["score"] != "p" else "p*v", "eps": 0.75,
                "min_samples": 2, "cluster_score": "max", "min_visibility": 0.2}
    dest = tmp_path / "tuned.ckpt"
    tune.write_tuned_checkpoint(checkpoint, dest, settings)
    tuned, cfg = load_checkpoint(dest)
    assert tune.current_settings(tuned.parameterization) == settings
    assert cfg.parameterization.averaging_eps == 0.75 and cfg.parameterization.score == settings["score"]
    for name, value in system.state_dict().items():
        assert (tuned.state_dict()[name] == value).all(), name
    assert tune.current_settings(load_checkpoint(checkpoint)[0].parameterization) == before  # source untouched


def test_writing_onto_the_tuned_checkpoint_itself_is_refused(checkpoint: Path) -> None:
    system, _ = load_checkpoint(checkpoint)
    with pytest.raises(ValueError, match="is the checkpoint being tuned"):
        tune.write_tuned_checkpoint(checkpoint, checkpoint, tune.current_settings(system.parameterization))


def test_stride_records_every_kth_scene(checkpoint: Path) -> None:
    whole = tune.RecordedSplit.record(str(checkpoint), "train")
    every2 = tune.RecordedSplit.record(str(checkpoint), "train", stride=2)
    n = sum(len(g) for g in whole.gts)
    assert sum(len(g) for g in every2.gts) == (n + 1) // 2
    assert every2.gts[0][0] is not None and len(whole.scenes(tune.current_settings(whole.parameterization))) == n


def test_the_turns_are_searched_from_the_turned_outputs_recorded(checkpoint: Path) -> None:
    """Recorded with every quarter turn, a split decodes each ``turns`` as the system decoding it does, and the
    search tries 1, 2 and 4; recorded as configured (one pass), the search keeps the configured turns."""
    from opnet.cli.build import build_datamodule
    from opnet.evaluation import predict_scenes

    split = tune.RecordedSplit.record(str(checkpoint), "val", turns=(1, 2, 3))
    assert sorted(split.turned) == [1, 2, 3] and all(len(v) == len(split.outputs) for v in split.turned.values())
    settings = {**tune.current_settings(split.parameterization), "turns": 4, "averaging": True}
    ours = list(split.scenes(settings).values())
    system, cfg = load_checkpoint(checkpoint)
    system.parameterization = tune.decoder(system.parameterization, settings)
    dm = build_datamodule(cfg, system.parameterization.obj, train=False)
    dm.setup("test")
    theirs = list(predict_scenes(system, dm.val_dataloader()).values())
    assert len(ours) == len(theirs) > 0
    assert any(len(h) != len(h1) for (_, h), (_, h1) in zip(ours, split.scenes({**settings, "turns": 1}).values()))
    for (_, a), (_, b) in zip(ours, theirs, strict=True):
        assert len(a) == len(b)
        assert abs(a.t - b.t).max(initial=0.0) < 1e-6 and abs(a.score - b.score).max(initial=0.0) < 1e-6
    _, rows = tune.search([split], rounds=1)
    assert {r["turns"] for r in rows} == {1, 2, 4}
    _, rows = tune.search([tune.RecordedSplit.record(str(checkpoint), "val")], rounds=1)
    assert {r["turns"] for r in rows} == {1}


def _copy(src: Path, dest: Path) -> Path:
    dest.write_bytes(src.read_bytes())
    return dest


def test_tuning_in_place_writes_a_better_decoding_into_the_checkpoint_and_keeps_a_worse_one_out(
        checkpoint: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """What a recipe's ``tune_decoding`` does after training: the checkpoint itself decodes with the setting the
    validation search found better, its weights untouched; a search that finds nothing better leaves it as it was."""
    import json

    system, _ = load_checkpoint(checkpoint)
    configured = tune.current_settings(system.parameterization)
    better = {**configured, "averaging": True, "eps": 0.75, "min_visibility": 0.3}
    rows = [{**configured, "ap": 0.40}, {**better, "ap": 0.55}]
    from opnet.cli import decoding_search

    monkeypatch.setattr(decoding_search, "search", lambda splits, verbose=True: (better, rows))
    ckpt = _copy(checkpoint, tmp_path / "epoch001-ap0.4000.ckpt")
    record = tune.tune_in_place(ckpt, 2, tmp_path / "tune_val")
    tuned, _ = load_checkpoint(ckpt)
    assert tune.current_settings(tuned.parameterization) == better
    for name, value in system.state_dict().items():
        assert (tuned.state_dict()[name] == value).all(), name
    assert record == json.loads((tmp_path / "tune_val" / tune.TUNED_RECORD).read_text())
    assert record["changed"] == {k: v for k, v in better.items() if configured[k] != v} and record["ap_chosen"] == 0.55
    assert (tmp_path / "tune_val" / "decoding_sweep.md").is_file() and sorted(tmp_path.glob("*.tuning")) == []
    assert "validation AP 0.400 -> 0.550" in tune.tuned_line(record)

    rows = [{**configured, "ap": 0.40}, {**better, "ap": 0.40}]  # a tie: the configured decoding stays
    kept = _copy(checkpoint, tmp_path / "epoch002-ap0.4000.ckpt")
    record = tune.tune_in_place(kept, 2, tmp_path / "tune_kept")
    assert record["changed"] == {} and kept.read_bytes() == checkpoint.read_bytes()
    assert "kept as configured" in tune.tuned_line(record)


def test_train_py_tunes_the_best_checkpoint_before_its_test(tiny_dataset: Path, tmp_path: Path) -> None:
    """``tune_decoding=K``: train.py searches the decoding on its validation split after training and tests the
    checkpoint as tuned; a bad value stops before any training, naming the key."""
    import json

    from omegaconf import OmegaConf

    from opnet.cli import train as train_cli

    from conftest import tiny_train_cfg

    out = tmp_path / "run"
    result = train_cli.run(tiny_train_cfg(tiny_dataset, out, ["parameterization=vanilla", "trainer.precision=32",
                                                              "tune_decoding=1"]))
    record = json.loads((out / "tune_val" / tune.TUNED_RECORD).read_text())
    assert record["scenes"] > 0 and record["checkpoint"] == Path(result["checkpoint"]).name
    tested, _ = load_checkpoint(result["checkpoint"])
    assert tune.current_settings(tested.parameterization) == (record["chosen"] if record["changed"]
                                                              else record["configured"])
    for bad in (0, True, 1.5):
        cfg = tiny_train_cfg(tiny_dataset, tmp_path / f"bad{bad}", [])
        OmegaConf.update(cfg, "tune_decoding", bad)
        with pytest.raises(ValueError, match=r"tune_decoding=.*expected null .* whole number >= 1"):
            train_cli.run(cfg)
        assert not (tmp_path / f"bad{bad}" / "checkpoints").exists()


@pytest.mark.parametrize("averaging", [True, False])
def test_the_decoding_arguments_give_eval_py_the_settings_they_spell(checkpoint: Path, averaging: bool) -> None:
    """``decoding_arguments``: what a benchmark passes eval.py to score a decoding; read as eval.py reads its
    ``+decoding.*`` overrides, they decode with those settings."""
    from omegaconf import OmegaConf

    system, _ = load_checkpoint(checkpoint)
    settings = {**tune.current_settings(system.parameterization), "averaging": averaging, "eps": 0.75,
                "min_samples": 2, "cluster_score": "max", "min_visibility": 0.3, "score": "p*v", "turns": 2}
    given = OmegaConf.to_container(OmegaConf.from_dotlist([a.lstrip("+") for a in tune.decoding_arguments(settings)]))
    system.set_decoding(system.settings.decoding.with_overrides(given["decoding"]))
    got = tune.current_settings(system.parameterization)
    assert {k: got[k] for k in settings if averaging or k not in tune.AVERAGING_KEYS} == \
        {k: v for k, v in settings.items() if averaging or k not in tune.AVERAGING_KEYS}


def test_root_records_every_scene_of_the_piles_given_instead_of_the_runs_split(checkpoint: Path,
                                                                              tiny_dataset: Path) -> None:
    """``--root``: validation piles of their own. Given the run's own dataset, every scene of it is recorded (its
    train, val and test shares together), with the ground truth the split's own recording reads."""
    from opnet.cli.build import build_datamodule

    system, cfg = load_checkpoint(checkpoint)
    dm = build_datamodule(cfg, system.parameterization.obj, train=False)
    dm.setup("test")
    shares = {k: len(v) for k, v in dm.splits.items()}
    assert shares["val"] < sum(shares.values())
    whole = tune.RecordedSplit.record(str(checkpoint), "val", root=tiny_dataset)
    assert sum(len(g) for g in whole.gts) == sum(shares.values())
    mark = lambda rec: {(len(g), round(float(g.t.sum()), 6)) for batch in rec.gts for g in batch}  # noqa: E731
    assert mark(tune.RecordedSplit.record(str(checkpoint), "val")) < mark(whole)


def test_a_missing_root_is_one_line_naming_it(checkpoint: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "no_piles"
    assert tune.main(["--ckpt", str(checkpoint), "--root", str(missing), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {missing}: dataset folder not found (--root)"]
    assert not (tmp_path / "o" / "decoding_sweep.csv").exists()
