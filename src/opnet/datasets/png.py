"""PNG images of the datasets: strict reading, deterministic writing, and the uint16 depth code.

Both dataset layouts store depth the same way (docs/formats.md#fraunhofer-ipa-layout): a 16-bit PNG
whose value ``v`` in [0, 65534] means ``z = clip_start + v / 65535 * (clip_end - clip_start)``
metres, and 65535 means "no depth".
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from opnet.fileio.atomic import write_bytes_atomic
from opnet.fileio.files import read_bytes
from opnet.geometry.camera import MAX_IMAGE_SIDE

DEPTH_MISSING = 65535
#: fixed encoder settings, so the same image always gives the same bytes
_PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 3]
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def read_png(
    path: str | Path, dtype: type[np.generic], shape: tuple[int, int] | None = None
) -> np.ndarray:
    """Read a single-channel PNG exactly as stored (``cv2.IMREAD_UNCHANGED``).

    Args:
        path: the PNG file.
        dtype: the expected pixel type, ``np.uint8`` or ``np.uint16``.
        shape: the expected (height, width), or None to accept any.
    Returns:
        (H, W) array of ``dtype``.
    Raises:
        FileNotFoundError: no such file.
        ValueError: not a PNG, corrupt or truncated, wrong bit depth, channels or shape; the message
            names the file.
    """
    data = read_bytes(path)
    if not data.startswith(_PNG_SIGNATURE):
        raise ValueError(f"{path}: not a PNG file (bad signature)")
    if len(data) < 24 or data[12:16] != b"IHDR":
        raise ValueError(f"{path}: corrupt PNG (no IHDR header)")
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if not (1 <= width <= MAX_IMAGE_SIDE and 1 <= height <= MAX_IMAGE_SIDE):
        # decoding would allocate width x height pixels first (50000 x 50000 from a 5 MB file)
        raise ValueError(f"{path}: the PNG header says {width}x{height} pixels; expected 1 to {MAX_IMAGE_SIDE} a side")
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise ValueError(f"{path}: corrupt or truncated PNG (cannot be decoded)")
    if img.ndim != 2:
        raise ValueError(f"{path}: expected a single-channel PNG, got {img.shape[2]} channels")
    if img.dtype != dtype:
        bits = {np.dtype(np.uint8): "8-bit", np.dtype(np.uint16): "16-bit"}
        want, got = bits.get(np.dtype(dtype), str(dtype)), bits.get(img.dtype, str(img.dtype))
        raise ValueError(f"{path}: expected a {want} PNG, got a {got} one")
    if shape is not None and img.shape != tuple(shape):
        raise ValueError(
            f"{path}: image is {img.shape[1]}x{img.shape[0]} (WxH), expected {shape[1]}x{shape[0]}"
        )
    return img


def write_png(path: str | Path, image: np.ndarray) -> None:
    """Write a (H, W) uint8 or uint16 image as a PNG, atomically and byte-deterministically."""
    if image.ndim != 2 or image.dtype not in (np.uint8, np.uint16):
        raise ValueError(
            f"{path}: expected a (H, W) uint8 or uint16 image, got {image.dtype} {image.shape}"
        )
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image), _PNG_PARAMS)
    if not ok:
        raise ValueError(f"{path}: PNG encoding failed")
    write_bytes_atomic(path, buf.tobytes())


def encode_depth(depth: np.ndarray, clip_start: float, clip_end: float) -> np.ndarray:
    """Metres to the uint16 depth code.

    Args:
        depth: (H, W) float z-depth in metres, camera frame; NaN = missing.
        clip_start, clip_end: the clip planes, metres.
    Returns:
        (H, W) uint16: ``round(65535 * (z - clip_start) / (clip_end - clip_start))`` capped at
        65534; 65535 where the depth is NaN or outside ``[clip_start, clip_end]``.
    """
    z = np.asarray(depth, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        valid = (z >= clip_start) & (z <= clip_end)
        code = np.rint(65535.0 * (z - clip_start) / (clip_end - clip_start))
    out = np.full(z.shape, DEPTH_MISSING, dtype=np.uint16)
    out[valid] = np.minimum(code[valid], DEPTH_MISSING - 1).astype(np.uint16)
    return out


def decode_depth(code: np.ndarray, clip_start: float, clip_end: float) -> np.ndarray:
    """The uint16 depth code to metres: (H, W) uint16 -> (H, W) float32, NaN where 65535."""
    z = clip_start + code.astype(np.float64) / 65535.0 * (clip_end - clip_start)
    z[code == DEPTH_MISSING] = np.nan
    return z.astype(np.float32)
