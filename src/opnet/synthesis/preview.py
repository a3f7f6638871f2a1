"""Preview images of generated scenes: colour-mapped depth beside the colour-coded segmentation."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from opnet.datasets.record import SceneRecord
from opnet.fileio.atomic import write_bytes_atomic

_PNG_PARAMS = [cv2.IMWRITE_PNG_COMPRESSION, 3]  # fixed settings: same image, same bytes


def instance_palette(n: int) -> np.ndarray:
    """(n + 1, 3) uint8 BGR colours: 0 black, then well-separated hues (golden-ratio steps)."""
    hues = (np.arange(1, n + 1) * 0.618033988749895) % 1.0
    hsv = np.stack([hues * 179.0, np.full(n, 200.0), np.full(n, 255.0)], -1).astype(np.uint8)
    bgr = cv2.cvtColor(hsv[None], cv2.COLOR_HSV2BGR)[0]
    return np.concatenate([np.zeros((1, 3), np.uint8), bgr])


def preview_image(record: SceneRecord) -> np.ndarray:
    """(H, 2 W, 3) uint8 BGR: depth (near = bright, missing = black) | segmentation (0 = black)."""
    cam = record.camera
    d = np.nan_to_num(cam.normalize_depth(record.depth.astype(np.float64)), nan=1.0)
    gray = np.clip(255.0 * (1.0 - d), 0, 255).astype(np.uint8)
    depth_bgr = cv2.applyColorMap(gray, cv2.COLORMAP_VIRIDIS)
    depth_bgr[np.isnan(record.depth)] = 0
    seg = record.segmentation if record.segmentation is not None else np.zeros(record.depth.shape, np.int32)
    palette = instance_palette(int(max(seg.max(), 0)))
    return np.concatenate([depth_bgr, palette[seg]], axis=1)


def write_preview(path: str | Path, record: SceneRecord) -> None:
    """Write :func:`preview_image` of ``record`` as a PNG, atomically and byte-deterministically."""
    ok, buf = cv2.imencode(".png", preview_image(record), _PNG_PARAMS)
    if not ok:
        raise ValueError(f"{path}: PNG encoding failed")
    write_bytes_atomic(path, buf.tobytes())
