"""``parameter.json`` of a Fraunhofer IPA dataset folder: the camera and the drop settings.

The depth image is a crop of a square ``resolution_big`` canvas rendered with the horizontal and
vertical field of view ``perspectiveAngle`` (docs/formats.md#fraunhofer-ipa-layout). Pixel ``(u, v)`` of
the image is pixel ``(u + pixelOffset_X, v + pixelOffset_Y)`` of the canvas.

Half-pixel decision: the canvas' principal point is ``c = resolution_big / 2 - 0.5``, the centre of
the canvas in the pixel-centre convention (pixel centres at integers), which is what the original
IPA back-projection script computes (PPR-Net's ``c = resolution_big / 2`` is half a pixel off).
The reader (:meth:`IPAParameters.camera`) and the writer (:meth:`IPAParameters.from_camera`) both
use it.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from opnet.fileio.atomic import write_text_if_changed
from opnet.fileio.files import read_json
from opnet.geometry.camera import Camera

PARAMETER_FILE = "parameter.json"
#: opnet's optional key: exact [fx, fy, cx, cy] of a camera the IPA fields cannot express
INTRINSICS_KEY = "opnet_intrinsics"

#: Python field -> (parameter.json key, kind); kinds: "float", "int", "vec3", "quat"
_FIELDS: dict[str, tuple[str, str]] = {
    "perspective_angle": ("perspectiveAngle", "float"),
    "clip_start": ("clip_start", "float"),
    "clip_end": ("clip_end", "float"),
    "resolution_x": ("resolutionX", "int"),
    "resolution_y": ("resolutionY", "int"),
    "resolution_big": ("resolution_big", "int"),
    "pixel_offset_x": ("pixelOffset_X_KoSyTopLeft", "int"),
    "pixel_offset_y": ("pixelOffset_Y_KoSyTopLeft", "int"),
    "number_cycles": ("number_cycles", "int"),
    "shape_drop_limit": ("shapeDropLimit", "int"),
    "location": ("location", "vec3"),
    "rotation": ("rotation", "quat"),
}
_EXPECTED = {
    "float": "a number",
    "int": "an integer",
    "vec3": "a list of 3 numbers",
    "quat": "a list of 4 numbers (quaternion w, x, y, z)",
}


@dataclass(frozen=True)
class IPAParameters:
    """The content of ``parameter.json`` (JSON keys in brackets).

    Attributes:
        perspective_angle: field of view of the square canvas, degrees (``perspectiveAngle``).
        clip_start, clip_end: clip planes, metres; the depth code spans them.
        resolution_x, resolution_y: image width and height, pixels (``resolutionX``,
            ``resolutionY``).
        resolution_big: side of the square canvas the image is cropped from, pixels.
        pixel_offset_x, pixel_offset_y: canvas position of the image's top-left pixel
            (``pixelOffset_X_KoSyTopLeft``, ``pixelOffset_Y_KoSyTopLeft``).
        number_cycles: number of drop cycles. shape_drop_limit: objects dropped per cycle
            (``shapeDropLimit``).
        location: camera position in the world, metres.
        rotation: camera orientation in the world, unit quaternion (w, x, y, z).
        intrinsics: (fx, fy, cx, cy) of a camera the IPA fields cannot express exactly (non-square
            pixels, a principal point off the half-pixel grid): opnet's optional
            ``opnet_intrinsics`` key, which :meth:`camera` prefers; the IPA fields then hold the
            nearest IPA camera, for tools that only know them. None = the IPA fields are exact.
    """

    perspective_angle: float
    clip_start: float
    clip_end: float
    resolution_x: int
    resolution_y: int
    resolution_big: int
    pixel_offset_x: int
    pixel_offset_y: int
    number_cycles: int
    shape_drop_limit: int
    location: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    intrinsics: tuple[float, float, float, float] | None = None

    def __post_init__(self) -> None:
        if not 0.0 < self.perspective_angle < 180.0:
            raise ValueError(
                f"perspectiveAngle must be in (0, 180) degrees, got {self.perspective_angle}"
            )
        if not 0.0 < self.clip_start < self.clip_end:
            raise ValueError(
                f"clip planes must satisfy 0 < clip_start < clip_end, "
                f"got {self.clip_start}, {self.clip_end}"
            )
        if min(self.resolution_x, self.resolution_y, self.resolution_big) <= 0:
            raise ValueError(
                f"resolutions must be positive, got resolutionX={self.resolution_x}, "
                f"resolutionY={self.resolution_y}, resolution_big={self.resolution_big}"
            )

    @property
    def focal_length(self) -> float:
        """``resolution_big / (2 tan(perspectiveAngle / 2))``, pixels (square pixels)."""
        return self.resolution_big / (2.0 * math.tan(math.radians(self.perspective_angle) / 2.0))

    def camera(self) -> Camera:
        """The depth image's camera in the internal OpenCV frame (x right, y down, z forward).

        IPA's own frame has x and y negated (``x_ipa = -(u_big - c) z / f``); flipping both back
        gives ``x = (u - cx) z / f`` with ``cx = c - pixel_offset_x``,
        ``c = resolution_big / 2 - 0.5``.
        """
        if self.intrinsics is not None:
            fx, fy, cx, cy = self.intrinsics
            return Camera(fx, fy, cx, cy, self.resolution_x, self.resolution_y, self.clip_start, self.clip_end)
        c = self.resolution_big / 2.0 - 0.5
        f = self.focal_length
        return Camera(
            fx=f,
            fy=f,
            cx=c - self.pixel_offset_x,
            cy=c - self.pixel_offset_y,
            width=self.resolution_x,
            height=self.resolution_y,
            clip_start=self.clip_start,
            clip_end=self.clip_end,
        )

    @classmethod
    def from_camera(
        cls,
        camera: Camera,
        number_cycles: int,
        shape_drop_limit: int,
        location: tuple[float, float, float] = (0.0, 0.0, 0.0),
        rotation: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0),
        resolution_big: int | None = None,
    ) -> IPAParameters:
        """Parameters whose :meth:`camera` is ``camera`` (focal length up to float rounding).

        Args:
            camera: square pixels (fx == fy); 2 cx and 2 cy integers of the same parity, so that the
                image is an integer-offset crop of a square canvas centred on the optical axis.
            number_cycles, shape_drop_limit: the drop settings to record.
            location, rotation: camera position (metres) and orientation (w, x, y, z) in the world.
            resolution_big: the canvas side; default: the smallest canvas that contains the image.
        Raises:
            ValueError: non-square pixels, or a principal point that no canvas crop can represent.
        """
        if not math.isclose(camera.fx, camera.fy, rel_tol=1e-9):
            raise ValueError(
                f"IPA parameters need square pixels, got fx={camera.fx}, fy={camera.fy}"
            )
        kx, ky = _twice_plus_one(camera.cx, "cx"), _twice_plus_one(camera.cy, "cy")
        if (kx - ky) % 2:
            raise ValueError(
                f"principal point ({camera.cx}, {camera.cy}) cannot be a canvas centre: cx and cy "
                f"must both be integers or both be half-integers"
            )
        if resolution_big is None:
            need = max(kx, ky, 2 * camera.width - kx, 2 * camera.height - ky, 1)
            resolution_big = need + (need - kx) % 2
        off_x, off_y = (resolution_big - kx) / 2, (resolution_big - ky) / 2
        if (
            off_x != int(off_x)
            or off_y != int(off_y)
            or min(off_x, off_y) < 0
            or off_x + camera.width > resolution_big
            or off_y + camera.height > resolution_big
        ):
            raise ValueError(
                f"a {camera.width}x{camera.height} image with principal point "
                f"({camera.cx}, {camera.cy}) "
                f"is not an integer-offset crop of a {resolution_big}-pixel canvas"
            )
        angle = 2.0 * math.degrees(math.atan(resolution_big / (2.0 * camera.fx)))
        return cls(
            perspective_angle=angle,
            clip_start=float(camera.clip_start),
            clip_end=float(camera.clip_end),
            resolution_x=camera.width,
            resolution_y=camera.height,
            resolution_big=int(resolution_big),
            pixel_offset_x=int(off_x),
            pixel_offset_y=int(off_y),
            number_cycles=int(number_cycles),
            shape_drop_limit=int(shape_drop_limit),
            location=tuple(float(x) for x in location),  # type: ignore[arg-type]
            rotation=tuple(float(x) for x in rotation),  # type: ignore[arg-type]
        )

    @classmethod
    def for_any_camera(cls, camera: Camera, number_cycles: int, shape_drop_limit: int,
                       location: tuple[float, float, float] = (0.0, 0.0, 0.0),
                       rotation: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)) -> IPAParameters:
        """Parameters whose :meth:`camera` is ``camera`` exactly: :meth:`from_camera` when the IPA
        fields can express it, else the nearest IPA camera (mean focal length, principal point on
        the half-pixel grid) plus ``intrinsics`` with the exact values."""
        try:
            return cls.from_camera(camera, number_cycles, shape_drop_limit, location, rotation)
        except ValueError:
            pass
        kx, ky = round(2 * camera.cx + 1), round(2 * camera.cy + 1)
        ky += (kx - ky) % 2  # same parity: both integer or both half-integer
        f = 0.5 * (camera.fx + camera.fy)
        near = Camera(f, f, (kx - 1) / 2, (ky - 1) / 2, camera.width, camera.height, camera.clip_start, camera.clip_end)
        params = cls.from_camera(near, number_cycles, shape_drop_limit, location, rotation)
        return dataclasses.replace(params, intrinsics=(float(camera.fx), float(camera.fy), float(camera.cx), float(camera.cy)))

    def to_json_dict(self) -> dict[str, Any]:
        """The ``parameter.json`` content (IPA key names, plus ``opnet_intrinsics`` when set)."""
        out: dict[str, Any] = {}
        for name, (key, kind) in _FIELDS.items():
            value = getattr(self, name)
            out[key] = list(value) if kind in ("vec3", "quat") else value
        if self.intrinsics is not None:
            out[INTRINSICS_KEY] = list(self.intrinsics)
        return out


def _twice_plus_one(c: float, name: str) -> int:
    """``2 c + 1`` as an integer (the canvas side parity a principal point needs)."""
    k = 2.0 * c + 1.0
    if abs(k - round(k)) > 1e-6:
        raise ValueError(
            f"principal point {name}={c} must be an integer or a half-integer for an IPA canvas"
        )
    return int(round(k))


def read_parameters(path: str | Path) -> IPAParameters:
    """Read ``parameter.json``.

    Args:
        path: the file, or the dataset folder holding it.
    Raises:
        FileNotFoundError: no ``parameter.json``.
        ValueError: malformed JSON, or a missing or ill-typed field (the message names both).
    """
    path = Path(path)
    if path.is_dir():
        path = path / PARAMETER_FILE
    data = read_json(path, "an object of camera parameters")
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object, got a JSON {type(data).__name__}")
    values = {name: _field(data, key, kind, path) for name, (key, kind) in _FIELDS.items()}
    if INTRINSICS_KEY in data:
        k = data[INTRINSICS_KEY]
        if not (isinstance(k, list) and len(k) == 4 and all(_is_number(x) for x in k) and k[0] > 0 and k[1] > 0):
            raise ValueError(f"{path}: field {INTRINSICS_KEY!r} is {k!r}, expected [fx, fy, cx, cy] (pixels, fx and fy > 0)")
        values["intrinsics"] = tuple(float(x) for x in k)
    try:
        params = IPAParameters(**values)
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    params.camera().check_plausible(str(path))  # offsets, sizes and clip planes of a real camera
    return params


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _field(data: dict[str, Any], key: str, kind: str, path: Path) -> Any:
    if key not in data:
        raise ValueError(f"{path}: missing field {key!r} (expected {_EXPECTED[kind]})")
    value = data[key]
    size = {"vec3": 3, "quat": 4}.get(kind)
    if kind == "float" and _is_number(value):
        return float(value)
    if kind == "int" and _is_number(value) and float(value).is_integer():
        return int(value)
    if (
        size
        and isinstance(value, list)
        and len(value) == size
        and all(_is_number(x) for x in value)
    ):
        return tuple(float(x) for x in value)
    raise ValueError(f"{path}: field {key!r} is {value!r}, expected {_EXPECTED[kind]}")


def write_parameters(root: str | Path, params: IPAParameters) -> None:
    """Write ``<root>/parameter.json`` atomically (floats in repr precision: reading is exact);
    an identical file is left as it is."""
    text = json.dumps(params.to_json_dict(), indent=2) + "\n"
    write_text_if_changed(Path(root) / PARAMETER_FILE, text)  # no write when unchanged (read-only data)
