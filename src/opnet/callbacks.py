"""Lightning callbacks of opnet: the learning curve (AP against minutes of training) and the
exponential moving average of the weights."""

from __future__ import annotations

import csv
import io
import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
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

    def _test_ap(self, trainer: L.Trainer, pl_module: L.LightningModule) -> float:
        from opnet.evaluation import AveragePrecision, evaluate

        was_training = pl_module.training
        ema = next((c for c in trainer.callbacks if isinstance(c, WeightEMA)), None)  # type: ignore[attr-defined]
        space = pl_module.parameterization.obj.pose_space
        with ema.applied(pl_module) if ema is not None else nullcontext():  # the weights validation scored
            summary, = evaluate(pl_module, trainer.datamodule.test_dataloader(),
                                [AveragePrecision(space, pl_module.max_occlusion)])
        pl_module.train(was_training)
        return float(summary.ap)

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


class WeightEMA(L.Callback):
    """An exponential moving average of the weights (parameters and floating-point buffers, the
    BatchNorm statistics included), updated after every optimizer step:
    ``avg <- d avg + (1 - d) w`` with ``d = min(decay, (1 + n) / (10 + n))`` after ``n`` updates (the
    short memory of the first steps keeps the random initialization out of the average).

    Validation, the learning curve's test scores and the checkpoints use the averaged weights: a
    checkpoint's ``state_dict`` holds them, so eval.py, predict.py and export.py read the averaged
    model like any other; the training weights travel under ``opnet_weight_ema`` for a resume.
    Why (results/dense/ab.md): on dense piles the validation AP of the raw weights swings between
    epochs while the learning rate is high, so the model chosen by it is partly chance.

    Args:
        decay: the average's decay per step, in [0, 1); 0 turns the callback off (the paper).
    """

    KEY = "opnet_weight_ema"

    def __init__(self, decay: float = 0.0) -> None:
        if isinstance(decay, bool) or not isinstance(decay, (int, float)) or not 0.0 <= float(decay) < 1.0:
            raise ValueError(f"callbacks.weight_ema.decay={decay!r}, expected a number in [0, 1) (0: off)")
        self.decay = float(decay)
        self.updates = 0
        self.average: dict[str, torch.Tensor] | None = None
        self._swapped = False

    @property
    def active(self) -> bool:
        return self.decay > 0.0

    def _tracked(self, pl_module: L.LightningModule) -> dict[str, torch.Tensor]:
        """The module's floating-point state by name (tensors shared with the module)."""
        return {k: v for k, v in pl_module.state_dict(keep_vars=True).items() if v.is_floating_point()}

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self.active and self.average is None:
            self.average = {k: v.detach().float().clone() for k, v in self._tracked(pl_module).items()}

    @torch.no_grad()
    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs: Any, batch: Any,
                           batch_idx: int) -> None:  # fmt: skip
        if self.average is None or self._swapped:
            return
        d = min(self.decay, (1.0 + self.updates) / (10.0 + self.updates))
        for name, value in self._tracked(pl_module).items():
            self.average[name].lerp_(value.detach().float(), 1.0 - d)
        self.updates += 1

    @torch.no_grad()
    def _swap(self, pl_module: L.LightningModule) -> None:
        assert self.average is not None
        for name, value in self._tracked(pl_module).items():
            held = value.detach().float().clone()
            value.data.copy_(self.average[name].to(value.dtype))
            self.average[name] = held
        self._swapped = not self._swapped

    @contextmanager
    def applied(self, pl_module: L.LightningModule) -> Iterator[None]:
        """Within the block the module holds the averaged weights (nothing changes where it
        already does, or before the first update)."""
        swap = self.average is not None and not self._swapped
        if swap:
            self._swap(pl_module)
        try:
            yield
        finally:
            if swap:
                self._swap(pl_module)

    def on_validation_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self.average is not None and not self._swapped:
            self._swap(pl_module)

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if self._swapped:
            self._swap(pl_module)

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        """The module keeps the averaged weights after fitting (what the checkpoints hold)."""
        if self.average is not None and not self._swapped:
            self._swap(pl_module)

    def on_save_checkpoint(self, trainer: L.Trainer, pl_module: L.LightningModule,
                           checkpoint: dict[str, Any]) -> None:  # fmt: skip
        if self.average is None:
            return
        module = {k: v.detach().float().clone() for k, v in self._tracked(pl_module).items()}
        averaged, raw = (module, self.average) if self._swapped else (self.average, module)
        state = checkpoint["state_dict"]
        for name, value in averaged.items():
            state[name] = value.to(state[name].dtype).clone()
        checkpoint[self.KEY] = {"raw": {k: v.clone() for k, v in raw.items()}, "updates": self.updates}

    def on_load_checkpoint(self, trainer: L.Trainer, pl_module: L.LightningModule,
                           checkpoint: dict[str, Any]) -> None:  # fmt: skip
        """Resume: the module gets the training weights back, the average those of ``state_dict``."""
        saved = checkpoint.get(self.KEY)
        if not self.active or not isinstance(saved, dict):
            return
        self.average = {k: v.detach().float().clone() for k, v in checkpoint["state_dict"].items()
                        if torch.is_tensor(v) and v.is_floating_point()}
        self.updates = int(saved.get("updates", 0))
        self._swapped = False
        with torch.no_grad():
            for name, value in self._tracked(pl_module).items():
                if name in saved["raw"]:
                    value.data.copy_(saved["raw"][name].to(value.dtype))

    def state_dict(self) -> dict[str, Any]:
        return {"updates": self.updates}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.updates = int(state_dict.get("updates", self.updates))


__all__ = ["CURVE_FIELDS", "LearningCurve", "WeightEMA"]
