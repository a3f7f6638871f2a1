"""Decode + pose-averaging time per image for every parameterization config (one CPU thread).

Realistic network outputs: the perfect output (encoded target) of dense random scenes of ~25
objects, plus Gaussian noise on every channel of the object cells (sigma 0.001 by default: the
copies of one object mostly fall within the DBSCAN radius, so clusters really get averaged) and,
in empty cells, a presence of |N(0, presence_sigma)| (about 15 % of them above τ = 0.1 by
default) with uniform garbage in the other channels. Target: under 5 ms per image for every
parameterization. Columns: median and best wall-clock time, median process CPU time (what the
decode costs when the machine is shared and the wall clock also counts waiting for a core).

    python scripts/bench/bench_decode.py [--object bracket] [--batch 1] [--repeats 20]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import hydra.utils
import numpy as np
import torch
from omegaconf import OmegaConf

from opnet.analysis.toy_scenes import random_scene_batch
from opnet.geometry import Camera
from opnet.objects import builtin_object
from opnet.parameterizations import Parameterization
from opnet.paths import config_dir


def realistic_output(
    param: Parameterization,
    target: torch.Tensor,
    noise: float,
    presence_sigma: float,
    gen: torch.Generator,
) -> torch.Tensor:
    """A perfect output (B, C, S, S) degraded like a trained network's."""
    grid = param.split_slots(target).clone()  # (B, L, C, S, S)
    present = grid[:, :, :1] > 0
    jitter = noise * torch.randn(grid.shape, generator=gen)
    garbage = torch.rand(grid.shape, generator=gen)
    garbage[:, :, :1] = (presence_sigma * torch.randn(grid[:, :, :1].shape, generator=gen)).abs()
    out = torch.where(present, grid + jitter, garbage).clamp(0, 1)
    return out.reshape(target.shape)


def bench(
    config: Path, obj, camera: Camera, batch: int, repeats: int, args: argparse.Namespace
) -> dict[str, float]:
    param = hydra.utils.instantiate(OmegaConf.load(config), obj=obj)
    gen = torch.Generator().manual_seed(0)
    gt = random_scene_batch(obj, camera, batch, (20, 30), gen)
    output = realistic_output(param, param.encode(gt, camera), args.noise, args.presence_sigma, gen)
    present = int((param.split_slots(output)[:, :, param.layout.presence] > param.threshold).sum())
    param.decode(output, camera)  # warm-up
    wall, cpu = [], []
    for _ in range(repeats):
        start, start_cpu = time.perf_counter(), time.process_time()
        hyps = param.decode(output, camera)
        wall.append(time.perf_counter() - start)
        cpu.append(time.process_time() - start_cpu)
    wall_ms, cpu_ms = 1e3 * np.asarray(wall) / batch, 1e3 * np.asarray(cpu) / batch
    return {
        "median_ms": float(np.median(wall_ms)),
        "min_ms": float(wall_ms.min()),
        "cpu_ms": float(np.median(cpu_ms)),
        "cells": present / batch,
        "hyps": sum(len(h) for h in hyps) / batch,
        "objects": len(gt) / batch,
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--object", default="bracket", help="built-in object (bracket, zbracket, shaft, pin)"
    )
    parser.add_argument("--batch", type=int, default=1, help="images decoded per call")
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument(
        "--noise", type=float, default=0.001, help="sigma of the noise on object cells (0: exact)"
    )
    parser.add_argument(
        "--presence-sigma", type=float, default=0.07, help="sigma of |presence| in empty cells"
    )
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    camera = Camera.from_fov(60.0, 128, 128, 0.5, 1.5)
    obj = builtin_object(args.object)
    print(
        f"object {args.object}, batch {args.batch}, {args.threads} thread(s), "
        f"{args.repeats} repeats; per image:"
    )
    print(
        f"{'parameterization':<17}{'median ms':>10}{'min ms':>8}{'cpu ms':>8}{'objects':>9}"
        f"{'cells>tau':>10}{'hypotheses':>11}"
    )
    for config in sorted((config_dir() / "parameterization").glob("*.yaml")):
        r = bench(config, obj, camera, args.batch, args.repeats, args)
        flag = "" if r["median_ms"] < 5.0 else "  (over 5 ms)"
        print(
            f"{config.stem:<17}{r['median_ms']:>10.2f}{r['min_ms']:>8.2f}{r['cpu_ms']:>8.2f}"
            f"{r['objects']:>9.1f}{r['cells']:>10.1f}{r['hyps']:>11.1f}{flag}"
        )


if __name__ == "__main__":
    main()
