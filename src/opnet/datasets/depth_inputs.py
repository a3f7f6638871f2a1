"""Depth images as users have them, with their camera: dataset PNGs (the camera from the
``parameter.json`` / ``camera_params.txt`` above them), a camera's 16-bit PNG or a ``.npy`` with
intrinsics from the command line or a YAML, and folders of them. No PyTorch: predict.py and the
torch-free ONNX runner (``python -m opnet.deploy``) share it. Every error names the file.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from opnet.datasets.camera_file import (
    YAML_CAMERA_KEYS,
    camera_number,
    read_camera_yaml_pose,
    require_principal_point_inside,
)
from opnet.datasets.ipa_params import read_parameters
from opnet.datasets.outputs import folder_lock, require_output_folder
from opnet.datasets.png import decode_depth, read_png
from opnet.datasets.sileane import read_camera_params
from opnet.datasets.sileane_json import write_results_json
from opnet.fileio.atomic import remove_stale_temporaries, write_text_atomic
from opnet.fileio.files import require_regular_file
from opnet.geometry.camera import MAX_CLIP_END_M, MAX_IMAGE_SIDE, Camera
from opnet.geometry.frames import BASE_POSE_KEY, camera_to_base, camera_to_world
from opnet.metrics.records import HypothesisSet

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
    #: the camera's pose in the robot's base frame (4 x 4, camera to base) of ``camera.file``, or None
    T_base_cam: np.ndarray | None = None
    file: str | None = None  # camera.file
    #: the model's training camera (the values of a camera YAML's keys, in their order) for an image given
    #: without intrinsics
    default: tuple[float, ...] | None = None
    default_origin: str = ""

    def describe(self, key: str) -> str:
        return f"camera.{key}={self.values[key]:g} ({self.origin[key]})"

    def with_default(self, camera: tuple[float, ...] | None, model: str) -> GivenCamera:
        """These values, with ``model``'s training camera (None: none) for an image given without intrinsics."""
        return self if camera is None else dataclasses.replace(self, default=tuple(camera),
                                                               default_origin=f"the training camera of {model}")

    def sources(self) -> str:
        """Where the intrinsics came from: "command line", a YAML file, or both."""
        return " and ".join(sorted(set(self.origin[k] for k in INTRINSIC_KEYS)))


def given_camera(camera_cfg: dict[str, Any] | None) -> GivenCamera:
    """The camera values of the config: ``camera.file`` (a YAML of the same keys) merged with the
    keys given directly; the same key with two different values is an error naming both."""
    camera_cfg = dict(camera_cfg or {})
    values: dict[str, float] = {}
    origin: dict[str, str] = {}
    file = camera_cfg.pop("file", None)
    pose = None
    if file is not None:
        path = Path(str(file))
        numbers, pose = read_camera_yaml_pose(path)
        for key, x in numbers.items():
            values[key], origin[key] = x, str(path)
    for key in CAMERA_KEYS:
        value = camera_cfg.get(key)
        if value is None:
            continue
        x = camera_number(value, key, "command line")
        if key in values and not math.isclose(values[key], x, rel_tol=1e-9, abs_tol=1e-12):
            raise ValueError(f"camera.{key}: {x:g} on the command line conflicts with {values[key]:g} in {origin[key]}")
        values[key], origin[key] = x, "command line"
    given = GivenCamera(values, origin, pose, None if file is None else str(file))
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


def _with_default(path: Path, given: GivenCamera, width: int, height: int) -> GivenCamera:
    """``given`` with the model's training camera for the keys it lacks, where it gives none of the
    intrinsics; an image of another size than that camera's is a ValueError naming both."""
    if given.default is None or any(k in given.values for k in ("fx", "fy", "cx", "cy")):
        return given
    default = dict(zip(YAML_CAMERA_KEYS, given.default, strict=True))
    if (int(default["width"]), int(default["height"])) != (width, height):
        raise ValueError(f"{path}: no camera file above it and no intrinsics given; {given.default_origin} is "
                         f"{int(default['width'])}x{int(default['height'])}, the image {width}x{height}: give "
                         "camera.fx, camera.fy, camera.cx, camera.cy, camera.clip_start, camera.clip_end (or camera.file=<yaml>)")
    values = {**{k: default[k] for k in INTRINSIC_KEYS}, **given.values}
    origin = {**{k: given.default_origin for k in INTRINSIC_KEYS}, **given.origin}
    return dataclasses.replace(given, values=values, origin=origin)


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
    return require_principal_point_inside(cam.check_plausible(source), source)


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


def read_npy_image(path: Path) -> np.ndarray:
    """A 2-D image from a ``.npy`` file, its header checked before anything is allocated: at most
    :data:`MAX_IMAGE_SIDE` pixels a side, a numeric dtype, and a file size that matches the header
    (a header claiming 200000 x 200000, or a 30 GB sparse file, is refused without reading it).

    Raises:
        ValueError: naming the file: not a .npy, a bad header, a size mismatch, truncated data.
    """
    path = require_regular_file(path)
    try:
        with path.open("rb") as fh:
            version = np.lib.format.read_magic(fh)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh)
            elif version in ((2, 0), (3, 0)):
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(fh)
            else:
                raise ValueError(f"unsupported .npy version {version}")
            if len(shape) != 2 or min(shape) < 1:
                raise ValueError(f"expected a 2-D depth array (H, W), the header says shape {shape}")
            if max(shape) > MAX_IMAGE_SIDE:
                raise ValueError(f"the header says {shape[1]}x{shape[0]} pixels, more than {MAX_IMAGE_SIDE} a side")
            if dtype.kind not in "uif" or dtype.itemsize > 8:
                raise ValueError(f"dtype {dtype} is not a depth (expected float or integer numbers)")
            expected = fh.tell() + shape[0] * shape[1] * dtype.itemsize
            size = path.stat().st_size
            if size != expected:
                raise ValueError(f"the file holds {size} bytes, its header describes {expected} (truncated or padded)")
            data = np.fromfile(fh, dtype=dtype, count=shape[0] * shape[1])
    except OSError as e:
        raise ValueError(f"{path}: cannot read .npy ({e})") from None
    except ValueError as e:
        raise ValueError(f"{path}: cannot read .npy ({str(e)[:200]})") from None
    return data.reshape(shape, order="F" if fortran else "C")


def _load_npy(path: Path, given: GivenCamera) -> DepthImage:
    depth = read_npy_image(path)
    if depth.ndim != 2 or min(depth.shape) < 1:
        raise ValueError(f"{path}: expected a 2-D depth array (H, W), got shape {depth.shape}")
    scale = given.values.get("depth_scale")
    if np.issubdtype(depth.dtype, np.integer) and scale is not None:
        depth = depth.astype(np.float64) * scale
    elif not np.issubdtype(depth.dtype, np.floating):
        raise ValueError(f"{path}: expected float depth in metres, got dtype {depth.dtype} "
                         "(integer depth needs camera.depth_scale, metres per unit)")
    given = _with_default(path, given, depth.shape[1], depth.shape[0])
    cam = _camera_from_given(path, given, depth.shape[1], depth.shape[0])
    depth = depth.astype(np.float32)
    if np.isinf(depth).any():
        raise ValueError(f"{path}: depth holds infinite values")
    depth[depth <= 0] = np.nan
    check_depth_in_range(path, depth, cam)
    return DepthImage(path, depth, cam, f"{_describe_camera(cam)}, depth in metres (from {given.sources()})")


#: below this share of the valid pixels between the clip planes, an image's depth is in other
#: units or the clip planes are wrong (the network would see a blank image: 0 objects)
MIN_SHARE_IN_RANGE = 0.01


def check_depth_in_range(path: Path, depth: np.ndarray, cam: Camera) -> None:
    """Refuse a depth image (metres) of which (almost) no valid pixel lies between the camera's
    clip planes: millimetres in a ``.npy``, or clip planes of another setup.

    Raises:
        ValueError: naming ``path``, the median depth and the clip range.
    """
    valid = depth[np.isfinite(depth)]
    if valid.size == 0:  # no depth at all: nothing to find, and said so by "0 objects"
        return
    inside = float(np.count_nonzero((valid >= cam.clip_start) & (valid <= cam.clip_end))) / valid.size
    if inside >= MIN_SHARE_IN_RANGE:
        return
    median = float(np.median(valid))
    hint = ("millimetres? depth is in metres (an integer array takes camera.depth_scale, metres per unit)"
            if median > 100 * cam.clip_end else "check camera.clip_start and camera.clip_end (metres)")
    raise ValueError(f"{path}: {100 * inside:.2g} % of the valid depth lies between the clip planes "
                     f"[{cam.clip_start:g}, {cam.clip_end:g}] m (median {median:.4g}); {hint}")


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
        given = _with_default(path, given, w, h)
        cam = _camera_from_given(path, given, w, h)
        scale = given.values.get("depth_scale")
        if scale is not None:
            depth = code.astype(np.float32) * np.float32(scale)
            depth[code == 0] = np.nan
            encoding = f"depth = value x {scale:g} m, 0 = none"
            check_depth_in_range(path, depth, cam)
        else:
            depth = decode_depth(code, cam.clip_start, cam.clip_end)
            encoding = "depth coded between the clip planes, 65535 = none"
        return DepthImage(path, depth, cam, f"{_describe_camera(cam)}, {encoding} (from {given.sources()})")
    _check_agrees(path, cam, source, given)
    if (h, w) != (cam.height, cam.width):
        # a crop or a resize changes the intrinsics in ways the image alone cannot tell: refuse
        raise ValueError(f"{path}: image is {w}x{h} but its camera {source} is {cam.width}x{cam.height}; give the "
                         "image at the camera's size, or move it out of that folder and give its own intrinsics "
                         "(camera.fx=... camera.fy=... camera.cx=... camera.cy=... camera.clip_start=... camera.clip_end=...)")
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


#: the files a run writes per image besides ``results/<scene>.json``: the torch-free runner's;
#: predict.py adds the overlay and the point cloud
POSE_SUFFIXES: tuple[str, ...] = (".json",)


def planned_outputs(out: Path, inputs: list[tuple[Path, Path]], suffixes: tuple[str, ...]) -> dict[Path, Path]:
    """Every file a run writes, each with its input: ``<out>/<name><suffix>`` and
    ``<out>/results/<scene>.json`` per image.

    Raises:
        ValueError: two inputs would write the same file (``a/x.npy`` and ``a_x.npy`` both give the
            scene ``a_x``; ``results/y.npy`` gives a pose file where ``y``'s results go); the
            message names both inputs and the file.
    """
    scenes = scene_names(inputs)
    planned: dict[Path, Path] = {}
    for path, name in inputs:
        for target in (*(out / f"{name}{suffix}" for suffix in suffixes), out / "results" / f"{scenes[name]}.json"):
            if target in planned:
                raise ValueError(f"{path} and {planned[target]} would both be written as {target}; rename one of them")
            planned[target] = path
    return planned


def check_outputs(out: Path, inputs: list[tuple[Path, Path]], overwrite: bool,
                  suffixes: tuple[str, ...] = POSE_SUFFIXES, option: str = "out=") -> None:
    """Refuse outputs that would overwrite an input or each other, or existing outputs without
    ``overwrite``; ``option`` is how the user names the output folder (``out=``, ``--out``)."""
    overwrite_option = "--overwrite" if option.startswith("--") else "overwrite=true"
    sources = {p.resolve() for p, _ in inputs}
    existing = []
    for target in planned_outputs(out, inputs, suffixes):
        if target.resolve() in sources:
            raise ValueError(f"{target}: the output would overwrite an input image; choose another out=")
        if target.exists():
            existing.append(target)
    if existing and not overwrite:
        more = f" (and {len(existing) - 1} more)" if len(existing) > 1 else ""
        raise ValueError(f"{existing[0]}{more}: predictions exist already; pass {overwrite_option} to replace them, "
                         f"or choose another {option}")


@contextlib.contextmanager
def claimed_outputs(out: Path, inputs: list[tuple[Path, Path]], overwrite: bool, suffixes: tuple[str, ...],
                    other_inputs: tuple[Path, ...] = (), option: str = "out=") -> Iterator[dict[Path, str]]:
    """Hold ``out`` for one run: refuse an ``out`` that is an input (an image, the model in
    ``other_inputs``) or a file, lock the folder (:func:`opnet.datasets.outputs.folder_lock`: a
    concurrent run into it stops with an error naming it), check the outputs inside the lock
    (:func:`check_outputs`), remove what a run killed while writing one of them left (its temporary
    files: the planned file itself was never replaced), and yield the results-file scene name of every
    input."""
    require_output_folder(out, [*(p for p, _ in inputs), *other_inputs], option)
    planned = planned_outputs(out, inputs, suffixes)  # name clashes: refused before anything is created
    with folder_lock(out, option):
        check_outputs(out, inputs, overwrite, suffixes, option)
        remove_stale_temporaries(planned)
        yield scene_names(inputs)


def predict_inputs(inputs: list[tuple[Path, Path]], given: GivenCamera, out: Path, scenes: dict[Path, str],
                   estimate: Callable[[DepthImage], HypothesisSet],
                   write: Callable[[Path, DepthImage, HypothesisSet, str], object], min_score: float = 0.5) -> int:
    """Read, estimate and write (``write(name, image, hyps, scene)``) every input, each on its
    console line; a bad image is reported and the others go on. Returns the number that failed."""
    failed, last_camera = 0, None
    for path, name in inputs:
        try:
            image = load_depth_image(path, given)
            if image.camera_source != last_camera:
                print(f"camera: {image.camera_source}")
                last_camera = image.camera_source
            hyps = estimate(image)
            (out / name).parent.mkdir(parents=True, exist_ok=True)
            write(name, image, hyps, scenes[name])
            print(f"{path}: {len(hyps.above(min_score))} objects (score >= {min_score:g}), {len(hyps)} hypotheses")
        except (ValueError, FileNotFoundError) as e:
            failed += 1
            print(f"error: {e}")
    return failed


def results_name(name: Path) -> str:
    """The scene name of a prediction: ``cycle_XXXX_NNN`` for an IPA depth image
    (``cycle_XXXX/NNN_depth_uint16``), else the image's stem (Siléane ``depth/<scene>``)."""
    m = re.fullmatch(r"(cycle_\d+)/(\d+)_depth_uint16", name.as_posix())
    return f"{m.group(1)}_{m.group(2)}" if m else name.name


def scene_names(inputs: list[tuple[Path, Path]]) -> dict[Path, str]:
    """The results-file scene name of every input (folders kept in the name when stems collide)."""
    scenes = {name: results_name(name) for _, name in inputs}
    if len(set(scenes.values())) < len(scenes):  # equal stems in different folders: keep the folders in the name
        scenes = {name: name.as_posix().replace("/", "_") for name in scenes}
    return scenes


def base_pose(given: GivenCamera, recorded: np.ndarray | None, model: str) -> np.ndarray | None:
    """The camera's pose in the robot's base frame a run writes base-frame poses with: the camera
    file's ``T_base_cam``, else the one ``model`` records (its cell's), else None; said on the console."""
    if given.T_base_cam is not None:
        replaced = recorded is not None and not np.allclose(given.T_base_cam, recorded, atol=1e-9)
        print(f"base frame: {BASE_POSE_KEY} of {given.file}" + (f" (in place of the one {model} records)" if replaced else ""))
        return given.T_base_cam
    if recorded is not None:
        print(f"base frame: {BASE_POSE_KEY} recorded in {model}")
    return recorded


def _pose_list(R: np.ndarray, t: np.ndarray, score: np.ndarray) -> list[dict[str, Any]]:
    return [{"R": r.tolist(), "t": x.tolist(), "score": float(s)} for r, x, s in zip(R, t, score)]


def write_pose_files(out: Path, name: Path, image: DepthImage, hyps: HypothesisSet, object_name: str,
                     scene: str | None = None, T_base_cam: np.ndarray | None = None) -> list[Path]:
    """Write ``<out>/<name>.json`` (poses in the camera frame, the world frame when the camera pose
    is known, and the robot's base frame as ``poses_base`` when ``T_base_cam`` is given) and
    ``<out>/results/<scene>.json`` (the Siléane results format, world frame when known, which
    opnet-evaluate reads as it is); returns both paths."""
    doc = {"image": str(image.path), "frame": "camera (OpenCV: x right, y down, z forward), metres",
           "camera": {k: getattr(image.camera, k) for k in ("fx", "fy", "cx", "cy", "width", "height", "clip_start", "clip_end")},
           "object": object_name, "poses": _pose_list(hyps.R, hyps.t, hyps.score)}
    R_out, t_out = hyps.R, hyps.t
    if image.world_from_camera is not None:  # Siléane: the camera pose is known, give world poses too
        R_out, t_out = camera_to_world(hyps.R, hyps.t, *image.world_from_camera)
        doc["poses_world"] = _pose_list(R_out, t_out, hyps.score)
    if T_base_cam is not None:  # the robot's base frame: X_base = T_base_cam X_cam
        doc[BASE_POSE_KEY] = np.asarray(T_base_cam, np.float64).tolist()
        doc["poses_base"] = _pose_list(*camera_to_base(hyps.R, hyps.t, T_base_cam), hyps.score)
    written = [out / f"{name}.json", out / "results" / f"{scene or results_name(name)}.json"]
    write_text_atomic(written[0], json.dumps(doc, indent=1))
    write_results_json(written[1], HypothesisSet(R_out, t_out, hyps.score, hyps.visibility))
    return written
