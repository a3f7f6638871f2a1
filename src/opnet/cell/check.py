"""Sim versus real without ground truth: a cell's real frames against generated piles of its recipe, in what
both have.

- the depth inside the working volume (the share of pixels there, its 5th / 50th / 95th percentiles and the
  overlap of the two histograms, 1 cm bins);
- the share of missing depth in the bin (inside its inner outline, from floor to rim) and off it; on and off
  the parts where the generated segmentation tells (a real frame has no masks without ground truth);
- the bin found (:mod:`opnet.cell.bin_view`) in every frame, and where (the generator's world);
- the floor's depth residual of an empty generated bin against a real frame: the generator renders the
  cell's bin where the real one stood (its x, y and yaw as measured, no jitter) and the two depths are
  compared on the real frame's floor;
- each sensor preset's missing-depth shares and floor noise on the same generated piles against the real
  frames' (the presets applied to the ideal depth; the closest by the sum of the differences, shares in
  percentage points and floor noise in millimetres).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from opnet.cell import rig
from opnet.cell.bin_view import BinNotFound, BinView, find_bin
from opnet.geometry.camera import Camera
from opnet.synthesis.sensor import SensorModel

#: the histogram bins of the depth in the working volume, metres
HIST_BIN_M = 0.01
#: a real frame's floor pixels lie within this of its floor plane, metres
FLOOR_BAND_M = 0.01


@dataclass
class FrameStats:
    """What one frame shows (shares of the image's pixels, depths in metres)."""

    name: str
    view: BinView | None
    error: str | None
    in_volume: float
    depths: np.ndarray
    missing_in_bin: float
    missing_off_bin: float
    missing_on_parts: float | None = None
    missing_off_parts: float | None = None
    pose: tuple[float, float, float] | None = None  # camera tilt, azimuth (degrees), height over the found floor


def bin_mask(view: BinView, camera: Camera, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool: the pixels inside the bin's inner outline, from its floor to its rim."""
    corners = np.concatenate([view.corners(0.0), view.rim_corners()])
    uv = np.stack([camera.fx * corners[:, 0] / corners[:, 2] + camera.cx,
                   camera.fy * corners[:, 1] / corners[:, 2] + camera.cy], 1)
    hull = cv2.convexHull(np.round(uv).astype(np.int32))
    mask = np.zeros(shape, np.uint8)
    cv2.fillConvexPoly(mask, hull, 1)
    return mask > 0


def frame_stats(name: str, depth: np.ndarray, camera: Camera, clip: tuple[float, float],
                segmentation: np.ndarray | None = None) -> FrameStats:  # fmt: skip
    """The statistics of one frame: ``camera`` with the clip planes the bin is searched between (a real
    camera file's, a generated frame's own), ``clip`` the working volume."""
    try:
        view, error = find_bin(depth, camera, name), None
    except BinNotFound as e:
        view, error = None, str(e)
    valid = np.isfinite(depth)
    eps = 1e-3 * (clip[1] - clip[0])
    inside = valid & (depth > clip[0] + eps) & (depth < clip[1] - eps)
    missing = ~valid
    stats = FrameStats(name, view, error, float(inside.mean()), depth[inside].astype(np.float32), np.nan,
                       float(missing.mean()))
    if view is not None:
        stats.pose = (*rig.tilt_azimuth(view.floor.normal), rig.generator_height(view.floor, camera))
        in_bin = bin_mask(view, camera, depth.shape)
        stats.missing_in_bin = float(missing[in_bin].mean()) if in_bin.any() else np.nan
        stats.missing_off_bin = float(missing[~in_bin].mean())
    if segmentation is not None:
        parts = segmentation > 0
        stats.missing_on_parts = float(missing[parts].mean()) if parts.any() else np.nan
        stats.missing_off_parts = float(missing[~parts].mean())
    return stats


def sensor_depth(sensor: SensorModel, depth: np.ndarray, camera: Camera, clip: tuple[float, float],
                 rng: np.random.Generator) -> np.ndarray:
    """``sensor`` applied to a generated frame's ideal depth; what the frame wrote onto a clip plane (a
    surface beyond it, ``outside_clip=clamp``) stays on the plane where the sensor measured it, as the
    generator applies the sensor before it clamps."""
    out = sensor.apply(depth, camera, rng)
    eps = 1e-3 * (clip[1] - clip[0])
    for plane, on in ((clip[0], depth <= clip[0] + eps), (clip[1], depth >= clip[1] - eps)):
        out = np.where(on & np.isfinite(out), np.float32(plane), out)
    return out


def histogram(depths: list[np.ndarray], clip: tuple[float, float]) -> np.ndarray:
    """The normalized histogram of the depths of several frames over the working volume."""
    edges = np.arange(clip[0], clip[1] + HIST_BIN_M, HIST_BIN_M)
    counts = sum(np.histogram(d, bins=edges)[0] for d in depths)
    total = float(np.sum(counts))
    return np.asarray(counts, dtype=np.float64) / max(total, 1.0)


def overlap(a: np.ndarray, b: np.ndarray) -> float:
    """The overlap of two normalized histograms (1: the same, 0: disjoint)."""
    return float(np.minimum(a, b).sum())


def floor_residual(real: np.ndarray, view: BinView, generated: np.ndarray, camera: Camera) -> np.ndarray:
    """(H, W) real minus generated depth (metres) on the real frame's floor inside its bin, NaN elsewhere
    (both depths at the real camera's pixels)."""
    v, u = np.mgrid[0 : real.shape[0], 0 : real.shape[1]]
    pts = np.stack([(u - camera.cx) * real / camera.fx, (v - camera.cy) * real / camera.fy, real], -1)
    on_floor = np.abs(view.floor.height(pts.reshape(-1, 3))).reshape(real.shape) < FLOOR_BAND_M
    keep = on_floor & bin_mask(view, camera, real.shape) & np.isfinite(generated)
    return np.where(keep, real - generated, np.nan)


def mean_of(values: list[float | None]) -> float:
    kept = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(kept)) if kept else float("nan")


def median_of(values: list[float | None]) -> float:
    """The median of the finite values (a frame whose pile hides the floor measures another bin: the
    median keeps to the others)."""
    kept = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.median(kept)) if kept else float("nan")


def placements(stats: list[FrameStats], T_world_cam: np.ndarray) -> np.ndarray:
    """(N, 3) x, y, yaw of the bins found, in the world of ``T_world_cam``."""
    return np.array([rig.bin_placement(T_world_cam, s.view.centre, s.view.axis) for s in stats if s.view is not None]
                    ).reshape(-1, 3)


def preset_distance(real: dict[str, float], preset: dict[str, float]) -> float:
    """How far a preset's statistics lie from the real frames': missing shares in percentage points plus the
    floor noise in millimetres."""
    return (100 * abs(real["missing_in_bin"] - preset["missing_in_bin"])
            + 100 * abs(real["missing_off_bin"] - preset["missing_off_bin"])
            + 1000 * abs(real["floor_rms"] - preset["floor_rms"]))


def summary(stats: list[FrameStats]) -> dict[str, float]:
    """The means over frames the preset comparison uses."""
    return {"missing_in_bin": mean_of([s.missing_in_bin for s in stats]),
            "missing_off_bin": mean_of([s.missing_off_bin for s in stats]),
            "floor_rms": median_of([s.view.floor_rms if s.view is not None else None for s in stats])}
