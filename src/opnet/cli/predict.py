"""``python predict.py ckpt=<path> input=<file or folder> out=<dir>``: depth images -> poses.

Accepted inputs:
- a 16-bit depth PNG. Its camera comes from, in this order of lookup:
  1. a dataset camera file above it: ``parameter.json`` (IPA) or ``camera_params.txt`` (Siléane),
     depth coded between the clip planes. Values given in the config must agree with that file
     (a conflict is an error naming both);
  2. else the config: ``camera.fx, fy, cx, cy, clip_start, clip_end`` on the command line and/or in
     a camera YAML (``camera.file=<yaml>`` with the same keys). The PNG's depth encoding is
     ``camera.depth_scale`` metres per unit (0.001 for millimetre PNGs of RealSense / Kinect /
     Zivid exports; 0 = no depth) or, when it is null, the datasets' code between the clip planes
     (65535 = no depth). The clip planes also set the network's depth normalization: use the
     working range of the training data.
- a ``.npy`` array of depth in metres (NaN or 0 = missing; an integer array with
  ``camera.depth_scale``), with the intrinsics from the config as in 2.
- a folder: every such file in it (recursively, regular files only).
Per image it writes ``<name>.json`` (poses R, t in metres in the camera frame, score, and in the
world frame when the camera pose is known: Siléane ``camera_params.txt``), ``results/<scene>.json``
(the Siléane results format, world frame when known, which ``opnet-evaluate`` scores as it is),
``<name>.png`` (the depth image with each estimated object's model projected on it) and
``<name>.ply`` (the scene's points and the posed models, for any 3-D viewer), where
``<name>`` mirrors the image's path relative to the input folder (``cycle_0001/004_depth_uint16``),
so images of the same name in different folders never overwrite each other. An existing output is
never overwritten unless ``overwrite=true``.
"""

from __future__ import annotations

import io
import json
import logging
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
import yaml
from omegaconf import DictConfig, OmegaConf

from opnet.cli.build import load_checkpoint
from opnet.data.preprocess import to_network_input
from opnet.datasets.atomic import write_bytes_atomic, write_text_atomic
from opnet.datasets.files import read_bytes, read_text, require_regular_file
from opnet.datasets.ipa_params import read_parameters
from opnet.datasets.png import decode_depth, read_png
from opnet.datasets.sileane import read_camera_params
from opnet.datasets.sileane_json import write_results_json
from opnet.geometry.camera import MAX_CLIP_END_M, Camera
from opnet.geometry.frames import camera_to_world
from opnet.metrics.records import HypothesisSet
from opnet.system import OPNetSystem
from opnet.visualize import draw_models

log = logging.getLogger(__name__)
IMAGE_SUFFIXES = {".png", ".npy"}
INTRINSIC_KEYS = ("fx", "fy", "cx", "cy", "clip_start", "clip_end")
CAMERA_KEYS = (*INTRINSIC_KEYS, "width", "height", "depth_scale")


@dataclass
class DepthImage:
    path: Path
    depth: np.ndarray  # (H, W) float32 metres, NaN = missing
    camera: Camera
    camera_source: str = ""  # where the camera came from, for the console
    world_from_camera: tuple[np.ndarray, np.ndarray] | None = None  # (R_world_cam, t_world_cam) when known


@dataclass
class GivenCamera:
    """Camera values given by the user (command line and/or a camera YAML), each with its origin."""

    values: dict[str, float]
    origin: dict[str, str]

    def describe(self, key: str) -> str:
        return f"camera.{key}={self.values[key]:g} ({self.origin[key]})"

    def sources(self) -> str:
        """Where the intrinsics came from: "command line", a YAML file, or both."""
        return " and ".join(sorted(set(self.origin[k] for k in INTRINSIC_KEYS)))


def _number(value: Any, key: str, origin: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{origin}: camera.{key}={value!r} is not a number") from None
    if not math.isfinite(x):
        raise ValueError(f"{origin}: camera.{key}={value!r} is not finite")
    return x


def given_camera(camera_cfg: dict[str, Any] | None) -> GivenCamera:
    """The camera values of the config: ``camera.file`` (a YAML of the same keys) merged with the
    keys given directly; the same key with two different values is an error naming both."""
    camera_cfg = dict(camera_cfg or {})
    values: dict[str, float] = {}
    origin: dict[str, str] = {}
    file = camera_cfg.pop("file", None)
    if file is not None:
        path = Path(str(file))
        try:
            doc = yaml.safe_load(read_text(path))
        except yaml.YAMLError as e:
            raise ValueError(f"{path}: malformed camera YAML ({e})") from None
        if not isinstance(doc, dict):
            raise ValueError(f"{path}: a camera YAML holds a mapping of {', '.join(CAMERA_KEYS)}")
        unknown = sorted(set(map(str, doc)) - set(CAMERA_KEYS))
        if unknown:
            raise ValueError(f"{path}: unknown camera key(s) {unknown}; expected {', '.join(CAMERA_KEYS)}")
        for key, value in doc.items():
            if value is not None:
                values[key], origin[key] = _number(value, key, str(path)), str(path)
    for key in CAMERA_KEYS:
        value = camera_cfg.get(key)
        if value is None:
            continue
        x = _number(value, key, "command line")
        if key in values and not math.isclose(values[key], x, rel_tol=1e-9, abs_tol=1e-12):
            raise ValueError(f"camera.{key}: {x:g} on the command line conflicts with {values[key]:g} in {origin[key]}")
        values[key], origin[key] = x, "command line"
    given = GivenCamera(values, origin)
    _check_plausible(given)
    return given


def _check_plausible(given: GivenCamera) -> None:
    """Units and signs of the given values, before any image is read (clip planes in metres)."""
    v = given.values
    for key in ("fx", "fy", "width", "height", "depth_scale"):
        if key in v and v[key] <= 0:
            raise ValueError(f"{given.describe(key)}: must be positive")
    for key in ("width", "height"):
        if key in v and v[key] != int(v[key]):
            raise ValueError(f"{given.describe(key)}: must be a whole number of pixels")
    if "clip_end" in v and v["clip_end"] > MAX_CLIP_END_M:
        raise ValueError(f"{given.describe('clip_end')}: clip planes are in metres; "
                         f"{v['clip_end']:g} m is implausible (millimetres? divide by 1000)")
    if "clip_start" in v and "clip_end" in v and not 0 < v["clip_start"] < v["clip_end"]:
        raise ValueError(f"{given.describe('clip_start')}, {given.describe('clip_end')}: "
                         "expected 0 < clip_start < clip_end (metres)")
    if "depth_scale" in v and v["depth_scale"] > 1.0:
        raise ValueError(f"{given.describe('depth_scale')}: metres per depth unit, expected <= 1 (0.001 for millimetres)")


def _camera_from_given(path: Path, given: GivenCamera, width: int, height: int) -> Camera:
    missing = [k for k in INTRINSIC_KEYS if k not in given.values]
    if missing:
        raise ValueError(f"{path}: no parameter.json (IPA) or camera_params.txt (Siléane) above it, so the camera "
                         f"must be given: missing camera.{', camera.'.join(missing)} (command line or camera.file=<yaml>)")
    for key, size in (("width", width), ("height", height)):
        if key in given.values and int(given.values[key]) != size:
            raise ValueError(f"{path}: image is {width}x{height} but {given.describe(key)}")
    v = given.values
    source = f"{path}: camera from {given.sources()}"
    try:
        cam = Camera(v["fx"], v["fy"], v["cx"], v["cy"], width, height, v["clip_start"], v["clip_end"])
    except ValueError as e:
        raise ValueError(f"{source}: {e}") from None
    return cam.check_plausible(source)


def _check_agrees(path: Path, cam: Camera, source: Path, given: GivenCamera) -> None:
    """A camera value given in the config must equal the camera file's (no silent precedence)."""
    if "depth_scale" in given.values:
        raise ValueError(f"{path}: {given.describe('depth_scale')} conflicts with {source}, whose PNGs are coded "
                         "between its clip planes; drop camera.depth_scale or move the image out of that folder")
    for key in ("fx", "fy", "cx", "cy", "clip_start", "clip_end", "width", "height"):
        if key in given.values:
            mine = float(getattr(cam, key))
            if not math.isclose(mine, given.values[key], rel_tol=1e-6, abs_tol=1e-9):
                raise ValueError(f"{path}: {given.describe(key)} conflicts with {key}={mine:g} of {source}; "
                                 "drop the override, or move the image out of that dataset folder")


def _find_upwards(path: Path, name: str, levels: int = 4) -> Path | None:
    for parent in list(path.parents)[:levels]:
        if (parent / name).is_file():
            return parent / name
    return None


def _describe_camera(cam: Camera) -> str:
    return (f"fx={cam.fx:g} fy={cam.fy:g} cx={cam.cx:g} cy={cam.cy:g} {cam.width}x{cam.height} "
            f"clip [{cam.clip_start:g}, {cam.clip_end:g}] m")


def _load_npy(path: Path, given: GivenCamera) -> DepthImage:
    try:
        depth = np.load(io.BytesIO(read_bytes(path)), allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise ValueError(f"{path}: cannot read .npy ({type(e).__name__}: {e})") from None
    if depth.ndim != 2 or min(depth.shape) < 1:
        raise ValueError(f"{path}: expected a 2-D depth array (H, W), got shape {depth.shape}")
    scale = given.values.get("depth_scale")
    if np.issubdtype(depth.dtype, np.integer) and scale is not None:
        depth = depth.astype(np.float64) * scale
    elif not np.issubdtype(depth.dtype, np.floating):
        raise ValueError(f"{path}: expected float depth in metres, got dtype {depth.dtype} "
                         "(integer depth needs camera.depth_scale, metres per unit)")
    cam = _camera_from_given(path, given, depth.shape[1], depth.shape[0])
    depth = depth.astype(np.float32)
    if np.isinf(depth).any():
        raise ValueError(f"{path}: depth holds infinite values")
    depth[depth <= 0] = np.nan
    return DepthImage(path, depth, cam, f"{_describe_camera(cam)}, depth in metres (from {given.sources()})")


def _load_png(path: Path, given: GivenCamera) -> DepthImage:
    if (params := _find_upwards(path, "parameter.json")) is not None:
        source: Path | None = params
        cam = read_parameters(params).camera()
    elif (cp := _find_upwards(path, "camera_params.txt")) is not None:
        source = cp
        cam, R_wc, t_wc = read_camera_params(cp)
    else:
        source = None
    code = read_png(path, np.uint16)
    h, w = code.shape
    if source is None:
        cam = _camera_from_given(path, given, w, h)
        scale = given.values.get("depth_scale")
        if scale is not None:
            depth = code.astype(np.float32) * np.float32(scale)
            depth[code == 0] = np.nan
            encoding = f"depth = value x {scale:g} m, 0 = none"
        else:
            depth = decode_depth(code, cam.clip_start, cam.clip_end)
            encoding = "depth coded between the clip planes, 65535 = none"
        return DepthImage(path, depth, cam, f"{_describe_camera(cam)}, {encoding} (from {given.sources()})")
    _check_agrees(path, cam, source, given)
    if (h, w) != (cam.height, cam.width):
        # a crop or a resized image: keep the intrinsics consistent by scaling them
        log.warning("%s: image %sx%s differs from the camera's %sx%s; scaling the intrinsics", path, w, h, cam.width, cam.height)
        cam = cam.resized(w, h)
    world = (R_wc, t_wc) if source.name == "camera_params.txt" else None
    return DepthImage(path, decode_depth(code, cam.clip_start, cam.clip_end), cam,
                      f"{_describe_camera(cam)}, depth coded between the clip planes (from {source})", world)


def load_depth_image(path: Path, camera_cfg: dict[str, Any] | GivenCamera | None) -> DepthImage:
    """Read one depth image with its camera; raises ValueError naming the file on bad input."""
    given = camera_cfg if isinstance(camera_cfg, GivenCamera) else given_camera(camera_cfg)
    require_regular_file(path)
    if path.suffix.lower() == ".npy":
        return _load_npy(path, given)
    if path.suffix.lower() == ".png":
        return _load_png(path, given)
    raise ValueError(f"{path}: unsupported input {path.suffix!r}; expected a 16-bit .png or a .npy")


def list_inputs(path: Path) -> list[tuple[Path, Path]]:
    """The depth images of ``path`` (a file or a folder), each with its output name (no suffix):
    the path relative to the folder, so that equal names in different folders stay apart."""
    if not path.exists():
        raise FileNotFoundError(f"{path}: input not found")
    if not path.is_dir():
        require_regular_file(path)
        return [(path, Path(path.stem))]
    files = sorted(p for p in path.rglob("*") if p.suffix.lower() in IMAGE_SUFFIXES and "segmentation" not in p.name
                   and "segmentation" not in p.parent.name and "rgb" not in p.parent.name)
    if not files:
        raise ValueError(f"{path}: no .png or .npy depth images in this folder")
    pairs = [(p, p.relative_to(path).with_suffix("")) for p in files]
    seen: dict[Path, Path] = {}
    for p, name in pairs:
        if name in seen:
            raise ValueError(f"{p} and {seen[name]} would both be written as {name}.json; rename one of them")
        seen[name] = p
    return pairs


def _check_outputs(out: Path, inputs: list[tuple[Path, Path]], overwrite: bool) -> None:
    sources = {p.resolve() for p, _ in inputs}
    existing = []
    for _, name in inputs:
        for target in (out / f"{name}.json", out / f"{name}.png"):
            if target.resolve() in sources:  # (the .ply and results/ files never clash with .png/.npy inputs)
                raise ValueError(f"{target}: the output would overwrite an input image; choose another out=")
            if target.exists():
                existing.append(target)
    if existing and not overwrite:
        more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
        raise ValueError(f"{existing[0]}{more}: predictions exist already; pass overwrite=true to replace them, "
                         "or choose another out=")


@torch.no_grad()
def predict_image(system: OPNetSystem, image: DepthImage) -> HypothesisSet:
    """Pose hypotheses for one depth image (camera frame, metres)."""
    size = int(system.hparams.get("config", {}).get("data", {}).get("input_size", 128))
    net_in, net_cam = to_network_input(image.depth, image.camera, size=size, interpolation=cv2.INTER_AREA)
    x = torch.from_numpy(net_in)[None, None].to(system.device)
    return system.parameterization.decode(system.infer(x), [net_cam])[0]


def write_prediction(out: Path, name: Path, image: DepthImage, hyps: HypothesisSet, system: OPNetSystem,
                     min_score: float, scene: str | None = None) -> list[Path]:
    """Write ``<out>/<name>.json`` and (with a mesh) ``<out>/<name>.png``; returns the files written."""
    poses = [{"R": R.tolist(), "t": t.tolist(), "score": float(s)} for R, t, s in zip(hyps.R, hyps.t, hyps.score)]
    doc = {"image": str(image.path), "frame": "camera (OpenCV: x right, y down, z forward), metres",
           "camera": {k: getattr(image.camera, k) for k in ("fx", "fy", "cx", "cy", "width", "height", "clip_start", "clip_end")},
           "object": system.parameterization.obj.name, "poses": poses}
    R_out, t_out = hyps.R, hyps.t
    if image.world_from_camera is not None:  # Siléane: the camera pose is known, give world poses too
        R_out, t_out = camera_to_world(hyps.R, hyps.t, *image.world_from_camera)
        doc["poses_world"] = [{"R": R.tolist(), "t": t.tolist(), "score": float(s)}
                              for R, t, s in zip(R_out, t_out, hyps.score)]
    written = [out / f"{name}.json", out / "results" / f"{scene or results_name(name)}.json"]
    write_text_atomic(written[0], json.dumps(doc, indent=1))
    # the Siléane results format (world frame when known), which opnet-evaluate reads as it is
    write_results_json(written[1], HypothesisSet(R_out, t_out, hyps.score, hyps.visibility))
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


def results_name(name: Path) -> str:
    """The scene name of a prediction: ``cycle_XXXX_NNN`` for an IPA depth image
    (``cycle_XXXX/NNN_depth_uint16``), else the image's stem (Siléane ``depth/<scene>``)."""
    m = re.fullmatch(r"(cycle_\d+)/(\d+)_depth_uint16", name.as_posix())
    return f"{m.group(1)}_{m.group(2)}" if m else name.name


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


def run(cfg: DictConfig) -> int:
    """Entry logic of predict.py; returns the number of images that failed (bad input of the whole
    run, e.g. a missing checkpoint or conflicting camera values, raises ValueError instead)."""
    camera_cfg = OmegaConf.to_container(cfg.camera, resolve=True) if cfg.get("camera") is not None else None
    given = given_camera(camera_cfg)
    system, _ = load_checkpoint(cfg.ckpt)
    print(f"inference: {system.configure_inference(cfg.get('inference'))}")
    out = Path(cfg.out)
    inputs = list_inputs(Path(cfg.input))
    _check_outputs(out, inputs, bool(cfg.get("overwrite", False)))
    scenes = {name: results_name(name) for _, name in inputs}
    if len(set(scenes.values())) < len(scenes):  # equal stems in different folders: keep the folders in the name
        scenes = {name: name.as_posix().replace("/", "_") for name in scenes}
    failed, written, last_camera = 0, 0, None
    for path, name in inputs:
        try:
            image = load_depth_image(path, given)
            if image.camera_source != last_camera:
                print(f"camera: {image.camera_source}")
                last_camera = image.camera_source
            hyps = predict_image(system, image)
            (out / name).parent.mkdir(parents=True, exist_ok=True)
            write_prediction(out, name, image, hyps, system, float(cfg.min_score), scenes[name])
            written += 1
            print(f"{path}: {len(hyps.above(cfg.min_score))} objects (score >= {cfg.min_score}), {len(hyps)} hypotheses")
        except (ValueError, FileNotFoundError) as e:
            failed += 1
            print(f"error: {e}")
    if written:
        print(f"{written} of {len(inputs)} predictions written to {out}" + (f" ({failed} failed)" if failed else ""))
    else:
        print(f"no predictions written: all {len(inputs)} input(s) failed")
    return failed
