"""``python predict.py ckpt=<path> input=<file or folder> out=<dir>``: depth images -> poses.

Accepted inputs:
- a 16-bit depth PNG inside an IPA folder (``parameter.json`` in an ancestor folder) or a Siléane
  folder (``camera_params.txt`` in an ancestor folder): the camera comes from that file;
- a ``.npy`` array of depth in metres (NaN or 0 = missing), with the intrinsics given in the config
  (``camera.fx, fy, cx, cy, clip_start, clip_end``);
- a folder: every such file in it (recursively).
Per image it writes ``<stem>.json`` (poses R, t in metres in the camera frame, score) and
``<stem>.png`` (the depth image with each estimated object's model projected on it).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from omegaconf import DictConfig

from opnet.cli.build import load_checkpoint
from opnet.data.preprocess import to_network_input
from opnet.datasets.atomic import write_text_atomic
from opnet.datasets.ipa_params import read_parameters
from opnet.datasets.png import decode_depth, read_png
from opnet.datasets.sileane import read_camera_params
from opnet.geometry.camera import Camera
from opnet.metrics.records import HypothesisSet
from opnet.system import OPNetSystem
from opnet.visualize import draw_models

log = logging.getLogger(__name__)
IMAGE_SUFFIXES = {".png", ".npy"}


@dataclass
class DepthImage:
    path: Path
    depth: np.ndarray  # (H, W) float32 metres, NaN = missing
    camera: Camera


def _find_upwards(path: Path, name: str, levels: int = 4) -> Path | None:
    for parent in list(path.parents)[:levels]:
        if (parent / name).is_file():
            return parent / name
    return None


def load_depth_image(path: Path, camera_cfg: dict[str, Any] | None) -> DepthImage:
    """Read one depth image with its camera; raises ValueError naming the file on bad input."""
    if path.suffix.lower() == ".npy":
        try:
            depth = np.load(path, allow_pickle=False)
        except Exception as e:
            raise ValueError(f"{path}: cannot read .npy ({type(e).__name__}: {e})") from e
        if depth.ndim != 2:
            raise ValueError(f"{path}: expected a 2-D depth array (H, W), got shape {depth.shape}")
        if not np.issubdtype(depth.dtype, np.floating):
            raise ValueError(f"{path}: expected float depth in metres, got dtype {depth.dtype}")
        if camera_cfg is None or any(camera_cfg.get(k) is None for k in ("fx", "fy", "cx", "cy", "clip_start", "clip_end")):
            raise ValueError(f"{path}: a .npy input needs camera.fx, fy, cx, cy, clip_start, clip_end in the config")
        h, w = depth.shape
        for key, size in (("width", w), ("height", h)):
            if camera_cfg.get(key) not in (None, size):
                raise ValueError(f"{path}: image is {w}x{h} but camera.{key} is {camera_cfg[key]}")
        cam = Camera(float(camera_cfg["fx"]), float(camera_cfg["fy"]), float(camera_cfg["cx"]), float(camera_cfg["cy"]),
                     w, h, float(camera_cfg["clip_start"]), float(camera_cfg["clip_end"]))
        depth = depth.astype(np.float32)
        if np.isinf(depth).any():
            raise ValueError(f"{path}: depth holds infinite values")
        depth[depth <= 0] = np.nan
        return DepthImage(path, depth, cam)
    if path.suffix.lower() == ".png":
        if (params := _find_upwards(path, "parameter.json")) is not None:
            cam = read_parameters(params).camera()
        elif (cp := _find_upwards(path, "camera_params.txt")) is not None:
            cam = read_camera_params(cp)[0]
        else:
            raise ValueError(f"{path}: no parameter.json (IPA) or camera_params.txt (Siléane) found above it")
        code = read_png(path, np.uint16)
        if code.shape != (cam.height, cam.width):
            # a crop or a resized image: keep the intrinsics consistent by scaling them
            log.warning("%s: image %s differs from the camera's %sx%s; scaling the intrinsics", path, code.shape[::-1], cam.width, cam.height)
            cam = cam.resized(code.shape[1], code.shape[0])
        return DepthImage(path, decode_depth(code, cam.clip_start, cam.clip_end), cam)
    raise ValueError(f"{path}: unsupported input {path.suffix!r}; expected a 16-bit .png or a .npy")


def list_inputs(path: Path) -> list[Path]:
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: input not found")
    files = sorted(p for p in path.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and "segmentation" not in p.name
                   and "segmentation" not in p.parent.name and "rgb" not in p.parent.name)
    if not files:
        raise ValueError(f"{path}: no .png or .npy depth images in this folder")
    return files


@torch.no_grad()
def predict_image(system: OPNetSystem, image: DepthImage) -> HypothesisSet:
    """Pose hypotheses for one depth image (camera frame, metres)."""
    size = int(system.hparams.get("config", {}).get("data", {}).get("input_size", 128))
    net_in, net_cam = to_network_input(image.depth, image.camera, size=size, interpolation=cv2.INTER_AREA)
    x = torch.from_numpy(net_in)[None, None].to(system.device)
    return system.parameterization.decode(system(x), [net_cam])[0]


def write_prediction(out: Path, image: DepthImage, hyps: HypothesisSet, system: OPNetSystem, min_score: float) -> None:
    stem = image.path.stem
    poses = [{"R": R.tolist(), "t": t.tolist(), "score": float(s)} for R, t, s in zip(hyps.R, hyps.t, hyps.score)]
    doc = {"image": str(image.path), "frame": "camera (OpenCV: x right, y down, z forward), metres",
           "object": system.parameterization.obj.name, "poses": poses}
    write_text_atomic(out / f"{stem}.json", json.dumps(doc, indent=1))
    mesh = system.parameterization.obj.mesh
    if mesh is not None:
        img = draw_models(image.depth, image.camera, mesh.vertices, mesh.faces, hyps.above(min_score))
        ok, buf = cv2.imencode(".png", img[..., ::-1])
        if ok:
            (out / f"{stem}.png").write_bytes(buf.tobytes())


def run(cfg: DictConfig) -> int:
    """Entry logic of predict.py; returns the number of images that failed."""
    system, _ = load_checkpoint(cfg.ckpt)
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    camera_cfg = dict(cfg.camera) if cfg.get("camera") is not None else None
    failed = 0
    for path in list_inputs(Path(cfg.input)):
        try:
            image = load_depth_image(path, camera_cfg)
            hyps = predict_image(system, image)
            write_prediction(out, image, hyps, system, float(cfg.min_score))
            print(f"{path}: {len(hyps.above(cfg.min_score))} objects (score >= {cfg.min_score}), {len(hyps)} hypotheses")
        except (ValueError, FileNotFoundError) as e:
            failed += 1
            print(f"error: {e}")
    print(f"predictions written to {out}")
    return failed
