"""What the hardware can do, probed once where the command line and the inference engine both
need it: native bf16 on the CPU, whether a training runs on a CUDA GPU, and the training
precision that follows from them.

A low module (imports torch only): ``opnet.inference`` and ``opnet.cli`` both use it.
"""

from __future__ import annotations

import os
from typing import Any

import torch

#: ``OPNET_CPU_BF16=0`` runs every ``auto`` precision (training and inference) as on a CPU without native
#: bf16, fp32 throughout; ``=1`` as on one with it. Unset: what the CPU reports. For checking on one
#: machine what another kind of CPU computes (the test suite is run both ways).
CPU_BF16_ENV = "OPNET_CPU_BF16"


def cpu_has_native_bf16() -> bool:
    """The CPU computes bf16 natively (AVX512-BF16 or AMX): bf16 autocast is then faster than fp32.
    Elsewhere bf16 is emulated and slower. ``OPNET_CPU_BF16`` (0 or 1) overrides the probe.

    Raises:
        ValueError: ``OPNET_CPU_BF16`` set to anything but 0 or 1.
    """
    forced = os.environ.get(CPU_BF16_ENV, "").strip()
    if forced:
        if forced not in ("0", "1"):
            raise ValueError(f"{CPU_BF16_ENV}={forced!r}: expected 0 (no native bf16: fp32) or 1, or unset")
        return forced == "1"
    probes = ("_is_avx512_bf16_supported", "_is_amx_tile_supported")
    return any(bool(getattr(torch.cpu, name, lambda: False)()) for name in probes)


def on_cuda(accelerator: str) -> bool:
    """``trainer.accelerator`` puts the run on a CUDA GPU (``auto``: where one is available)."""
    return accelerator in ("gpu", "cuda") or (accelerator == "auto" and torch.cuda.is_available())


def configure_matmul_precision(accelerator: str) -> bool:
    """On a CUDA GPU, let float32 matrix products and convolutions use the tensor cores (TF32:
    ``torch.set_float32_matmul_precision("high")``), unless the process chose a precision already;
    Lightning warns on tensor-core GPUs while it is PyTorch's default ``highest``. A CPU run is left
    as it is. Returns whether the precision was set."""
    if not on_cuda(accelerator) or torch.get_float32_matmul_precision() != "highest":
        return False
    torch.set_float32_matmul_precision("high")
    return True


def resolve_precision(precision: Any, accelerator: str) -> Any:
    """``trainer.precision: auto``: bf16 mixed precision where the hardware has it (GPUs, CPUs with
    native bf16), else 32-bit. Any other value is passed to Lightning as it is."""
    if str(precision) != "auto":
        return precision
    if on_cuda(accelerator):
        return "bf16-mixed"
    return "bf16-mixed" if cpu_has_native_bf16() else "32-true"


def precision_path(precision: Any, accelerator: str) -> str:
    """One line for the console: the numeric path a training takes and why. Models trained on
    another path are other models (the quickstart's figure differs between the two)."""
    resolved = resolve_precision(precision, accelerator)
    if str(precision) != "auto":
        return f"precision path: {resolved} (trainer.precision={precision})"
    if str(resolved).startswith("bf16"):
        why = "a GPU" if on_cuda(accelerator) else "the CPU has native bf16"
        return f"precision path: bf16 mixed ({why}; trainer.precision=auto)"
    return "precision path: fp32 (this CPU has no native bf16; trainer.precision=auto)"


__all__ = ["CPU_BF16_ENV", "configure_matmul_precision", "cpu_has_native_bf16", "on_cuda", "precision_path", "resolve_precision"]
