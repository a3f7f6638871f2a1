"""Pinhole camera in the internal OpenCV frame (x right, y down, z forward; docs/formats.md#frames).

Pixel ``(u, v)`` = (column, row), 0-based, pixel centres at integers:
``u = fx * x / z + cx``, ``v = fy * y / z + cy``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from opnet.settings_schema import MAX_CLIP_END_M, SETTINGS

if TYPE_CHECKING:
    import torch


#: no depth camera has more pixels a side; larger values are typos that would allocate gigabytes
MAX_IMAGE_SIDE = 16384
#: field of view (degrees, per image axis) of any real depth camera: a focal length outside it is a
#: typo (1e-9 px puts the parts 1e10 m away; 1e12 px makes overlays hang while drawing)
MIN_FOV_DEG = 0.5
MAX_FOV_DEG = 175.0


def parse_clip(value: object, option: str = "clip") -> tuple[float, float] | None:
    """``[near, far]`` working clip planes (metres) given by a user (a list, a tuple or an OmegaConf
    list), or None; one ``SettingError`` naming the option and what is wrong (the schema's
    ``trained_clip``, :mod:`opnet.settings_schema`)."""
    return SETTINGS["trained_clip"].check(value, option)


#: ``clip`` values of predict.py and the ONNX runtime that are no planes: the model's training
#: planes (``trained_clip`` of its :class:`~opnet.run_settings.InputSettings`), or the input camera's own
CLIP_SOURCES = ("model", "camera")


def working_clip(value: object, trained: tuple[float, float] | None, option: str = "clip") -> tuple[float, float] | None:
    """The clip planes an input's depth is normalized with, in place of its camera's (None: the
    camera's own). ``value``: ``"model"`` or None, the model's training planes ``trained`` (None when
    it records none); ``"camera"``, the camera's; ``[near, far]``, those."""
    if value is None or value == CLIP_SOURCES[0]:
        return trained
    if value == CLIP_SOURCES[1]:
        return None
    if isinstance(value, str):
        raise ValueError(f"{option}={value!r}: expected {', '.join(CLIP_SOURCES)} or [near, far] in metres")
    return parse_clip(value, option)


def describe_clip(clip: tuple[float, float] | None, trained: tuple[float, float] | None) -> str:
    """One console line: the planes the inputs are normalized with and where they come from."""
    if clip is None:
        return "clip planes: each camera's own" + ("" if trained is not None else " (the model records no training planes)")
    source = "the model's training planes" if clip == trained else "given"
    return f"clip planes: [{clip[0]:g}, {clip[1]:g}] m ({source})"


def with_clip(camera: Camera, clip: tuple[float, float] | None) -> Camera:
    """``camera`` with the clip planes ``clip`` (None: unchanged)."""
    return camera if clip is None else replace(camera, clip_start=clip[0], clip_end=clip[1])


#: a camera as one row of numbers, in this order: the ONNX graph's camera input, cached scenes, the settings a
#: checkpoint records, camera YAML files (:meth:`Camera.row`, :meth:`Camera.from_row`)
CAMERA_FIELDS = ("fx", "fy", "cx", "cy", "width", "height", "clip_start", "clip_end")


@dataclass(frozen=True)
class Camera:
    """Intrinsics, image size and clip planes of a depth camera.

    Attributes:
        fx, fy: focal lengths in pixels.
        cx, cy: principal point in pixels (0-based, pixel-centre convention).
        width, height: image size in pixels.
        clip_start, clip_end: near and far clip planes in metres (depth normalization range).
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    clip_start: float
    clip_end: float

    def __post_init__(self) -> None:
        for key in CAMERA_FIELDS:
            if isinstance(getattr(self, key), bool):  # True would read as 1
                raise ValueError(f"camera {key} must be a number, got the boolean {getattr(self, key)}")
        values = (self.fx, self.fy, self.cx, self.cy, self.clip_start, self.clip_end)
        if not all(math.isfinite(float(v)) for v in values):
            raise ValueError(f"Camera parameters must be finite, got {self}")
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"Camera focal lengths must be positive, got fx={self.fx}, fy={self.fy}")
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f"Camera size must be positive, got {self.width}x{self.height}")
        if not 0 < self.clip_start < self.clip_end:
            raise ValueError(
                f"Camera clip planes must satisfy 0 < clip_start < clip_end, "
                f"got clip_start={self.clip_start}, clip_end={self.clip_end}"
            )

    def row(self) -> list[float]:
        """The camera as :data:`CAMERA_FIELDS` in order (the image size as floats too)."""
        return [float(getattr(self, key)) for key in CAMERA_FIELDS]

    @classmethod
    def from_row(cls, row: object) -> Camera:
        """The camera of a row of :data:`CAMERA_FIELDS` (:meth:`row`); the image size read as whole pixels.

        Raises:
            ValueError: not 8 numbers, a size that is not a whole number, or an invalid camera.
        """
        values = [float(x) for x in row]  # type: ignore[attr-defined]
        if len(values) != len(CAMERA_FIELDS):
            raise ValueError(f"a camera row has {len(CAMERA_FIELDS)} numbers ({', '.join(CAMERA_FIELDS)}), "
                             f"got {len(values)}")
        if not (values[4].is_integer() and values[5].is_integer()):
            raise ValueError(f"camera width and height must be whole pixels, got {values[4]:g} x {values[5]:g}")
        return cls(*values[:4], int(values[4]), int(values[5]), *values[6:])

    def check_plausible(self, source: str = "camera") -> Camera:
        """``self`` if it describes a real depth camera, checked where a camera enters the program
        (readers, configs): a field of view in [:data:`MIN_FOV_DEG`, :data:`MAX_FOV_DEG`] along
        each axis, at most :data:`MAX_IMAGE_SIDE` pixels a side, the principal point within
        one image size of the image, clip planes in metres (``clip_end`` <= :data:`MAX_CLIP_END_M`).
        Beyond these, values are typos that would allocate gigabytes (a canvas around a far-away
        principal point) or silently normalize depth wrongly.

        Raises:
            ValueError: naming ``source`` (a file or config key) and the value.
        """
        for key, f, size in (("fx", self.fx, self.width), ("fy", self.fy, self.height)):
            fov = math.degrees(2.0 * math.atan(size / (2.0 * f)))
            if not MIN_FOV_DEG <= fov <= MAX_FOV_DEG:
                raise ValueError(f"{source}: focal length {key} = {f:g} px is implausible: a field of view of {fov:.3g} degrees "
                                 f"over {size} pixels; a depth camera sees {MIN_FOV_DEG:g} to {MAX_FOV_DEG:g} degrees "
                                 "(focal lengths are in pixels)")
        if max(self.width, self.height) > MAX_IMAGE_SIDE:
            raise ValueError(f"{source}: image size {self.width}x{self.height} is implausible "
                             f"(more than {MAX_IMAGE_SIDE} pixels a side)")
        if not (-self.width <= self.cx <= 2 * self.width and -self.height <= self.cy <= 2 * self.height):
            raise ValueError(f"{source}: principal point ({self.cx:g}, {self.cy:g}) lies implausibly far outside "
                             f"the {self.width}x{self.height} image (expected within one image size of it)")
        if self.clip_end > MAX_CLIP_END_M:
            raise ValueError(f"{source}: clip_end = {self.clip_end:g} m is implausible for a depth camera "
                             f"(clip planes are in metres; millimetres? divide by 1000)")
        return self

    @classmethod
    def from_fov(
        cls, fov_deg: float, width: int, height: int, clip_start: float, clip_end: float
    ) -> Camera:
        """Square-pixel camera whose horizontal field of view is ``fov_deg`` (degrees)."""
        f = width / (2.0 * math.tan(math.radians(fov_deg) / 2.0))
        return cls(f, f, (width - 1) / 2.0, (height - 1) / 2.0, width, height, clip_start, clip_end)

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 intrinsic matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def project(self, points_cam: torch.Tensor | np.ndarray) -> torch.Tensor | np.ndarray:
        """Project camera-frame points (..., 3), metres, to pixels (..., 2) as (u, v)."""
        lib = _lib(points_cam)
        x, y, z = points_cam[..., 0], points_cam[..., 1], points_cam[..., 2]
        return lib.stack((self.fx * x / z + self.cx, self.fy * y / z + self.cy), -1)

    def backproject(self, u, v, z):  # noqa: ANN001, ANN201 - arrays or tensors, same shapes
        """Pixel coordinates and depth (metres) of the same shape to camera-frame points (..., 3)."""
        lib = _lib(z)
        return lib.stack(((u - self.cx) * z / self.fx, (v - self.cy) * z / self.fy, z), -1)

    def depth_to_points(self, depth: np.ndarray) -> np.ndarray:
        """(H, W) z-depth in metres (NaN = missing) to (H, W, 3) camera-frame points."""
        if depth.shape != (self.height, self.width):
            raise ValueError(f"depth has shape {depth.shape}, camera expects {(self.height, self.width)}")
        v, u = np.mgrid[0 : self.height, 0 : self.width].astype(np.float64)
        return self.backproject(u, v, depth.astype(np.float64))

    def normalize_depth(self, z):  # noqa: ANN001, ANN201
        """Depth in metres to ``(z - clip_start) / (clip_end - clip_start)`` (docs/method.md#network-input)."""
        return (z - self.clip_start) / (self.clip_end - self.clip_start)

    def denormalize_depth(self, d):  # noqa: ANN001, ANN201
        """Inverse of :meth:`normalize_depth`."""
        return self.clip_start + d * (self.clip_end - self.clip_start)

    def resized(self, width: int, height: int) -> Camera:
        """The same camera seen at another resolution (pixel-centre aligned scaling)."""
        sx, sy = width / self.width, height / self.height
        return replace(
            self,
            fx=self.fx * sx,
            fy=self.fy * sy,
            cx=(self.cx + 0.5) * sx - 0.5,
            cy=(self.cy + 0.5) * sy - 0.5,
            width=width,
            height=height,
        )

    def scaled(self, scale: float) -> Camera:
        """The same camera at ``scale`` x its pixels: ``round(width * scale)`` x ``round(height * scale)``,
        the same field of view and rays (:meth:`resized`), the clip planes unchanged."""
        width, height = round(self.width * scale), round(self.height * scale)
        if width < 1 or height < 1:
            raise ValueError(f"{self.width}x{self.height} pixels at {scale:g} x leave none")
        return self.resized(width, height)

    def cropped(self, x0: int, y0: int, width: int, height: int) -> Camera:
        """The camera of the sub-image ``[y0:y0+height, x0:x0+width]`` (x0, y0 may be negative: padding)."""
        return replace(self, cx=self.cx - x0, cy=self.cy - y0, width=width, height=height)


def _lib(x: object) -> object:
    """torch for a tensor, else numpy (torch is imported only when a tensor is given: the camera
    module loads without PyTorch)."""
    if type(x).__module__.startswith("torch"):
        import torch

        return torch
    return np
