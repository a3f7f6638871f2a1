"""``python predict.py ckpt=<path> input=<file or folder> out=<dir>``: depth images -> poses.

Accepted inputs:
- a 16-bit depth PNG. Its camera comes from, in this order of lookup:
  1. a dataset camera file above it: ``parameter.json`` (IPA) or ``camera_params.txt`` (Siléane),
     depth coded between the clip planes. Values given in the config must agree with that file
     (a conflict is an error naming both);
  2. else the config: ``camera.fx, fy, cx, cy, clip_start, clip_end`` on the command line and/or in
     a camera YAML (``camera.file=<yaml>`` with the same keys); with none of ``fx, fy, cx, cy``
     given, the camera of the training scenes the checkpoint records, for an image of its size. The PNG's depth encoding is
     ``camera.depth_scale`` metres per unit (0.001 for millimetre PNGs of RealSense / Kinect /
     Zivid exports; 0 = no depth) or, when it is null, the datasets' code between the clip planes
     (65535 = no depth).
  The network normalizes depth with the clip planes of its training scenes, which checkpoints
  written by train.py record (``trained_clip``): ``clip=model`` (the default) uses them whatever
  planes the camera gives, ``clip=camera`` the camera's, ``clip=[near,far]`` those (a checkpoint
  that records none: the camera's).
- a ``.npy`` array of depth in metres (NaN or 0 = missing; an integer array with
  ``camera.depth_scale``), with the intrinsics from the config as in 2.
- a folder: every such file in it (recursively, regular files only).
Per image it writes ``<name>.json`` (poses R, t in metres in the camera frame, score, in the
world frame when the camera pose is known: Siléane ``camera_params.txt``, and in the robot's base
frame as ``poses_base`` when the camera YAML (``camera.file``) or the checkpoint (its cell's) gives
``T_base_cam``), ``results/<scene>.json``
(the Siléane results format, world frame when known, which ``opnet-evaluate`` scores as it is),
``<name>.png`` (the depth image with each estimated object's model projected on it) and
``<name>.ply`` (the scene's points and the posed models, for any 3-D viewer), where
``<name>`` mirrors the image's path relative to the input folder (``cycle_0001/004_depth_uint16``),
so images of the same name in different folders never overwrite each other. An existing output is
never overwritten unless ``overwrite=true``; two inputs that would write the same file, an ``out=``
that is an input, and a second run into a folder another run is writing into are refused.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from opnet.cli.build import load_checkpoint
from opnet.cli.eval import model_settings
from opnet.data.preprocess import to_network_input
from opnet.data.preprocess_torch import to_network_input as device_input
from opnet.data.roi import crop_image, parse_roi
from opnet.datasets.depth_inputs import (
    DepthImage,
    base_pose,
    claimed_outputs,
    given_camera,
    list_inputs,
    predict_inputs,
    write_pose_files,
)
from opnet.fileio.atomic import write_bytes_atomic
from opnet.geometry.camera import describe_clip, with_clip, working_clip
from opnet.metrics.records import HypothesisSet
from opnet.refine import Refiner
from opnet.estimator import PoseEstimator
from opnet.visualize import draw_models

log = logging.getLogger(__name__)


@torch.no_grad()
def predict_image(system: PoseEstimator, image: DepthImage, roi: Any = "checkpoint") -> HypothesisSet:
    """Pose hypotheses for one depth image (camera frame, metres).

    Args:
        roi: the region of interest (:mod:`opnet.data.roi`, parsed); ``"checkpoint"``: the
            training's (the system's :class:`~opnet.run_settings.InputSettings`).
    """
    framing = system.settings.input  # the training's
    size, fit = framing.size, framing.fit
    roi = framing.roi if roi == "checkpoint" else roi
    depth, camera = crop_image(image.depth, image.camera, roi, f"{image.path}: roi")
    graphed = system.graphed_pipeline(camera, size, fit)
    if graphed is not None:  # on a GPU: preprocessing, network and decoding replayed as one CUDA graph
        try:
            return graphed(depth)
        except ValueError as exc:
            raise ValueError(f"{image.path}: {exc}; no poses written for it") from exc
    if system.device_side:  # the same input, computed on the model's device (inference.device_side)
        x, net_cam = device_input(depth, camera, size=size, fit=fit, device=system.device)
    else:
        net_in, net_cam = to_network_input(depth, camera, size=size, interpolation=cv2.INTER_AREA, fit=fit)
        x = torch.from_numpy(net_in)[None, None].to(system.device)
    output = system.infer(x)
    if not bool(torch.isfinite(output).all()):  # would decode to "0 objects" without a word
        raise ValueError(f"{image.path}: the network's output holds NaN or inf (diverged weights or an input it "
                         "cannot take); no poses written for it")
    return system.decode(output, [net_cam], x)[0]


def write_prediction(out: Path, name: Path, image: DepthImage, hyps: HypothesisSet, system: PoseEstimator,
                     min_score: float, scene: str | None = None, T_base_cam: np.ndarray | None = None) -> list[Path]:
    """Write ``<out>/<name>.json`` (with base-frame poses when ``T_base_cam`` is given) and (with a
    mesh) ``<out>/<name>.png``; returns the files written."""
    written = write_pose_files(out, name, image, hyps, system.parameterization.obj.name, scene, T_base_cam)
    mesh = system.parameterization.obj.mesh
    if mesh is not None:
        img = draw_models(image.depth, image.camera, mesh.vertices, mesh.faces, hyps.above(min_score))
        ok, buf = cv2.imencode(".png", img[..., ::-1])
        if ok:
            written.append(out / f"{name}.png")
            write_bytes_atomic(written[-1], buf.tobytes())
        written.append(out / f"{name}.ply")
        write_point_cloud(written[-1], image, mesh, hyps.above(min_score))
    return written


#: at most this many scene points in the PLY (a 1296 x 1024 frame is subsampled on a regular grid)
PLY_MAX_POINTS = 300_000


def write_point_cloud(path: Path, image: DepthImage, mesh: Any, hyps: HypothesisSet) -> None:
    """A binary PLY for any 3-D viewer: the scene's points (camera frame, grey by depth) and each
    estimated object's posed model surface (one colour per object)."""
    import trimesh

    h, w = image.depth.shape
    step = max(1, int(math.ceil(math.sqrt(h * w / PLY_MAX_POINTS))))
    depth = image.depth[::step, ::step]
    v, u = np.mgrid[0:h:step, 0:w:step]
    ok = np.isfinite(depth)
    z = depth[ok].astype(np.float64)
    pts = np.stack([(u[ok] - image.camera.cx) * z / image.camera.fx, (v[ok] - image.camera.cy) * z / image.camera.fy, z], 1)
    span = max(float(np.ptp(z)), 1e-6) if len(z) else 1.0
    grey = (200 - 150 * (z - z.min()) / span).astype(np.uint8) if len(z) else np.zeros(0, np.uint8)
    colours = [np.stack([grey, grey, grey, np.full_like(grey, 255)], 1)]
    points = [pts]
    surface = trimesh.sample.sample_surface_even(mesh, 4000, seed=0)[0] if len(hyps) else np.zeros((0, 3))
    palette = (np.array(_PALETTE) * 255).astype(np.uint8)
    for k, (R, t) in enumerate(zip(hyps.R, hyps.t)):
        points.append(surface @ R.T + t)
        colours.append(np.tile([*palette[k % len(palette)], 255], (len(surface), 1)).astype(np.uint8))
    vertices, rgba = np.concatenate(points), np.concatenate(colours)
    if len(vertices) == 0:  # no depth at all and nothing found: an empty cloud, as a valid PLY
        header = "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
        write_bytes_atomic(path, header.encode())
        return
    write_bytes_atomic(path, trimesh.PointCloud(vertices, colors=rgba).export(file_type="ply"))


_PALETTE = [(0.9, 0.1, 0.1), (0.1, 0.7, 0.1), (0.1, 0.3, 0.9), (0.9, 0.6, 0.0), (0.6, 0.1, 0.8), (0.0, 0.7, 0.7)]


#: the files predict.py writes per image besides ``results/<scene>.json``
PREDICT_SUFFIXES = (".json", ".png", ".ply")


def run(cfg: DictConfig) -> int:
    """Entry logic of predict.py; returns the number of images that failed (bad input of the whole
    run, e.g. a missing checkpoint or conflicting camera values, raises ValueError instead)."""
    camera_cfg = OmegaConf.to_container(cfg.camera, resolve=True) if cfg.get("camera") is not None else None
    given = given_camera(camera_cfg)
    system, _ = load_checkpoint(cfg.ckpt)
    icp = model_settings(system, cfg.get("refine"), cfg.get("decoding"))
    print(f"inference: {system.configure_inference(cfg.get('inference'))}")
    trained = system.settings.input.trained_clip
    clip = working_clip(cfg.get("clip"), trained)
    print(describe_clip(clip, trained))
    refiner = Refiner.for_object(system.parameterization.obj, icp) if icp is not None else None
    recorded = system.settings.T_base_cam
    T_base_cam = base_pose(given, None if recorded is None else np.array(recorded), str(cfg.ckpt))
    given = given.with_default(system.settings.camera, str(cfg.ckpt))

    roi = "checkpoint" if cfg.get("roi") is None else parse_roi(cfg.roi, "roi")

    def estimate(image: DepthImage) -> HypothesisSet:
        if clip is not None:  # the model's working range in place of the camera's (the input's normalization)
            image = dataclasses.replace(image, camera=with_clip(image.camera, clip))
        hyps = predict_image(system, image, roi)
        return hyps if refiner is None else refiner(hyps, image.depth, image.camera)[0]

    out = Path(cfg.out)
    inputs = list_inputs(Path(cfg.input))
    overwrite, min_score = bool(cfg.get("overwrite", False)), float(cfg.min_score)
    with claimed_outputs(out, inputs, overwrite, PREDICT_SUFFIXES, (Path(cfg.ckpt),)) as scenes:
        failed = predict_inputs(
            inputs, given, out, scenes, estimate,
            lambda name, image, hyps, scene: write_prediction(out, name, image, hyps, system, min_score, scene,
                                                              T_base_cam),
            min_score)  # fmt: skip
    written = len(inputs) - failed
    if written:
        print(f"{written} of {len(inputs)} predictions written to {out}" + (f" ({failed} failed)" if failed else ""))
    else:
        print(f"no predictions written: all {len(inputs)} input(s) failed")
    return failed
