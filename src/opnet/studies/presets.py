"""The backbone presets of ``conf/model/`` built and measured (``scripts/bench/model_stats.py``): the config
reading above the model package, the measurements in :mod:`opnet.models.stats`."""

from __future__ import annotations

import copy
from collections.abc import Sequence
from pathlib import Path

import torch
from hydra.utils import get_class
from omegaconf import OmegaConf
from torch import nn

from opnet.models.stats import (
    ModelStats,
    count_parameters,
    forward_ms_per_image,
    gflops_per_image,
    train_images_per_s,
)
from opnet.paths import config_dir


def load_model_preset(
    preset: str, out_channels: int, out_grid: int, conf_dir: Path | None = None
) -> nn.Module:
    """Build the backbone of ``conf/model/<preset>.yaml`` for a parameterization's output.

    Raises:
        ValueError: when the preset file does not exist or carries out_channels / out_grid.
    """
    path = (conf_dir or config_dir()) / "model" / f"{preset}.yaml"
    if not path.is_file():
        raise ValueError(f"model preset {preset!r}: {path} does not exist")
    kwargs = OmegaConf.to_container(OmegaConf.load(path), resolve=True)
    target = kwargs.pop("_target_")
    clash = {"out_channels", "out_grid"} & kwargs.keys()
    if clash:
        raise ValueError(
            f"{path}: keys {sorted(clash)} come from the parameterization, remove them"
        )
    return get_class(target)(out_channels=out_channels, out_grid=out_grid, **kwargs)


def preset_stats(
    presets: Sequence[str] = ("paper", "small", "tiny"),
    grids: Sequence[int] = (16, 8, 32),
    out_channels: int = 8,
    timing: bool = True,
    train: bool = False,
    repeats: int = 5,
) -> list[ModelStats]:
    """Statistics rows of every (preset, grid) pair, ``out_channels = 8`` (vanilla) by default.

    Args:
        presets: names of ``conf/model`` presets.
        grids: output grid sides.
        out_channels: channels of the head.
        timing: also time the CPU forward pass at batch 1 and 8.
        train: also measure the CPU training throughput at batch 16.
        repeats: timed repetitions (the best one counts).
    """
    rows = []
    for preset in presets:
        for grid in grids:
            torch.manual_seed(0)
            model = load_model_preset(preset, out_channels, grid)
            size = model.in_size
            rows.append(
                ModelStats(
                    preset=preset,
                    out_grid=grid,
                    parameters=count_parameters(model),
                    gflops=gflops_per_image(model, size),
                    ms_batch1=forward_ms_per_image(model, 1, size, repeats) if timing else None,
                    ms_batch8=forward_ms_per_image(model, 8, size, repeats) if timing else None,
                    train_images_per_s=train_images_per_s(copy.deepcopy(model), 16, size, repeats)
                    if train
                    else None,
                    train_fast_images_per_s=train_images_per_s(copy.deepcopy(model), 16, size, repeats, fast=True)
                    if train
                    else None,
                )
            )
    return rows


__all__ = ["load_model_preset", "preset_stats"]
