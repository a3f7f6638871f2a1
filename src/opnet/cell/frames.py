"""A cell's depth frames as a user has them, checked against the camera file before anything is measured.

The frames: a ``.npy`` of metres (or of integers with ``depth_scale``, metres per unit), a 16-bit PNG
(``depth_scale`` metres per unit, 0 = none; inside an IPA or Siléane dataset folder the folder's camera
decodes it), a folder of them, or a BOP split or scene folder (``XXXXXX/scene_camera.json`` with ``depth/``):
its ``cam_K`` and ``depth_scale`` are read, its ground truth never. Every problem is one ``ValueError``
naming the file: frames of different sizes or cameras, a camera file whose image size or intrinsics are not
the frames', a frame without depth or with none between the camera file's clip planes.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opnet.datasets.depth_inputs import GivenCamera, list_inputs, load_depth_image, read_npy_image
from opnet.datasets.png import read_png
from opnet.fileio.files import read_json
from opnet.geometry.camera import Camera

#: a frame's intrinsics agree with the camera file's within this share (BOP files round to 1e-6 or so)
INTRINSICS_RTOL = 1e-4
#: the share of a frame's valid depth that must lie between the camera file's clip planes
MIN_SHARE_IN_CLIP = 0.05


@dataclass(frozen=True)
class Frame:
    """One depth frame: its file, (H, W) float32 z-depth in metres (NaN = none) and the intrinsics the
    frame's own files give (fx, fy, cx, cy), if any."""

    path: Path
    depth: np.ndarray
    intrinsics: tuple[float, float, float, float] | None = None

    @property
    def name(self) -> str:
        return str(self.path)


def _bop_scene_folders(path: Path) -> list[Path]:
    """The BOP scene folders of ``path`` (a split, or one scene folder); none for other folders."""
    if not path.is_dir():
        return []
    if (path / "scene_camera.json").is_file() and (path / "depth").is_dir():
        return [path]
    return sorted(p for p in path.iterdir() if re.fullmatch(r"\d{6}", p.name) and (p / "scene_camera.json").is_file())


def _bop_frames(scenes: list[Path]) -> list[Frame]:
    frames = []
    for scene in scenes:
        cameras = read_json(scene / "scene_camera.json")
        if not isinstance(cameras, dict) or not cameras:
            raise ValueError(f"{scene / 'scene_camera.json'}: expected an object of image id -> camera entries")
        for key in sorted(cameras, key=lambda k: int(k) if str(k).isdigit() else -1):
            entry, where = cameras[key], f"{scene / 'scene_camera.json'}: image {key}"
            if not str(key).isdigit() or not isinstance(entry, dict):
                raise ValueError(f"{where}: expected a whole-number image id with an object of cam_K and depth_scale")
            try:
                K = [float(x) for x in entry["cam_K"]]
                scale = float(entry["depth_scale"])
            except (KeyError, TypeError, ValueError):
                raise ValueError(f"{where}: needs cam_K (9 numbers) and depth_scale (millimetres per unit)") from None
            if len(K) != 9 or not all(map(math.isfinite, K)) or not (math.isfinite(scale) and scale > 0):
                raise ValueError(f"{where}: cam_K must be 9 finite numbers and depth_scale a positive number")
            path = scene / "depth" / f"{int(key):06d}.png"
            code = read_png(path, np.uint16)
            depth = code.astype(np.float32) * np.float32(scale / 1000.0)
            depth[code == 0] = np.nan
            frames.append(Frame(path, depth, (K[0], K[4], K[2], K[5])))
    return frames


def _file_frame(path: Path, depth_scale: float | None) -> Frame:
    if path.suffix.lower() == ".npy":
        depth = read_npy_image(path)
        if np.issubdtype(depth.dtype, np.integer):
            if depth_scale is None:
                raise ValueError(f"{path}: integer depth needs --depth-scale (metres per unit, 0.001 for millimetres)")
            depth = depth.astype(np.float64) * depth_scale
        depth = depth.astype(np.float32)
        if not np.isfinite(depth[~np.isnan(depth)]).all():
            raise ValueError(f"{path}: depth holds infinite values")
        depth[depth <= 0] = np.nan
        return Frame(path, depth)
    if path.suffix.lower() != ".png":
        raise ValueError(f"{path}: unsupported frame {path.suffix!r}; expected a 16-bit .png, a .npy or a BOP split")
    if any((parent / name).is_file() for parent in list(path.parents)[:4]
           for name in ("parameter.json", "camera_params.txt")):  # fmt: skip
        image = load_depth_image(path, GivenCamera({}, {}))  # a dataset's PNG: its own camera decodes it
        c = image.camera
        return Frame(path, image.depth, (c.fx, c.fy, c.cx, c.cy))
    if depth_scale is None:
        raise ValueError(f"{path}: a 16-bit depth PNG needs --depth-scale (metres per unit: 0.001 for millimetres)")
    code = read_png(path, np.uint16)
    depth = code.astype(np.float32) * np.float32(depth_scale)
    depth[code == 0] = np.nan
    return Frame(path, depth)


def read_frames(path: Path, camera: Camera, camera_file: Path, depth_scale: float | None = None) -> list[Frame]:
    """The frames of ``path`` (module docstring), checked against ``camera`` (read from ``camera_file``).

    Raises:
        ValueError, FileNotFoundError: one line naming the file and what is wrong.
    """
    path = Path(path)
    if depth_scale is not None and not (math.isfinite(depth_scale) and 0 < depth_scale <= 1):
        raise ValueError(f"--depth-scale {depth_scale:g}: expected metres per unit in (0, 1] (0.001 for millimetres)")
    scenes = _bop_scene_folders(path)
    frames = _bop_frames(scenes) if scenes else [_file_frame(p, depth_scale) for p, _ in list_inputs(path)]
    first = frames[0]
    for frame in frames:
        h, w = frame.depth.shape
        if frame.depth.shape != first.depth.shape:
            raise ValueError(f"{frame.name}: the frame is {w} x {h} pixels, {first.name} is {first.depth.shape[1]} x "
                             f"{first.depth.shape[0]}: the frames of one camera have one size")
        if frame.intrinsics is not None and first.intrinsics is not None and not np.allclose(
                frame.intrinsics, first.intrinsics, rtol=INTRINSICS_RTOL):
            raise ValueError(f"{frame.name}: its camera (fx, fy, cx, cy) = {_fmt(frame.intrinsics)} is not that of "
                             f"{first.name}, {_fmt(first.intrinsics)}: give frames of one camera")
        if (w, h) != (camera.width, camera.height):
            raise ValueError(f"{frame.name}: the frame is {w} x {h} pixels, the camera file {camera_file} says "
                             f"{camera.width} x {camera.height}: not this camera's frame (or a crop or resize of it)")
        own = (camera.fx, camera.fy, camera.cx, camera.cy)
        if frame.intrinsics is not None and not np.allclose(frame.intrinsics, own, rtol=INTRINSICS_RTOL):
            raise ValueError(f"{frame.name}: its camera (fx, fy, cx, cy) = {_fmt(frame.intrinsics)} is not the camera "
                             f"file's {camera_file}, {_fmt(own)}")
        valid = frame.depth[np.isfinite(frame.depth)]
        if valid.size == 0:
            raise ValueError(f"{frame.name}: no depth (every pixel is 0 or missing)")
        inside = float(np.count_nonzero((valid >= camera.clip_start) & (valid <= camera.clip_end))) / valid.size
        if inside < MIN_SHARE_IN_CLIP:
            raise ValueError(f"{frame.name}: {100 * inside:.2g} % of its depth (median {float(np.median(valid)):.4g} m) "
                             f"lies between the clip planes [{camera.clip_start:g}, {camera.clip_end:g}] m of the camera "
                             f"file {camera_file}: depth in other units (--depth-scale), or another camera's file")
    return frames


def _fmt(values: tuple[float, ...]) -> str:
    return "(" + ", ".join(f"{v:g}" for v in values) + ")"


def frames_summary(frames: list[Frame]) -> str:
    """One line: how many frames, their size and valid share."""
    h, w = frames[0].depth.shape
    share = np.mean([np.isfinite(f.depth).mean() for f in frames])
    return f"{len(frames)} frame(s) of {w} x {h} pixels, {100 * share:.0f} % with depth"


__all__ = ["Frame", "frames_summary", "read_frames"]
