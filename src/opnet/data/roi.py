"""Region of interest: the part of the depth image the network sees.

Real cells often show the bin in a fifth of the image; framed whole into 128 × 128 input pixels, a
part becomes a few pixels wide. ``data.roi`` crops every image before the framing (``data.fit``),
with the intrinsics shifted (``cx - x0``, ``cy - y0``) and the image size changed, so poses stay in
the same camera frame and nothing else changes. Values:

- ``null``: the whole image (the default);
- ``[x0, y0, x1, y1]``: a pixel box of the full image (``x1``, ``y1`` exclusive; at least :data:`MIN_BOX_SIDE` a side);
- ``auto``: per image, the box of the bin found in the depth (:mod:`opnet.data.bin_finder`: the largest
  connected region of depth in the working volume, between the clip planes), 2 % of the image side to spare;
- ``auto:S``: per image, a square of ``S`` metres at the bin's depth centred on the bin found: a fixed
  metric size, so parts keep their size in network pixels wherever the bin stands (the policy for a cell
  whose bin moves: train with it on generated piles of moved bins, the checkpoint keeps ``S``).

A frame with no bin between the clip planes is a one-line error naming it.

The checkpoint keeps it (a data key), ``predict.py`` and the ONNX export apply it as ``data.fit``.
Training records are cropped with their segmentation, and the ground-truth visibility of a part is
scaled by the share of its visible pixels inside the box (exact: the renderer's visibility is
visible pixels over unoccluded pixels, and the box only removes visible pixels).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from opnet.geometry.camera import Camera
from opnet.settings_schema import AUTO, MAX_AUTO_SIDE, MIN_BOX_SIDE, Box, check_value


def is_auto(roi: Any) -> bool:
    """``roi`` is a bin finder (``auto`` or ``auto:S``), found anew in every image."""
    return isinstance(roi, str) and (roi == AUTO or roi.startswith(AUTO + ":"))


def auto_side(roi: str) -> float | None:
    """The metric side S of ``auto:S`` (None for ``auto``)."""
    return None if roi == AUTO else float(roi.split(":", 1)[1])


def parse_roi(value: Any, where: str = "data.roi") -> Box | str | None:
    """A config value -> None, ``"auto"``, ``"auto:S"`` (S in metres, written as ``%g``) or an
    ``(x0, y0, x1, y1)`` box; a one-line ``SettingError`` naming ``where`` for anything else (the
    schema's ``roi``, :mod:`opnet.settings_schema`)."""
    return check_value("roi", value, where)


def resolve_box(roi: Box | str | None, depth: np.ndarray | None, camera: Camera, where: str = "data.roi",
                frame: str | None = None) -> Box:  # fmt: skip
    """The box of one image: the given box checked against the image, the bin found (``auto``, ``auto:S``;
    a :class:`opnet.data.bin_finder.NoBinError` naming ``frame`` where there is none), the whole image for None."""
    W, H = camera.width, camera.height
    if roi is None:
        return (0, 0, W, H)
    if is_auto(roi):
        if depth is None:
            raise ValueError(f"{where}={roi} needs the depth image")
        from opnet.data.bin_finder import find_bin

        return find_bin(depth, camera, auto_side(roi), f"{where}={roi}", frame).box  # type: ignore[arg-type]
    x0, y0, x1, y1 = roi  # type: ignore[misc]
    if x1 > W or y1 > H:
        raise ValueError(f"{where}={[x0, y0, x1, y1]}: outside the {W} x {H} image")
    return (x0, y0, x1, y1)


def crop_camera(camera: Camera, box: Box) -> Camera:
    """The camera of the pixels of ``box``: the same rays, the principal point shifted."""
    x0, y0, x1, y1 = box
    return dataclasses.replace(camera, cx=camera.cx - x0, cy=camera.cy - y0, width=x1 - x0, height=y1 - y0)


def crop_image(depth: np.ndarray, camera: Camera, roi: Box | str | None, where: str = "data.roi",
               frame: str | None = None) -> tuple[np.ndarray, Camera]:  # fmt: skip
    """A depth image and its camera cropped to the region of interest (``frame`` names the image in errors)."""
    box = resolve_box(roi, depth, camera, where, frame)
    if box == (0, 0, camera.width, camera.height):
        return depth, camera
    x0, y0, x1, y1 = box
    return depth[y0:y1, x0:x1], crop_camera(camera, box)


def crop_record(record: Any, roi: Box | str | None) -> Any:
    """A :class:`opnet.datasets.record.SceneRecord` cropped to the region of interest (its depth,
    segmentation and camera; visibilities scaled by the share of each part's pixels inside)."""
    box = resolve_box(roi, record.depth, record.camera, frame=getattr(record, "name", None))
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


#: the bin finder's revision, in the tag of ``auto`` crops: a cache of crops an earlier finder made is not
#: reused (2: a perforated basket counts by its outline; 3: with auto:S, a region wider than S is no bin, and of
#: regions about as large the nearer is)
FINDER_REVISION = 3


def roi_tag(roi: Box | str | None) -> str:
    """A file-name tag of the region of interest ("" for none): the cache of cropped scenes
    lives apart from the uncropped one (and, for ``auto``, from crops of an earlier bin finder)."""
    if roi is None:
        return ""
    if is_auto(roi):
        return "_roi" + str(roi).replace(":", "") + f"_f{FINDER_REVISION}"
    return "_roi" + "-".join(str(v) for v in roi)  # type: ignore[union-attr]


class ROIScenes:
    """A dataset whose records come cropped to the region of interest; everything else (scene
    keys, names, lengths) is the dataset's."""

    def __init__(self, source: Any, roi: Box | str) -> None:
        self.source, self.roi = source, roi
        camera = getattr(source, "camera", None)
        # one camera for every scene: the cropped one (an automatic box differs per image)
        self.camera = crop_camera(camera, resolve_box(roi, None, camera)) if isinstance(camera, Camera) and not is_auto(roi) else None

    def __len__(self) -> int:
        return len(self.source)

    def __getitem__(self, i: int) -> Any:
        return crop_record(self.source[i], self.roi)

    def __getattr__(self, name: str) -> Any:
        if name == "source":  # not set yet (unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.source, name)


__all__ = ["AUTO", "FINDER_REVISION", "MAX_AUTO_SIDE", "MIN_BOX_SIDE", "ROIScenes", "auto_side", "crop_camera", "crop_image", "crop_record", "is_auto", "parse_roi", "resolve_box", "roi_tag"]
