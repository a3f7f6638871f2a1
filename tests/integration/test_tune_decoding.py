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
