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
