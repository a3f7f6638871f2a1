"""Find the bin in a depth image: the region of interest that follows a bin that moved (``data.roi=auto``).

In a real cell the bin is pushed, swapped and turned between shifts while the camera stays; a fixed pixel
box cut around one placement then cuts the bin or misses it. The bin is what fills the working volume (the
depth between the clip planes, which the user sets around the bin's height): this module finds it per image
from the depth alone, with no model of the cell.

- ``auto:S`` (S in metres): the crop is a square of side ``S`` at the bin's depth, centred on the bin. The
  bin's centre is found on a metric grid of the working-volume points (camera x and y, each point weighted
  by the area of the surface it stands for, so near and far count alike): the windows of ``S`` x ``S`` that
  hold the most surface are those the whole bin fits in; the centre of that plateau is the bin's centre
  (a window larger than the bin slides over it without changing its sum). Its depth is the middle of the
  depths inside the window. The crop has a fixed metric size, so a part is the same number of network pixels
  wherever the bin stands: the size recorded with a checkpoint is the one it was trained with.
- ``auto``: the bounding box of the bin's region, 2 % of the image side to spare: the bin's own box, whose
  size changes with the bin.

The bin's region, for both, is the largest connected region of working-volume depth, after closing the gaps
of a wire basket's holes and the sensor's dropouts (3 cm) and opening away what is thinner than 8 cm (bars of
the cell, cables, a neighbour's rim touching the bin), measured by the surface it covers with the gaps closed
(a perforated floor by its outline: by its bars alone, a floor reaching into the volume at the far side of a
tilted camera outweighed it); with ``auto:S`` a region wider than S (the bin fits in its crop), a floor
reaching into the volume across the frame, gives way to the largest region that fits, and of fitting
regions about as large the nearer is the bin (it stands above the floor, whose patch in the volume lies at
the far plane). ``auto:S`` then centres on that region alone.

Both look at the image subsampled to about :data:`GRID_PIXELS` pixels a side (fast on 2-megapixel frames)
and raise :class:`NoBinError` (one line, naming the frame) where the clip planes hold no bin. NumPy and OpenCV
only: the ONNX runtime uses it too.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from opnet.geometry.camera import Camera
from opnet.settings_schema import MIN_BOX_SIDE

#: the subsampled image's longer side, pixels
GRID_PIXELS = 320
#: cells of the metric grid across the window side
WINDOW_CELLS = 60
#: windows holding at least this share of the best window's surface are on the plateau
PLATEAU = 0.97
#: a window holding less than this share of its area in surface is no bin (an empty wire basket under a
#: structured-light sensor fills 2-3 % of a square of its diagonal)
MIN_FILL = 0.005
#: gaps the bin's region is closed over (holes of a wire basket, dropouts), metres
CLOSE_M = 0.03
#: what is thinner than this is opened away from the bin's region (bars, cables), metres
OPEN_M = 0.08
#: a region that fits in the crop (auto:S) wins over a larger one that does not where it covers at least
#: this share of the crop's area (a bin's outline fills about a third of a square 1.1 x its diagonal; what
#: covers less is no bin, and the largest region stays)
MIN_FIT_SHARE = 0.05
#: of fitting regions with at least this share of the largest fitting one's surface, the nearest is the bin
NEAR_TIE = 0.75
#: regions tried, largest first, after the largest
MAX_REGIONS = 8
#: margin of the connected-region box, share of the image's longer side
REGION_MARGIN = 0.02
Box = tuple[int, int, int, int]


class NoBinError(ValueError):
    """No bin in the working volume of a frame."""


@dataclass(frozen=True)
class FoundBin:
    """A bin found in one image: its centre (camera frame, metres) and the pixel box to crop."""

    centre: np.ndarray
    box: Box


def _samples(depth: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """The subsampled depth (h, w), its pixel coordinates (u (w,), v (h,)) in the full image, and the stride;
    depth outside the open working volume (beyond the planes, or clamped onto them) is NaN."""
    H, W = depth.shape
    s = max(1, int(math.ceil(max(W, H) / GRID_PIXELS)))
    d = np.asarray(depth, dtype=np.float64)[s // 2 :: s, s // 2 :: s].copy()
    near, far = camera.clip_start, camera.clip_end
    eps = 1e-3 * (far - near)  # a surface written at a plane (outside_clip=clamp, a clamped input) is outside
    d[~(np.isfinite(d) & (d > near + eps) & (d < far - eps))] = np.nan
    return d, np.arange(s // 2, W, s, dtype=np.float64), np.arange(s // 2, H, s, dtype=np.float64), s


def _no_bin(where: str, frame: str | None, why: str) -> NoBinError:
    what = f"{frame}: " if frame else ""
    return NoBinError(f"{where}: {what}no bin found between the clip planes ({why}); check the planes "
                      "(they must hold the bin) or give a fixed box")  # fmt: skip


def find_bin(depth: np.ndarray, camera: Camera, side: float | None, where: str = "data.roi=auto",
             frame: str | None = None) -> FoundBin:  # fmt: skip
    """The bin of one z-depth image (H, W) (metres, NaN missing) seen by ``camera`` (its clip planes bound
    the working volume): with ``side`` (metres) the square box of that size centred on it, else the box of
    its connected region (module docstring).

    Raises:
        NoBinError: no bin between the clip planes (the message names ``where`` and ``frame``).
    """
    depth = np.asarray(depth)
    if depth.ndim != 2 or depth.shape != (camera.height, camera.width):
        raise ValueError(f"{where}: the depth image is {depth.shape}, the camera {camera.width} x {camera.height}")
    d, u, v, s = _samples(depth, camera)
    ok = np.isfinite(d)
    if ok.sum() < 16:
        raise _no_bin(where, frame, f"{int(ok.sum())} of {d.size} sampled pixels in the working volume")
    if side is None:
        return _region(d, _largest_region(d, ok, camera.fx / float(np.median(d[ok])) / s), u, v, s, camera)
    xy = _metric_xy(d, u, v, camera)
    sel = _largest_region(d, ok, camera.fx / float(np.median(d[ok])) / s, (xy, float(side), s / camera.fx))
    return _centred(d, sel, xy, s, camera, float(side), where, frame)


def _metric_xy(d: np.ndarray, u: np.ndarray, v: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Camera x and y (metres) of every sample (h, w); NaN where the depth is."""
    return (u[None, :] - camera.cx) * d / camera.fx, (v[:, None] - camera.cy) * d / camera.fy


def _largest_region(d: np.ndarray, ok: np.ndarray, px_per_m: float,
                    fit: tuple[tuple[np.ndarray, np.ndarray], float, float] | None = None) -> np.ndarray:  # fmt: skip
    """The samples (h, w) bool of the largest connected region (by surface) of working-volume depth, after
    closing gaps up to :data:`CLOSE_M` (a wire basket's holes, the sensor's dropouts) and opening away what
    is thinner than :data:`OPEN_M` (bars of the cell, cables, a neighbour's rim touching the bin). With
    ``fit`` (the samples' camera x and y, the crop's side S and a sample's side per metre of depth), a region
    wider than S (the bin fits in its crop) gives way to the largest one that fits, where that one covers at
    least :data:`MIN_FIT_SHARE` of S x S: a floor or table reaching into the volume across the frame is no
    bin, however large; and of fitting regions with :data:`NEAR_TIE` of the largest fitting one's surface, the
    nearest (median depth) is the bin. Where none fits, the largest region stays."""

    def kernel(metres: float) -> np.ndarray:
        k = int(min(max(3, metres * px_per_m), max(3, min(d.shape) // 8)))
        return np.ones((k | 1, k | 1), np.uint8)

    closed = cv2.morphologyEx(ok.astype(np.uint8), cv2.MORPH_CLOSE, kernel(CLOSE_M))
    opened = cv2.morphologyEx(closed, cv2.MORPH_OPEN, kernel(OPEN_M))
    if not opened.any():  # all of it thinner than the opening: keep what closing made
        opened = closed
    n, labels = cv2.connectedComponents(opened, connectivity=8)
    # surface per sample ~ z^2; a gap the closing spanned (a wire basket's hole, a dropout) is the region's
    # surface too, at the region's depth: a perforated floor counts by its outline, not by its bars alone
    # (else a solid surface of four fifths its outline, a floor or table reaching into the volume, wins)
    ids = labels.ravel()
    z2 = np.where(ok, np.nan_to_num(d) ** 2, 0.0).ravel()
    seen = np.bincount(ids, weights=ok.ravel().astype(np.float64), minlength=n)
    depth2 = np.bincount(ids, weights=z2, minlength=n) / np.maximum(seen, 1.0)  # mean z^2 of the seen samples
    area = np.bincount(ids, minlength=n) * depth2
    area[0] = 0.0
    best = int(np.argmax(area))
    if fit is not None:
        xy, side, sample_m = fit
        fitting = [int(label) for label in np.argsort(-area)[: 1 + MAX_REGIONS]
                   if area[label] * sample_m**2 >= MIN_FIT_SHARE * side * side and _fits(labels == label, ok, xy, side)]
        if fitting:  # else none is the bin's size: the largest stays
            # of regions about as large, the nearest: the bin stands above the floor, whose patch reaching
            # into the volume lies at its far plane
            near = [label for label in fitting if area[label] >= NEAR_TIE * area[fitting[0]]]
            best = min(near, key=lambda label: float(np.median(d[(labels == label) & ok])))
    return (labels == best) & ok


def _fits(region: np.ndarray, ok: np.ndarray, xy: tuple[np.ndarray, np.ndarray], side: float) -> bool:
    """Whether the region's seen samples span at most ``side`` in camera x and in camera y (1st to 99th
    percentile: a few stray samples do not widen it)."""
    seen = region & ok
    if seen.sum() < 4:
        return False
    return all(float(np.subtract(*np.percentile(c[seen], [99.0, 1.0]))) <= side for c in xy)


def _region(d: np.ndarray, sel: np.ndarray, u: np.ndarray, v: np.ndarray, s: int, camera: Camera) -> FoundBin:
    """The pixel box of the region ``sel`` (samples), :data:`REGION_MARGIN` to spare."""
    rows, cols = np.flatnonzero(sel.any(1)), np.flatnonzero(sel.any(0))
    W, H = camera.width, camera.height
    m = int(round(REGION_MARGIN * max(W, H)))
    x0, x1 = int(u[cols[0]]) - s // 2 - m, int(u[cols[-1]]) + s - s // 2 + m
    y0, y1 = int(v[rows[0]]) - s // 2 - m, int(v[rows[-1]]) + s - s // 2 + m
    zc = float(np.median(d[sel]))
    uc, vc = float(np.broadcast_to(u, d.shape)[sel].mean()), float(np.broadcast_to(v[:, None], d.shape)[sel].mean())
    centre = np.array([(uc - camera.cx) * zc / camera.fx, (vc - camera.cy) * zc / camera.fy, zc])
    return FoundBin(centre, (max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)))


def _centred(d: np.ndarray, sel: np.ndarray, xy: tuple[np.ndarray, np.ndarray], s: int, camera: Camera,
             side: float, where: str, frame: str | None) -> FoundBin:  # fmt: skip
    """The square box of ``side`` metres centred on the bin: the plateau of the best windows over the
    region's points (``xy``: every sample's camera x and y; a window the whole region fits in slides over it
    without changing its sum)."""
    z = d[sel]
    pixels = side * min(camera.fx, camera.fy) / float(np.median(z))
    if pixels < MIN_BOX_SIDE:  # before the search, whose grid grows as the square shrinks
        raise ValueError(f"{where}: the {side:g} m square spans {pixels:.1f} pixels at the bin's depth "
                         f"({float(np.median(z)):.2f} m); the network needs at least {MIN_BOX_SIDE} a side: a larger S")
    x, y = xy[0][sel], xy[1][sel]
    area = (s * z) ** 2 / (camera.fx * camera.fy)  # the surface each sample stands for, m^2 (facing the camera)
    k = WINDOW_CELLS
    cell = side / k
    x_lo, y_lo = x.min() - side, y.min() - side  # room for windows reaching past the points
    ix, iy = ((x - x_lo) / cell).astype(np.intp), ((y - y_lo) / cell).astype(np.intp)
    nx, ny = int(ix.max()) + k + 1, int(iy.max()) + k + 1
    grid = np.bincount(iy * nx + ix, weights=area, minlength=nx * ny).reshape(ny, nx)
    integral = np.zeros((ny + 1, nx + 1))
    integral[1:, 1:] = grid.cumsum(0).cumsum(1)
    sums = integral[k:, k:] - integral[:-k, k:] - integral[k:, :-k] + integral[:-k, :-k]  # window at (row, col)
    best = float(sums.max())
    if best < MIN_FILL * side * side:
        raise _no_bin(where, frame, f"the fullest {side:g} m square holds {best / side / side:.1%} of its area")
    rows, cols = np.nonzero(sums >= PLATEAU * best)
    # window (row, col) covers cells row..row+k-1: its centre lies k/2 cells from its corner
    xc = x_lo + (float(cols.mean()) + k / 2.0) * cell
    yc = y_lo + (float(rows.mean()) + k / 2.0) * cell
    inside = (np.abs(x - xc) <= side / 2) & (np.abs(y - yc) <= side / 2)
    lo, hi = np.percentile(z[inside], [2.0, 98.0])
    zc = float(lo + hi) / 2.0
    centre = np.array([xc, yc, zc])
    uc, vc = camera.fx * xc / zc + camera.cx, camera.fy * yc / zc + camera.cy
    half_w, half_h = side / 2.0 * camera.fx / zc, side / 2.0 * camera.fy / zc
    return FoundBin(centre, _fit_box(uc - half_w, vc - half_h, 2.0 * half_w, 2.0 * half_h, camera))


def _fit_box(x: float, y: float, w: float, h: float, camera: Camera) -> Box:
    """A pixel box of size (w, h) at corner (x, y), moved inside the image (never resized, unless larger)."""
    W, H = camera.width, camera.height
    w, h = min(max(int(round(w)), 1), W), min(max(int(round(h)), 1), H)
    x0 = min(max(int(round(x)), 0), W - w)
    y0 = min(max(int(round(y)), 0), H - h)
    return (x0, y0, x0 + w, y0 + h)


__all__ = ["FoundBin", "NoBinError", "find_bin"]
