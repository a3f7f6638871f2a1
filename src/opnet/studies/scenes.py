"""Scenes as the generation benchmarks set them up: the scene overrides of a command line and the
``conf/scene/`` presets as a :class:`opnet.synthesis.SceneConfig`; a depth image and a network output
to time inference on without a dataset."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from opnet.geometry.camera import Camera
from opnet.paths import config_dir

if TYPE_CHECKING:
    from opnet.synthesis import SceneConfig


def scene_overrides(camera_file: str | None, camera_height: float | None, sets: list[str]) -> dict[str, object]:
    """Scene overrides of the command line: a camera file (its clip planes used), its height, and
    ``key=value`` pairs (values parsed as YAML: numbers, booleans, null)."""
    import yaml

    out: dict[str, object] = {}
    if camera_file:
        out.update(camera_file=str(Path(camera_file).resolve()), camera_file_clip=True)
    if camera_height is not None:
        out["camera_height"] = camera_height
    for item in sets:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"--set {item!r}: expected key=value")
        out[key.strip()] = yaml.safe_load(value)
    return out


def scene_preset(name: str, **overrides: object) -> SceneConfig:
    """The SceneConfig of conf/scene/<name>.yaml (a preset's ``defaults`` resolved) with overrides."""
    from omegaconf import OmegaConf

    from opnet.synthesis import SceneConfig

    def load(preset: str) -> dict:
        doc = OmegaConf.to_container(OmegaConf.load(config_dir() / "scene" / f"{preset}.yaml"))
        values: dict = {}
        for base in doc.pop("defaults", []):
            values.update(load(base))
        return {**values, **doc}

    return SceneConfig.from_dict({**load(name), **overrides})


def depth_image(camera: Camera, rng: np.random.Generator) -> np.ndarray:
    """A bin floor with box-shaped parts on it and 5 % missing pixels, metres."""
    depth = np.full((camera.height, camera.width), 0.9 * camera.clip_end, np.float32)
    for _ in range(25):
        x, y = rng.integers(0, camera.width - 60), rng.integers(0, camera.height - 60)
        depth[y : y + rng.integers(20, 60), x : x + rng.integers(20, 60)] -= rng.uniform(0.02, 0.1)
    depth[rng.random(depth.shape) < 0.05] = np.nan
    return depth


def noisy_setup(name: str, model_name: str, obj: object, net_cam: Camera, device: object,
                decoding: str | None = None) -> tuple:  # fmt: skip
    """The parameterization ``name`` (with ``conf/decoding/<decoding>.yaml``), a fresh network of
    ``model_name`` for it on ``device``, and a realistic noisy output of 25 parts."""
    import torch
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from opnet.analysis.toy_scenes import random_scene_batch

    pcfg = OmegaConf.load(config_dir() / "parameterization" / f"{name}.yaml")
    if decoding:
        pcfg = OmegaConf.merge(pcfg, OmegaConf.load(config_dir() / "decoding" / f"{decoding}.yaml"))
    param = instantiate(pcfg, _partial_=True)(obj=obj)
    model = instantiate(OmegaConf.load(config_dir() / "model" / f"{model_name}.yaml"),
                        out_channels=param.out_channels, out_grid=param.grid_size).to(device).eval()
    gt = random_scene_batch(obj, net_cam, 1, 25, torch.Generator().manual_seed(0))
    perfect = param.encode(gt, net_cam)
    noisy = (perfect + 0.01 * torch.rand_like(perfect)).clamp(0, 1)
    presence = noisy[:, :: param.channels_per_slot]
    presence[torch.rand_like(presence) < 0.15] = 0.2  # low-confidence cells above tau
    return param, model, noisy


__all__ = ["depth_image", "noisy_setup", "scene_overrides", "scene_preset"]
