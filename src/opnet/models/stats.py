"""Size and speed measurements of a backbone: parameters, FLOPs, forward and training speed.

FLOPs are measured with :class:`torch.utils.flop_counter.FlopCounterMode`, which counts a
multiply-add as 2 FLOPs and counts convolutions and matrix products only (batch norm, ReLU,
pooling and the sigmoid are not counted; they are < 1 % of the total here).

Every measurement runs on the device the model is on: its probe inputs are made there.
"""

from __future__ import annotations

import contextlib
import itertools
import time
from dataclasses import dataclass

import torch
from torch import nn
from torch.utils.flop_counter import FlopCounterMode


@dataclass(frozen=True)
class ModelStats:
    """One row of the model statistics table.

    Attributes:
        preset: name of the model preset (``conf/model/<preset>.yaml``).
        out_grid: output grid side S.
        parameters: number of trainable parameters.
        gflops: GFLOPs per image of one forward pass (multiply-add = 2 FLOPs).
        ms_batch1, ms_batch8: CPU forward milliseconds per image at batch 1 and 8 (None: not timed).
        train_images_per_s: CPU training throughput at batch 16, forward + backward + Adam step,
            fp32 contiguous, as before the speed work (None: not timed).
        train_fast_images_per_s: the same with the training defaults on CPUs with native bf16
            (bf16 autocast and channels-last; None: not timed).
    """

    preset: str
    out_grid: int
    parameters: int
    gflops: float
    ms_batch1: float | None = None
    ms_batch8: float | None = None
    train_images_per_s: float | None = None
    train_fast_images_per_s: float | None = None


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters of ``model``."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


def model_device(model: nn.Module) -> torch.device:
    """The device of ``model``'s first parameter or buffer (the CPU for a module without either)."""
    first = next(itertools.chain(model.parameters(), model.buffers()), None)
    return torch.device("cpu") if first is None else first.device


def _input(model: nn.Module, batch: int, in_size: int) -> torch.Tensor:
    """A seeded (batch, C, in_size, in_size) probe on the model's device (drawn on the CPU, so
    every device sees the same values)."""
    channels = getattr(model, "in_channels", 1)
    x = torch.rand(batch, channels, in_size, in_size, generator=torch.Generator().manual_seed(0))
    return x.to(model_device(model))


def _sync(device: torch.device) -> None:
    """Wait for the device's queued work (CUDA runs asynchronously: a timer would see the launch only)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


@torch.no_grad()
def gflops_per_image(model: nn.Module, in_size: int = 128) -> float:
    """GFLOPs of one forward pass on one (1, C, in_size, in_size) image, measured (2 FLOPs per MAC)."""
    was_training = model.training
    model.eval()
    with FlopCounterMode(display=False) as counter:
        model(_input(model, 1, in_size))
    model.train(was_training)
    return counter.get_total_flops() / 1e9


@torch.no_grad()
def forward_ms_per_image(
    model: nn.Module, batch: int, in_size: int = 128, repeats: int = 5, warmup: int = 1
) -> float:
    """Best-of-``repeats`` forward time per image in milliseconds (eval mode, no grad) on the
    model's device.

    The minimum (timeit's convention) is the least disturbed by other processes on a shared machine.
    """
    was_training = model.training
    model.eval()
    x = _input(model, batch, in_size)
    for _ in range(warmup):
        model(x)
    _sync(x.device)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        model(x)
        _sync(x.device)
        times.append(time.perf_counter() - start)
    model.train(was_training)
    return min(times) * 1e3 / batch


def train_images_per_s(
    model: nn.Module, batch: int = 16, in_size: int = 128, steps: int = 5, warmup: int = 1, fast: bool = False
) -> float:
    """Training throughput on the model's device (images/s, best step of ``steps``): forward,
    squared-L2 loss, backward and an Adam step; ``fast``: bf16 autocast and channels-last (the
    training defaults where the CPU has native bf16).

    The model's weights are changed by the measurement; pass a copy to keep them.
    """
    model.train()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-4)
    x = _input(model, batch, in_size)
    if fast:
        model.to(memory_format=torch.channels_last)
        x = x.contiguous(memory_format=torch.channels_last)
    target = None
    times = []
    for step in range(warmup + steps):
        start = time.perf_counter()
        with torch.autocast(x.device.type, dtype=torch.bfloat16) if fast else contextlib.nullcontext():
            y = model(x).float()
        target = torch.full_like(y, 0.5) if target is None else target
        loss = (y - target).square().mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        _sync(x.device)
        if step >= warmup:
            times.append(time.perf_counter() - start)
    return batch / min(times)
