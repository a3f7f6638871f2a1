"""Lightning callbacks of opnet: the learning curve (AP against minutes of training)."""

from __future__ import annotations

import csv
import io
import logging
import time
from pathlib import Path
from typing import Any

import lightning as L
import torch

from opnet.fileio.atomic import write_text_atomic

log = logging.getLogger(__name__)

CURVE_FIELDS = ("epoch", "step", "train_minutes", "images", "val_ap", "test_ap")


class LearningCurve(L.Callback):
    """Records, at every validation, the training time so far and the validation AP (and, every
    ``test_every`` validations, the AP on the test split) into ``<dir>/learning_curve.csv``.

    Training time is the wall time spent in training epochs (data loading, forward, backward,
    optimizer), without validation, testing or checkpointing; it survives a resume (the callback
    state goes into the checkpoint). The test AP is only reported, never used to select a model.

    Args:
        dirpath: where the CSV goes (the run directory).
        test_every: evaluate the test split every this many validations (0: never).
    """

    def __init__(self, dirpath: str | Path, test_every: int = 0) -> None:
        self.dirpath = Path(dirpath)
        self.test_every = int(test_every)
        self.rows: list[dict[str, Any]] = []
        self.train_seconds = 0.0
        self.images = 0
        self._epoch_start: float | None = None

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._epoch_start = time.perf_counter()

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs: Any, batch: Any,
                           batch_idx: int) -> None:  # fmt: skip
        self.images += len(batch)

    def on_validation_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._pause()

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._pause()

    def _pause(self) -> None:
        if self._epoch_start is not None:
            self.train_seconds += time.perf_counter() - self._epoch_start
            self._epoch_start = None

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or not trainer.is_global_zero:
            return
        val = trainer.callback_metrics.get("val/ap")
        row = {
            "epoch": trainer.current_epoch, "step": trainer.global_step,
            "train_minutes": round(self.train_seconds / 60, 4), "images": self.images,
            "val_ap": float(val) if val is not None else float("nan"), "test_ap": "",
        }  # fmt: skip
        if self.test_every and (len(self.rows) + 1) % self.test_every == 0:
            row["test_ap"] = self._test_ap(trainer, pl_module)
        self.rows.append(row)
        self._write()
        # training goes on after a mid-epoch validation: restart the clock
        self._epoch_start = time.perf_counter() if trainer.state.fn == "fit" else None

    @torch.no_grad()
    def _test_ap(self, trainer: L.Trainer, pl_module: L.LightningModule) -> float:
        from opnet.metrics.bregier import evaluate_scenes
        from opnet.system import predict_split

        dm = trainer.datamodule
        was_training = pl_module.training
        scenes = predict_split(pl_module, dm.test_dataloader())
        pl_module.train(was_training)
        space = pl_module.parameterization.obj.pose_space
        return float(evaluate_scenes(scenes, space, max_occlusion=pl_module.hparams.max_occlusion).ap)

    def _write(self) -> None:
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=CURVE_FIELDS)
        writer.writeheader()
        writer.writerows(self.rows)
        write_text_atomic(self.dirpath / "learning_curve.csv", buf.getvalue())

    def state_dict(self) -> dict[str, Any]:
        return {"rows": self.rows, "train_seconds": self.train_seconds, "images": self.images}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.rows = list(state_dict.get("rows", []))
        self.train_seconds = float(state_dict.get("train_seconds", 0.0))
        self.images = int(state_dict.get("images", 0))


__all__ = ["CURVE_FIELDS", "LearningCurve"]
