"""The single LightningModule: DenseNet-BC backbone + output parameterization + multi-task loss.

Training encodes the ground truth with the parameterization (vectorized, on the model's device)
and optimizes the paper's loss; validation decodes the output into pose hypotheses and scores them
with the Brégier average precision (docs/method.md#matching-and-scores). The test split is scored
outside Lightning's loop, by :func:`opnet.evaluation.evaluate` (train.py, eval.py, the learning curve).
"""

from __future__ import annotations

import logging
import math
from typing import Any

import lightning as L
import torch
from torch import nn

from opnet.data.sample import Batch
from opnet.datasets.camera_file import dataset_camera
from opnet.losses import MultiTaskLoss
from opnet.metrics.diagnostics import MISS_REASONS
from opnet.metrics.plot import pr_curve_figure
from opnet.metrics.records import HypothesisSet
from opnet.metrics.torchmetric import PoseAP
from opnet.parameterizations.base import Parameterization
from opnet.run_settings import CHECKPOINT_KEY, DecodingSettings, RunSettings
from opnet.visualize import draw_positions

log = logging.getLogger(__name__)

#: whole-image CUDA graphs kept per system, one per camera and framing (each holds its own GPU memory)
MAX_GRAPHED_CAMERAS = 4


class OPNetSystem(L.LightningModule):
    """Backbone, parameterization and loss, with the optimizer and the AP metric.

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
        super().__init__()
        self.save_hyperparameters(ignore=["backbone", "parameterization", "loss", "settings"])
        self.backbone = backbone
        self.parameterization = parameterization
        self.loss = loss
        if settings is None:
            settings = RunSettings.from_training_config(config or {}, decoding=DecodingSettings.of(parameterization))
        self.settings = settings
        space, diameter = parameterization.obj.pose_space, parameterization.obj.diameter
        self.val_ap = PoseAP(space, max_occlusion=max_occlusion, diameter=diameter)
        self._val_images: list[torch.Tensor] = []

    @property
    def obj(self) -> Any:
        """The object the system estimates (its parameterization's :class:`~opnet.objects.model.ObjectModel`)."""
        return self.parameterization.obj

    @property
    def settings(self) -> RunSettings:
        """What the trained model needs at inference (:class:`~opnet.run_settings.RunSettings`): the
        framing, the training clip planes and the object as given, the decoding the parameterization
        decodes with now."""
        return self._run_settings.with_decoding(DecodingSettings.of(self.parameterization))

    @settings.setter
    def settings(self, settings: RunSettings) -> None:
        self._run_settings = settings
        self.set_decoding(settings.decoding)

    def set_decoding(self, decoding: DecodingSettings) -> None:
        """Decode with ``decoding`` from now on: the parameterization becomes a copy with those
        settings (its encoding unchanged)."""
        if decoding == DecodingSettings.of(self.parameterization):
            return
        self.parameterization = self.parameterization.with_decoding(**decoding.overrides())

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

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """(B, 1, S, S) normalized depth -> (B, C, G, G) parameterization output."""
        return self.backbone(images)

    def predict_poses(self, batch: Batch) -> list[HypothesisSet]:
        """Pose hypotheses per image, camera frame, metres (through the fast inference path when
        :meth:`configure_inference` set one and the module is not training)."""
        return self.decode(self.infer(batch.images), batch.cameras)

    def decode(self, output: torch.Tensor, cameras: Any) -> list[HypothesisSet]:
        """The parameterization's hypotheses of a network output, averaged on the model's device
        or on the host as :attr:`device_side` says."""
        return self.parameterization.decode(output, cameras, device_side=self.device_side)

    @property
    def device_side(self) -> bool:
        """Whether preprocessing (predict.py) and averaging run as torch operations on the model's
        device (``inference.device_side``, resolved for the device the module is on now: ``auto``
        is on for CUDA, so validation on a GPU averages there)."""
        from opnet.inference import device_side

        return device_side(getattr(self, "_device_side", "auto"), self.device)

    def configure_decoding(self, device_side: bool | str = "auto") -> None:
        """Set ``inference.device_side`` (auto, true or false) for validation, test and predictions."""
        from opnet.inference import device_side as resolve

        resolve(device_side, self.device)  # a bad value is refused now, naming the key
        self._device_side = device_side

    def configure_inference(self, settings: Any) -> str:
        """Use :func:`opnet.inference.fast_forward` with ``settings`` for predictions (and their
        ``device_side`` for decoding); returns a description of the path (precision, memory
        format, CUDA graph, where preprocessing and averaging run, device)."""
        from opnet.inference import InferenceSettings, fast_forward

        if not isinstance(settings, InferenceSettings):
            settings = InferenceSettings.from_config(settings)
        self._fast = fast_forward(self.backbone, settings)
        self._settings = settings
        self._pipelines: dict = {}
        self.configure_decoding(settings.device_side)
        return settings.describe(self.device, self.backbone)

    def graphed_pipeline(self, camera: Any, size: int, fit: str) -> Any:
        """The whole prediction of one image of ``camera`` as one CUDA graph
        (:class:`opnet.inference.GraphedPipeline`, made at the first image of each camera and
        framing), where :meth:`configure_inference` asked for a CUDA graph and device-side decoding
        on a CUDA device; else None."""
        settings = getattr(self, "_settings", None)
        if settings is None or self.training or not settings.graphed(self.device) or not self.device_side:
            return None
        key = (camera, size, fit)
        if key not in self._pipelines:
            if len(self._pipelines) >= MAX_GRAPHED_CAMERAS:  # each graph holds its own GPU memory
                if not getattr(self, "_graphs_full", False):
                    log.info("inference: more than %d cameras (a region of interest per image?): images of further "
                             "cameras run without a whole-image graph", MAX_GRAPHED_CAMERAS)
                    self._graphs_full = True
                return None
            from opnet.inference import GraphedPipeline

            self._pipelines[key] = GraphedPipeline(self.backbone, settings, self.parameterization, camera, size, fit,
                                                   fuse=settings.compile_pipeline)
        return self._pipelines[key]

    def infer(self, images: torch.Tensor) -> torch.Tensor:
        """The network output for prediction: the fast path if configured (eval mode), else forward."""
        fast = getattr(self, "_fast", None)
        if fast is not None and not self.training:
            return fast(images)
        return self(images)

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
        hyps = self.decode(output, batch.cameras)
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
