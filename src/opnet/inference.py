"""The fast inference path of ``predict.py`` and ``eval.py``: memory format, precision, compilation.

Measured on this 2-core CPU (AVX512-BF16), paper network, batch 1 (``scripts/bench_infer.py``):
fp32 eager ≈ 80 ms, fp32 channels-last ≈ 76 ms, bf16 autocast channels-last ≈ 54 ms,
bf16 channels-last under ``torch.compile`` ≈ 36 ms (after a one-off compilation of ≈ 45 s).

``inference.precision``: ``32`` (the default: the poses of fp32 eager, bit for bit with
channels-last on this CPU), ``bf16`` (autocast), or ``auto`` = bf16 where the hardware computes it
natively (CPUs with AVX512-BF16 / AMX, CUDA GPUs), fp32 elsewhere.
``inference.channels_last``: ``auto`` = on (faster on CPUs and GPUs alike for this network).
``inference.compile``: ``torch.compile`` the backbone (worth it for long runs or a service: the
first call compiles for tens of seconds).

bf16 changes the network output by a few 1e-3, so its poses are not those of fp32:
``scripts/check_inference.py`` measured on the quickstart model's 150 test scenes p99 differences
of 0.37 mm and 3.8 deg between paired hypotheses (1052 vs 1044 hypotheses; AP 0.8092 vs 0.8100),
which is why fp32 stays the default and bf16 is a documented opt-in.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import torch

PRECISIONS = ("auto", "32", "bf16")


@dataclass(frozen=True)
class InferenceSettings:
    precision: str = "32"
    channels_last: bool | str = "auto"
    compile: bool = False
    #: larger batches run in chunks of this many images: the DenseNet's concatenated activations of
    #: a batch of 32 no longer fit the caches (measured per image at batch 32: fp32 122 ms whole,
    #: 75 ms in chunks of 8; bf16 43 ms whole, 33 ms in chunks of 8); same outputs (eval mode)
    max_batch: int = 8

    @classmethod
    def from_config(cls, cfg: Any) -> InferenceSettings:
        cfg = dict(cfg or {})
        unknown = set(cfg) - {"precision", "channels_last", "compile", "max_batch"}
        if unknown:
            raise ValueError(f"inference: unknown keys {sorted(unknown)}; expected precision, channels_last, compile, max_batch")
        precision = str(cfg.get("precision", "32"))
        if precision not in PRECISIONS:
            raise ValueError(f"inference.precision={precision!r}, expected one of {PRECISIONS}")
        cl = cfg.get("channels_last", "auto")
        if cl not in ("auto", True, False):
            raise ValueError(f"inference.channels_last={cl!r}, expected auto, true or false")
        max_batch = cfg.get("max_batch", 8)
        if isinstance(max_batch, bool) or not isinstance(max_batch, int) or max_batch < 1:
            raise ValueError(f"inference.max_batch={max_batch!r}, expected a positive integer")
        return cls(precision, cl, bool(cfg.get("compile", False)), max_batch)

    def resolved(self, device: torch.device) -> tuple[bool, bool]:
        """(bf16, channels_last) for ``device``."""
        if self.precision == "auto":
            from opnet.cli.train import cpu_has_native_bf16

            bf16 = device.type == "cuda" or (device.type == "cpu" and cpu_has_native_bf16())
        else:
            bf16 = self.precision == "bf16"
        cl = True if self.channels_last == "auto" else bool(self.channels_last)
        return bf16, cl

    def describe(self, device: torch.device) -> str:
        bf16, cl = self.resolved(device)
        return (f"{'bf16 autocast' if bf16 else 'fp32'}, {'channels-last' if cl else 'contiguous'}"
                f"{', compiled' if self.compile else ''} on {device.type}")


def fast_forward(backbone: torch.nn.Module, settings: InferenceSettings) -> Callable[[torch.Tensor], torch.Tensor]:
    """A function (B, 1, S, S) -> fp32 output running ``backbone`` (in eval mode) the fast way."""
    device = next(backbone.parameters()).device
    bf16, cl = settings.resolved(device)
    backbone.eval()
    if cl:
        backbone = backbone.to(memory_format=torch.channels_last)
    module: Callable[[torch.Tensor], torch.Tensor] = torch.compile(backbone) if settings.compile else backbone

    def one(x: torch.Tensor) -> torch.Tensor:
        if cl:
            x = x.contiguous(memory_format=torch.channels_last)
        if bf16:
            with torch.autocast(device.type, dtype=torch.bfloat16):
                return module(x).float()
        return module(x)

    @torch.inference_mode()
    def run(images: torch.Tensor) -> torch.Tensor:
        x = images.to(device)
        step = settings.max_batch
        outs = [one(x[i : i + step]) for i in range(0, len(x), step)] if len(x) > step else [one(x)]
        return torch.cat(outs).contiguous() if len(outs) > 1 else outs[0].contiguous()

    return run
