"""Region of interest: the part of the depth image the network sees (issue 26).

Real cells often show the bin in a fifth of the image; framed whole into 128 × 128 input pixels, a
part becomes a few pixels wide. ``data.roi`` crops every image before the framing (``data.fit``),
with the intrinsics shifted (``cx - x0``, ``cy - y0``) and the image size changed, so poses stay in
the same camera frame and nothing else changes. Values:

- ``null``: the whole image (the default);
- ``[x0, y0, x1, y1]``: a pixel box of the full image (``x1``, ``y1`` exclusive);
- ``auto``: per image, the bounding box of the pixels whose depth lies in the working volume
  (between the clip planes), enlarged by 2 % of the image side on each side; an image without
  such depth keeps the whole image.

The checkpoint keeps it (a data key), ``predict.py`` and the ONNX export apply it as ``data.fit``.
Training records are cropped with their segmentation, and the ground-truth visibility of a part is
scaled by the share of its visible pixels inside the box (exact: the renderer's visibility is
visible pixels over unoccluded pixels, and the box only removes visible pixels).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from opnet.geometry.camera import Camera

AUTO = "auto"
AUTO_MARGIN = 0.02  # of the image side, on each side of the automatic box

Box = tuple[int, int, int, int]


def parse_roi(value: Any, where: str = "data.roi") -> Box | str | None:
    """A config value -> None, ``"auto"`` or an ``(x0, y0, x1, y1)`` box; ValueError (one line,
    naming ``where``) for anything else."""
    if value is None or value == "null":
        return None
    if isinstance(value, str):
        if value == AUTO:
            return AUTO
        parts = value.replace("[", "").replace("]", "").split(",")
        if len(parts) == 4:
            try:
                return parse_roi([int(p) for p in parts], where)
            except ValueError:
                pass
        raise ValueError(f"{where}={value!r}: expected null, auto or [x0, y0, x1, y1] pixels")
    if not isinstance(value, Sequence) or len(value) != 4:
        raise ValueError(f"{where}={value!r}: expected null, auto or [x0, y0, x1, y1] pixels")
    if any(isinstance(v, bool) or not isinstance(v, (int, np.integer)) for v in value):
        raise ValueError(f"{where}={list(value)!r}: the box needs whole pixel numbers")
    x0, y0, x1, y1 = (int(v) for v in value)
    if x0 < 0 or y0 < 0 or x1 <= x0 or y1 <= y0:
        raise ValueError(f"{where}={[x0, y0, x1, y1]}: expected 0 <= x0 < x1 and 0 <= y0 < y1 (an empty box)")
    return (x0, y0, x1, y1)


def resolve_box(roi: Box | str | None, depth: np.ndarray | None, camera: Camera, where: str = "data.roi") -> Box:
    """The box of one image: the given box checked against the image, the automatic one found,
    the whole image for None."""
    W, H = camera.width, camera.height
    if roi is None:
        return (0, 0, W, H)
    if roi == AUTO:
        if depth is None:
            raise ValueError(f"{where}=auto needs the depth image")
        ok = np.isfinite(depth) & (depth >= camera.clip_start) & (depth <= camera.clip_end)
        if not ok.any():
            return (0, 0, W, H)
        rows, cols = np.flatnonzero(ok.any(1)), np.flatnonzero(ok.any(0))
        m = int(round(AUTO_MARGIN * max(W, H)))
        return (max(int(cols[0]) - m, 0), max(int(rows[0]) - m, 0), min(int(cols[-1]) + 1 + m, W),
                min(int(rows[-1]) + 1 + m, H))  # fmt: skip
    x0, y0, x1, y1 = roi  # type: ignore[misc]
    if x1 > W or y1 > H:
        raise ValueError(f"{where}={[x0, y0, x1, y1]}: outside the {W} x {H} image")
    return (x0, y0, x1, y1)


def crop_camera(camera: Camera, box: Box) -> Camera:
    """The camera of the pixels of ``box``: the same rays, the principal point shifted."""
    x0, y0, x1, y1 = box
    return dataclasses.replace(camera, cx=camera.cx - x0, cy=camera.cy - y0, width=x1 - x0, height=y1 - y0)


def crop_image(depth: np.ndarray, camera: Camera, roi: Box | str | None,
               where: str = "data.roi") -> tuple[np.ndarray, Camera]:  # fmt: skip
    """A depth image and its camera cropped to the region of interest."""
    box = resolve_box(roi, depth, camera, where)
    if box == (0, 0, camera.width, camera.height):
        return depth, camera
    x0, y0, x1, y1 = box
    return depth[y0:y1, x0:x1], crop_camera(camera, box)


def crop_record(record: Any, roi: Box | str | None) -> Any:
    """A :class:`opnet.datasets.record.SceneRecord` cropped to the region of interest (its depth,
    segmentation and camera; visibilities scaled by the share of each part's pixels inside)."""
    box = resolve_box(roi, record.depth, record.camera)
    if box == (0, 0, record.camera.width, record.camera.height):
        return record
    x0, y0, x1, y1 = box
    visibility, seg = record.visibility, record.segmentation
    if seg is not None:
        ids = np.asarray(record.instance_id)
        inside = seg[y0:y1, x0:x1]
        span = int(max(seg.max(initial=0), ids.max(initial=0))) + 1
        total = np.bincount(seg.ravel().clip(0), minlength=span)[ids]
        kept = np.bincount(inside.ravel().clip(0), minlength=span)[ids]
        share = np.where(total > 0, kept / np.maximum(total, 1), 0.0)
        visibility = np.asarray(record.visibility, np.float64) * share
        seg = inside
    return dataclasses.replace(record, depth=record.depth[y0:y1, x0:x1], camera=crop_camera(record.camera, box),
                               segmentation=seg, visibility=visibility)


def roi_tag(roi: Box | str | None) -> str:
    """A file-name tag of the region of interest ("" for none): the cache of cropped scenes
    lives apart from the uncropped one."""
    if roi is None:
        return ""
    return "_roiauto" if roi == AUTO else "_roi" + "-".join(str(v) for v in roi)  # type: ignore[union-attr]


class ROIScenes:
    """A dataset whose records come cropped to the region of interest; everything else (scene
    keys, names, lengths) is the dataset's."""

    def __init__(self, source: Any, roi: Box | str) -> None:
        self.source, self.roi = source, roi
        camera = getattr(source, "camera", None)
        # one camera for every scene: the cropped one (an automatic box differs per image)
        self.camera = crop_camera(camera, resolve_box(roi, None, camera)) if isinstance(camera, Camera) and roi != AUTO else None

    def __len__(self) -> int:
        return len(self.source)

    def __getitem__(self, i: int) -> Any:
        return crop_record(self.source[i], self.roi)

    def __getattr__(self, name: str) -> Any:
        if name == "source":  # not set yet (unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.source, name)


__all__ = ["AUTO", "ROIScenes", "crop_camera", "crop_image", "crop_record", "parse_roi", "resolve_box", "roi_tag"]
