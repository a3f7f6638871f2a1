"""Scenes as the generation benchmarks set them up: the scene overrides of a command line and the
``conf/scene/`` presets as a :class:`opnet.synthesis.SceneConfig`; a depth image and a network output
to time inference on without a dataset; the statistics of the piles a dataset holds."""

from __future__ import annotations

import json
from collections.abc import Sequence
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
        out.update(camera_file=str(Path(camera_file).resolve()), clip="camera")
    if camera_height is not None:
        out["camera_height"] = camera_height
    for item in sets:
        key, sep, value = item.partition("=")
        if not sep:
            raise SystemExit(f"--set {item!r}: expected key=value")
        out[key.strip()] = yaml.safe_load(value)
    return out


def dense_scene(camera: Path | None = None, height: float | None = None, views: int = 8,
                physics: str | None = None, settings: Sequence[str] = ()) -> SceneConfig:
    """The generator's scene of ``experiment=dense`` (conf/experiment/dense.yaml: the bulk preset with
    its jitters, composed as train.py does) with ``views`` views per pile; ``camera``: another camera
    file than the recipe's; at ``height`` as it stands (``scene.rig_d=null``), or None: the recipe's
    rig, sized to the part; ``physics``: another engine than the recipe's; ``settings``: further scene settings,
    ``KEY=VALUE`` (e.g. ``view_spin=true``)."""
    from omegaconf import OmegaConf

    from opnet.studies import compose_train
    from opnet.synthesis import SceneConfig

    overrides = ["experiment=dense", f"paths.root_dir={config_dir().parent}", f"scene.views={views}",
                 *([f"scene.camera_file={Path(camera).resolve()}"] if camera is not None else []),
                 *([f"scene.camera_height={height}", "scene.rig_d=null"] if height is not None else []),
                 *([f"scene.physics={physics}"] if physics else []), *(f"scene.{kv}" for kv in settings)]
    cfg = compose_train(overrides)
    return SceneConfig.from_dict(OmegaConf.to_container(cfg.scene, resolve=True))


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
    presence = param.split_slots(noisy)[:, :, param.layout.presence]  # a view: writes reach noisy
    presence[torch.rand_like(presence) < 0.15] = 0.2  # low-confidence cells above tau
    return param, model, noisy


VIS_EDGES = (0.0, 1e-9, 0.25, 0.5, 0.75, 1.0 + 1e-9)
VIS_LABELS = ("0", "(0, .25)", "[.25, .5)", "[.5, .75)", "[.75, 1]")
FLAT_DEG = 20.0


def pile_stats(root: Path) -> dict[str, float | list[float]]:
    """The piles of one IPA dataset folder: scenes, parts per scene, the visibility histogram of every
    part of every scene (bins :data:`VIS_LABELS`), and over the full piles (the last scene of every
    cycle), in the bin's frame: the pile height (highest part origin above the floor, and the mean),
    the share of parts lying flat (the thinnest bounding-box axis within :data:`FLAT_DEG` of the
    vertical), the share fully hidden and the share crossing the near clip plane (``clipped``: some
    of the part nearer the camera than ``clip_start`` of ``parameter.json``, its top cut off)."""
    from opnet.datasets.ipa import IPADataset, read_ipa_csv, scene_paths
    from opnet.objects import object_from_config
    from opnet.synthesis.layout import homogeneous, inverse_pose

    ds = IPADataset(root)
    obj = object_from_config(json.loads((root / "object.json").read_text()))
    clip_start = float(json.loads((root / "parameter.json").read_text())["clip_start"])
    vertices = np.asarray(obj.mesh.convex_hull.vertices)
    thin_axis = np.eye(3)[int(np.argmin(obj.mesh.extents))]
    scenes = ds.scenes()
    last = max(n for _, n in scenes)
    vis_all, counts, heights, mean_heights, flat, hidden, clipped = [], [], [], [], [], [], []
    for cycle, n in scenes:
        gt = read_ipa_csv(scene_paths(root, cycle, n)["csv"])
        vis_all.append(gt.visibility_o)
        counts.append(n)
        if n != last or n == 0:
            continue
        T_bin_cam = inverse_pose(homogeneous(gt.R_cam_bin, gt.t_cam_bin))
        R_bin_obj = T_bin_cam[:3, :3] @ gt.R_cam_obj
        z = gt.t_cam_obj @ T_bin_cam[:3, :3].T[:, 2] + T_bin_cam[2, 3]
        heights.append(z.max())
        mean_heights.append(z.mean())
        up = np.abs((R_bin_obj @ thin_axis)[:, 2])
        flat.append(np.mean(up >= np.cos(np.radians(FLAT_DEG))))
        hidden.append(np.mean(gt.visibility_o == 0))
        nearest = np.einsum("nij,vj->nvi", gt.R_cam_obj, vertices)[..., 2].min(axis=1) + gt.t_cam_obj[:, 2]
        clipped.append(np.mean(nearest < clip_start))
    vis = np.concatenate(vis_all)
    hist, _ = np.histogram(vis, bins=VIS_EDGES)
    return {
        "scenes": len(scenes), "parts_per_scene": float(np.mean(counts)), "full_piles": len(heights),
        "vis_hist": (hist / max(len(vis), 1)).tolist(),
        "height_max_mm": 1e3 * float(np.mean(heights)), "height_max_sd_mm": 1e3 * float(np.std(heights)),
        "height_mean_mm": 1e3 * float(np.mean(mean_heights)),
        "flat": float(np.mean(flat)), "hidden": float(np.mean(hidden)), "clipped": float(np.mean(clipped)),
        **recorded_bin(root, obj),
    }


def recorded_bin(root: Path, obj: object) -> dict[str, float]:
    """The bin of a dataset made by :mod:`opnet.synthesis` (its rig rebuilt from the scene its
    ``generation.json`` records): ``walls_mm``, the height of its walls, and ``fill``, the convex hulls of
    its drops over the volume inside the walls (floor area x wall height; above about 0.5 the piles stand
    above the walls). NaN for another dataset."""
    from opnet.synthesis import SceneConfig
    from opnet.synthesis.layout import bin_fill, make_rig
    from opnet.synthesis.writer import read_generation

    try:
        record = read_generation(root)
    except FileNotFoundError:
        return {"walls_mm": float("nan"), "fill": float("nan")}
    drops = int(record["drops"])
    rig = make_rig(obj, drops, 1, SceneConfig.from_dict(record["scene"]))
    return {"walls_mm": 1e3 * rig.bin.wall_height, "fill": bin_fill(obj, drops, rig.bin)}


__all__ = ["FLAT_DEG", "VIS_EDGES", "VIS_LABELS", "depth_image", "noisy_setup", "pile_stats", "scene_overrides",
           "scene_preset"]
