"""Training's numbers, the console tools' variant settings and inputs, refused in one line naming the key or file.

Each of these was found by the fuzz pass (scripts/dev/fuzz_inputs.py, results/fuzz.md) and failed
before its fix: ``loss.lambda_xy=abc`` and ``seed=abc`` said only Python's ``could not convert`` /
``invalid literal``; ``data.val_fraction=-0.1`` trained, ``data.val_fraction=1.5`` ended in the
sampler's ``num_samples=0``; ``data.batch_size=0`` wrote the logger's files before the data loader
refused it; a variant setting given twice kept the last silently; a file given as the dataset was
"dataset folder not found", a folder or FIFO given as the checkpoint "checkpoint not found".
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import pytest

from opnet.arguments import variant_settings
from opnet.data.scene_data import SceneData
from opnet.datasets.autodetect import open_dataset
from opnet.losses import MultiTaskLoss
from opnet.objects import builtin_object


@pytest.mark.parametrize("value", ["abc", -1, float("nan"), None, True])
def test_a_loss_weight_that_is_no_number_at_or_above_zero_is_named(value: Any) -> None:
    with pytest.raises(ValueError, match=r"^loss\.lambda_xy must be a number >= 0, got "):
        MultiTaskLoss(lambda_xy=value)


def test_loss_weights_take_numbers() -> None:
    assert MultiTaskLoss(lambda_xy=0, lambda_z=2.5).lambda_xy == 0.0


@pytest.mark.parametrize(("settings", "named"), [
    ({"batch_size": 0}, "data.batch_size=0"),
    ({"batch_size": 2.5}, "data.batch_size=2.5"),
    ({"batch_size": "abc"}, "data.batch_size='abc'"),
    ({"num_workers": -1}, "data.num_workers=-1"),
    ({"seed": "x"}, "data.seed='x'"),
    ({"val_fraction": -0.1}, "data.val_fraction=-0.1"),
    ({"val_fraction": 1.5}, "data.val_fraction=1.5"),
    ({"test_fraction": 1}, "data.test_fraction=1"),
    ({"val_fraction": "a"}, "data.val_fraction='a'"),
    ({"val_fraction": 0.6, "test_fraction": 0.4}, "data.val_fraction=0.6 and data.test_fraction=0.4 leave no scene"),
])  # fmt: skip
def test_the_data_modules_numbers_are_checked_when_it_is_built(settings: dict, named: str, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="^" + re.escape(named)):
        SceneData(builtin_object("zbracket"), tmp_path, **settings)


def test_the_data_modules_bounds_keep_what_trains() -> None:
    dm = SceneData(builtin_object("zbracket"), "x", val_fraction=0.0, test_fraction=0.0, batch_size=1,
                         num_workers=0, seed=3)  # fmt: skip
    assert (dm.val_fraction, dm.batch_size) == (0.0, 1)
    assert SceneData(builtin_object("zbracket"), "x", seed=None).seed is None  # seed=null: a random split


def test_train_names_a_seed_that_is_no_whole_number(tiny_dataset: Path, tmp_path: Path) -> None:
    from conftest import tiny_train_cfg

    from opnet.cli import train as train_cli

    with pytest.raises(ValueError, match=r"^seed='abc': expected a whole number"):
        train_cli.run(tiny_train_cfg(tiny_dataset, tmp_path, ["seed=abc"]))
    assert not (tmp_path / "checkpoints").exists()


def test_a_variant_setting_given_twice_is_refused() -> None:
    with pytest.raises(ValueError, match="--variant v:threshold=0.2,threshold=0.3: 'threshold' is given twice"):
        variant_settings("v:threshold=0.2,threshold=0.3", "threshold=0.2,threshold=0.3", ["threshold"], "--variant")
    assert variant_settings("v:threshold=0.2", "threshold=0.2", ["threshold"], "--variant") == {"threshold": 0.2}


def test_a_file_given_as_a_dataset_is_named_a_file(tmp_path: Path) -> None:
    (tmp_path / "a_file").write_text("x\n")
    with pytest.raises(ValueError, match="a_file: a file, not a dataset folder"):
        open_dataset(tmp_path / "a_file")
    with pytest.raises(FileNotFoundError, match="gone: dataset folder not found"):
        open_dataset(tmp_path / "gone")


def test_a_folder_or_fifo_given_as_a_checkpoint_is_named_so(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from opnet.cli.build import read_checkpoint
    from opnet.tools import diagnose_sources

    (tmp_path / "folder.ckpt").mkdir()
    os.mkfifo(tmp_path / "fifo.ckpt")
    for name, kind in (("folder.ckpt", "a folder"), ("fifo.ckpt", "a FIFO")):
        with pytest.raises(ValueError, match=f"{name}: not a regular file \\({kind}\\)"):
            read_checkpoint(tmp_path / name)
        assert diagnose_sources.main(["--ckpt", str(tmp_path / name), "--out", str(tmp_path / "out")]) == 2
        assert f"{name}: not a regular file ({kind})" in capsys.readouterr().err
    with pytest.raises(FileNotFoundError, match="gone.ckpt: checkpoint not found"):
        read_checkpoint(tmp_path / "gone.ckpt")
    assert not (tmp_path / "out").exists()


def test_a_file_given_as_the_training_dataset_of_record_trained_clip_is_named_a_file(tmp_path: Path) -> None:
    from opnet.tools.record_trained_clip import datasets_clip

    (tmp_path / "a_file").write_text("x\n")
    with pytest.raises(ValueError, match="a_file: a file, not a dataset folder"):
        datasets_clip([tmp_path / "a_file"])
