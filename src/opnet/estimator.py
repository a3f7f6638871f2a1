"""The trained model at inference: DenseNet-BC backbone + output parameterization, without Lightning.

:class:`PoseEstimator` is what a checkpoint is loaded into (:func:`opnet.cli.build.load_checkpoint`) for
``eval.py``, ``predict.py`` and the export: the network, the parameterization that decodes its output, and
the settings the model needs at inference (:class:`~opnet.run_settings.RunSettings`). The training system,
:class:`opnet.system.OPNetSystem`, is a :class:`PoseEstimator` and a LightningModule; the inference
commands import neither Lightning nor torchmetrics (several seconds of every start).
"""

from __future__ import annotations

import logging
from typing import Any

import torch
from torch import nn

from opnet.metrics.records import HypothesisSet
from opnet.parameterizations.base import Parameterization
from opnet.parameterizations.turns import quarters
from opnet.run_settings import DecodingSettings, RunSettings

log = logging.getLogger(__name__)

#: whole-image CUDA graphs kept per model, one per camera and framing (each holds its own GPU memory)
MAX_GRAPHED_CAMERAS = 4


class PoseEstimator(nn.Module):
    """Backbone and parameterization, with the settings the trained model needs at inference.

    Args:
        backbone: maps (B, 1, S, S) normalized depth to (B, C, G, G), C = parameterization.out_channels.
        parameterization: encoder/decoder of the output tensor.
        config: the resolved run configuration (what a checkpoint rebuilds the model from).
        settings: what the trained model needs at inference (framing, decoding, object;
            :mod:`opnet.run_settings`); default: read from ``config``, with the parameterization's decoding.
        max_occlusion: occlusion rate up to which instances must be found when scored (0.5).
    """

    def __init__(self, backbone: nn.Module, parameterization: Parameterization, config: dict[str, Any] | None = None,
                 settings: RunSettings | None = None, max_occlusion: float = 0.5) -> None:  # fmt: skip
        super().__init__()
        self.backbone = backbone
        self.parameterization = parameterization
        self.config = config or {}
        self.max_occlusion = max_occlusion
        if settings is None:
            settings = RunSettings.from_training_config(self.config, decoding=DecodingSettings.of(parameterization))
        self.settings = settings

    @property
    def obj(self) -> Any:
        """The object the model estimates (its parameterization's :class:`~opnet.objects.model.ObjectModel`)."""
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

    @property
    def device(self) -> torch.device:
        """The device the network's weights are on."""
        first = next(self.backbone.parameters(), None)
        return first.device if first is not None else torch.device("cpu")

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        """(B, 1, S, S) normalized depth -> (B, C, G, G) parameterization output."""
        return self.backbone(images)

    def predict_poses(self, batch: Any) -> list[HypothesisSet]:
        """Pose hypotheses per image of a :class:`~opnet.data.sample.Batch`, camera frame, metres (through the
        fast inference path when :meth:`configure_inference` set one and the module is not training)."""
        return self.decode(self.infer(batch.images), batch.cameras, batch.images)

    def decode(self, output: torch.Tensor, cameras: Any, images: torch.Tensor | None = None) -> list[HypothesisSet]:
        """The parameterization's hypotheses of a network output, averaged on the model's device
        or on the host as :attr:`device_side` says. With the decoding's ``turns`` 2 or 4 the network also
        runs on ``images`` (the input ``output`` was made of) turned by each other quarter turn, and the
        hypotheses of every turn are pooled before the averaging (:mod:`opnet.parameterizations.turns`).

        Raises:
            ValueError: ``turns`` above 1 and no ``images``.
        """
        param = self.parameterization
        turned = None
        if param.turns > 1:
            if images is None:
                raise ValueError(f"decoding.turns={param.turns} runs the network on the turned input: "
                                 "PoseEstimator.decode needs the images the output was made of")  # fmt: skip
            turned = self.turned_outputs(images, quarters(param.turns)[1:])
        return param.decode(output, cameras, device_side=self.device_side, turned=turned)

    def turned_outputs(self, images: torch.Tensor, turns: Any) -> list[tuple[int, torch.Tensor]]:
        """``(q, output)`` of ``images`` turned by each quarter turn ``q`` of ``turns`` (:meth:`infer`'s output)."""
        return [(q, self.infer(torch.rot90(images, q, dims=(-2, -1)).contiguous())) for q in turns]

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
        on a CUDA device and the decoding runs one pass (``turns`` 1); else None."""
        settings = getattr(self, "_settings", None)
        if settings is None or self.training or not settings.graphed(self.device) or not self.device_side:
            return None
        if self.parameterization.turns > 1:  # the graph holds one pass of the network
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


__all__ = ["MAX_GRAPHED_CAMERAS", "PoseEstimator"]
