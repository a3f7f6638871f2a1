"""The single LightningModule: a :class:`~opnet.estimator.PoseEstimator` (DenseNet-BC backbone + output
parameterization) with the multi-task loss, the optimizer and the validation metric.

Training encodes the ground truth with the parameterization (vectorized, on the model's device)
and optimizes the paper's loss; validation decodes the output into pose hypotheses and scores them
with the Brégier average precision (docs/method.md#matching-and-scores). The test split is scored
outside Lightning's loop, by :func:`opnet.evaluation.evaluate` (train.py, eval.py, the learning curve).
"""

from __future__ import annotations

import math
from typing import Any

import lightning as L
import torch
from torch import nn

from opnet.data.sample import Batch
from opnet.datasets.camera_file import dataset_camera
from opnet.estimator import PoseEstimator
from opnet.losses import MultiTaskLoss
from opnet.metrics.diagnostics import MISS_REASONS
from opnet.metrics.plot import pr_curve_figure
from opnet.metrics.records import HypothesisSet
from opnet.metrics.torchmetric import PoseAP
from opnet.parameterizations.base import Parameterization
from opnet.run_settings import CHECKPOINT_KEY, RunSettings
from opnet.visualize import draw_positions


class OPNetSystem(PoseEstimator, L.LightningModule):
    """A :class:`~opnet.estimator.PoseEstimator` that trains: the loss, the optimizer and the AP metric.

    Args:
        backbone: maps (B, 1, S, S) normalized depth to (B, C, G, G), C = parameterization.out_channels.
        parameterization: encoder/decoder of the output tensor.
        loss: the multi-task loss.
        lr, weight_decay: AdamW settings.
        scheduler: "cosine" (after a linear warm-up of ``warmup_steps``) or "none".
        max_occlusion: occlusion rate up to which instances must be found (0.5).
        log_images: how many validation images per epoch to draw to TensorBoard.
        config: the resolved run configuration, stored in checkpoints to rebuild the system.
        settings: what the trained model needs at inference (framing, decoding, object;
            :mod:`opnet.run_settings`), saved as their own checkpoint entry; default: read from
            ``config``, with the parameterization's decoding.
    """

    #: Lightning's own (it follows ``.to()`` before the module has weights on the device)
    device = L.LightningModule.device

    def __init__(
        self,
        backbone: nn.Module,
        parameterization: Parameterization,
        loss: MultiTaskLoss,
        lr: float = 2e-3,
        weight_decay: float = 1e-4,
        scheduler: str = "cosine",
        warmup_steps: int = 100,
        max_occlusion: float = 0.5,
        log_images: int = 4,
        config: dict[str, Any] | None = None,
        settings: RunSettings | None = None,
    ) -> None:
        super().__init__(backbone, parameterization, config=config, settings=settings, max_occlusion=max_occlusion)
        self.save_hyperparameters(ignore=["backbone", "parameterization", "loss", "settings"])
        self.loss = loss
        space, diameter = parameterization.obj.pose_space, parameterization.obj.diameter
        self.val_ap = PoseAP(space, max_occlusion=max_occlusion, diameter=diameter)
        self._val_images: list[torch.Tensor] = []

    def on_fit_start(self) -> None:
        """Record the training scenes' clip planes in :attr:`settings` (``trained_clip``), which the
        checkpoints carry: predict.py and the ONNX runtime normalize a new image's depth with them,
        whatever planes its camera file gives; and the dataset's camera (``camera``), their camera
        for an image that comes without one."""
        datamodule = getattr(self.trainer, "datamodule", None)
        train = (getattr(datamodule, "splits", None) or {}).get("train")
        if train is not None and hasattr(train, "clip_planes"):
            self.settings = self.settings.with_trained_clip(train.clip_planes())
        roots = getattr(datamodule, "roots", None)
        if roots is not None and len(roots) == 1:  # the training camera: predict.py's default for a bare image
            self.settings = self.settings.with_camera(dataset_camera(roots[0]))

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """Save :attr:`settings` as their own entry (:data:`opnet.run_settings.CHECKPOINT_KEY`), plain data."""
        checkpoint[CHECKPOINT_KEY] = self.settings.to_dict()

    # ---- training ---------------------------------------------------------------------------
    def _losses(self, batch: Batch, output: torch.Tensor) -> dict[str, torch.Tensor]:
        target = self.parameterization.encode(batch.gt, batch.cameras)
        return self.loss(output, target, self.parameterization, batch.cameras)

    def training_step(self, batch: Batch, batch_idx: int) -> torch.Tensor:
        losses = self._losses(batch, self(batch.images))
        self.log_dict({f"train/{k}": v for k, v in losses.items()}, batch_size=len(batch), prog_bar=False)
        self.log("train/loss", losses["total"], batch_size=len(batch), prog_bar=True, logger=False)
        return losses["total"]

    # ---- evaluation --------------------------------------------------------------------------
    def _eval_step(self, batch: Batch, metric: PoseAP, stage: str) -> list[HypothesisSet]:
        output = self(batch.images)
        losses = self._losses(batch, output)
        self.log_dict({f"{stage}/{k}": v for k, v in losses.items()}, batch_size=len(batch))
        hyps = self.decode(output, batch.cameras, batch.images)
        metric.update(hyps, batch.gt_sets)
        return hyps

    def validation_step(self, batch: Batch, batch_idx: int) -> None:
        hyps = self._eval_step(batch, self.val_ap, "val")
        if len(self._val_images) < self.hparams.log_images:
            for k in range(min(len(batch), self.hparams.log_images - len(self._val_images))):
                img = draw_positions(batch.images[k, 0].cpu().numpy(), batch.cameras[k], batch.gt_sets[k], hyps[k])
                self._val_images.append(torch.from_numpy(img).permute(2, 0, 1))

    def on_validation_epoch_end(self) -> None:
        self._log_metric(self.val_ap, "val")
        tb = self._tensorboard()
        if tb is not None and self._val_images:
            tb.add_images("val/positions", torch.stack(self._val_images), self.global_step)
        self._val_images = []

    def _log_metric(self, metric: PoseAP, stage: str) -> None:
        values = metric.compute()
        self.log_dict({f"{stage}/{k}": v for k, v in values.items() if k != "ap"})
        self.log(f"{stage}/ap", values["ap"], prog_bar=True)
        diag = metric.last_diagnostics
        if diag is not None:  # why instances are missed, as fractions of the instances to find
            n = max(diag.to_find, 1)
            fractions = {k: getattr(diag, k) / n for k in ("matched", *MISS_REASONS)}
            fractions["confident_false_positives"] = diag.confident_false_positives / n
            fractions["duplicates"] = diag.duplicates / n
            errors = {k: getattr(diag, k) for k in ("t_err_mm_p50", "r_err_deg_p50")}
            self.log_dict({f"{stage}_diag/{k}": float(v) for k, v in {**fractions, **errors}.items()})
        tb = self._tensorboard()
        curve = getattr(metric, "last_curve", None)
        if tb is not None and curve is not None:
            tb.add_figure(f"{stage}/pr_curve", pr_curve_figure(curve[0], curve[1], f"{stage} AP {float(values['ap']):.4f}"), self.global_step)
        metric.reset()

    def _tensorboard(self) -> Any:
        exp = getattr(self.logger, "experiment", None) if self.logger is not None else None
        return exp if exp is not None and hasattr(exp, "add_images") else None

    # ---- optimization ------------------------------------------------------------------------
    def configure_optimizers(self) -> Any:
        opt = torch.optim.AdamW(self.parameters(), lr=self.hparams.lr, weight_decay=self.hparams.weight_decay)
        if self.hparams.scheduler == "none":
            return opt
        if self.hparams.scheduler != "cosine":
            raise ValueError(f"scheduler must be 'cosine' or 'none', got {self.hparams.scheduler!r}")
        total = max(1, int(self.trainer.estimated_stepping_batches))
        warm = min(self.hparams.warmup_steps, total // 2)

        def factor(step: int) -> float:
            if step < warm:
                return (step + 1) / warm
            progress = (step - warm) / max(1, total - warm)
            return 0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * min(1.0, progress)))

        sched = torch.optim.lr_scheduler.LambdaLR(opt, factor)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
