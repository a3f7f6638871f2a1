"""The bin in one depth frame, measured from the depth alone: its inner floor, walls, rim and support.

1. **Planes.** The frame's valid depth between the camera file's clip planes is back-projected (about
   :data:`~opnet.cell.planes.SAMPLE_PIXELS` samples a side) and the planes the camera faces are found by
   sequential RANSAC with a least-squares refit (:mod:`opnet.cell.planes`), inliers within a tolerance
   that grows with the depth (0.3 % of it, at least 2 mm).
2. **The inner floor.** On each plane, a metric grid (two sample spacings a cell) holds the plane's
   inliers (the floor seen between the parts and through a basket's holes) and the points risen above it by
   :data:`RISE_M` or more (walls, rim, parts). The inliers' cells, closed over :data:`CLOSE_M` and less
   the risen cells, fall into connected regions; a region (or all of them together: the pieces of a floor
   a pile's parts cut up, :data:`MIN_FILL_PIECES`) is a bin's floor when it is rectangular (its
   minimum-area rectangle at least :data:`MIN_FILL` full) and walls rise beside at least three of the
   rectangle's sides, each along most of its length (the fourth may hide in the sensor's shadow or be missing from the depth). The
   floor of most inliers over all planes is the bin's; the floor plane is refitted on its inliers alone (a
   bin on the ground: its floor, not the ground's).
3. **Walls and rim.** In the rectangle's frame each side's wall points (risen, up to :data:`SIDE_BAND_M`
   beyond the floor's edge) give the rim height (the 95th percentile of their heights; the median over
   the sides: a handle above one wall does not lift it) and the wall's position (the densest cluster of
   their outward coordinate above a quarter of the rim height: the face the camera sees, the inner one
   unless the camera stands beyond the wall) and, where the rim's top is seen, its inner edge (the 10th
   percentile across it; its width is the wall's thickness). The inner face lies no nearer than the
   floor's edge; a side without wall points takes the farther of
   the floor's edge and the end of the rims running towards it.
4. **Support.** The plane the bin stands on is the largest other plane within :data:`SUPPORT_ANGLE_DEG`
   of the floor, at or below it, most of whose inliers lie outside the bin: the drop from the floor to it
   along the floor's normal at the bin's centre, and the angle between them.

Every failure is a :class:`BinNotFound` (no plane, no bin) naming the frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from opnet.cell.planes import Plane, back_project, find_planes, plane_axes, refit, sample_stride
from opnet.geometry.camera import Camera

#: points risen this far over a floor are walls, rim or parts, metres (at least three plane tolerances)
RISE_M = 0.015
#: gaps closed in the floor's cells (a basket's holes, parts lying on it, dropouts), metres
CLOSE_M = 0.03
#: a floor region's smallest side, metres
MIN_SIDE_M = 0.08
#: a bin's floor fills at least this share of its minimum-area rectangle; its pieces together (each of at
#: least MIN_PIECE_CELLS grid cells), between the parts of a pile, this share
MIN_FILL = 0.6
MIN_FILL_PIECES = 0.4
MIN_PIECE_CELLS = 10
#: how far beyond the floor's edge a side's wall points are looked for, metres (the floor behind a near
#: wall hides in its shadow), and how far inside it
SIDE_BAND_M = 0.12
INSIDE_BAND_M = 0.03
#: a wall's position is measured this far from the corners, metres
CORNER_M = 0.04
#: the tallest bin wall looked for, metres
MAX_WALL_M = 1.0
#: a side has a wall where this many wall points per metre of its length per sample spacing are seen
WALL_POINTS_PER_SAMPLE = 0.15
#: ... along at least this many tenths of the side's length
WALL_COVER_TENTHS = 6
#: the support plane lies within this angle of the floor
SUPPORT_ANGLE_DEG = 25.0
#: the fewest valid points a frame must have, and the fewest inliers of a plane
MIN_POINTS = 500


class BinNotFound(ValueError):
    """No plane, or no bin, in a frame (the message names it)."""


@dataclass(frozen=True)
class BinView:
    """The bin measured in one frame (camera frame, metres).

    Attributes:
        frame: the frame's name (its file).
        floor: the inner floor's plane.
        centre: (3,) the centre of the inner floor's rectangle, on the floor plane.
        axis: (3,) unit vector in the floor plane along the bin's shorter inner side.
        sides: inner sizes (along ``axis``, across it), the first the shorter.
        wall_height: the rim's height over the inner floor.
        thickness: the rim's width seen from above (the wall's thickness).
        walls_seen: how many of the four sides showed wall points.
        support: the plane the bin stands on, or None where none is seen below it.
        support_drop: the distance from the inner floor down to ``support`` at the centre, along the
            floor's normal (None without a support).
        support_angle_deg: the angle between the floor and ``support`` (None without a support).
        floor_rms: the floor's residual over its inliers, metres.
        points: how many valid points the frame gave.
    """

    frame: str
    floor: Plane
    centre: np.ndarray
    axis: np.ndarray
    sides: tuple[float, float]
    wall_height: float
    thickness: float
    walls_seen: int
    support: Plane | None
    support_drop: float | None
    support_angle_deg: float | None
    floor_rms: float
    points: int

    @property
    def across(self) -> np.ndarray:
        """(3,) unit vector in the floor plane along the longer inner side."""
        return np.cross(self.floor.normal, self.axis)

    def rim_corners(self) -> np.ndarray:
        """(4, 3) the corners of the inner rectangle at the rim's height (camera frame)."""
        return self.corners(self.wall_height)

    def corners(self, height: float = 0.0, grow: float = 0.0) -> np.ndarray:
        """(4, 3) the corners of the inner rectangle grown by ``grow`` a side, ``height`` over the floor."""
        a, b = self.sides[0] / 2 + grow, self.sides[1] / 2 + grow
        up = self.floor.normal * height
        return np.array([self.centre + sa * a * self.axis + sb * b * self.across + up
                         for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))])


@dataclass(frozen=True)
class _Floor:
    """A candidate inner floor: its plane, rectangle (centre, unit axes, half sides; camera frame) and score."""

    plane: Plane
    centre: np.ndarray
    axes: tuple[np.ndarray, np.ndarray]
    half: tuple[float, float]
    walls: int
    area: float
    members: np.ndarray  # indices of the points of the floor's inliers in its region


def find_bin(depth: np.ndarray, camera: Camera, frame: str) -> BinView:
    """The bin of one z-depth image (H, W metres, NaN missing) of ``camera`` (module docstring).

    Raises:
        BinNotFound: too little depth, no plane facing the camera, or no floor with walls (names ``frame``).
    """
    stride = sample_stride(camera)
    points, _ = back_project(depth, camera, stride)
    if len(points) < MIN_POINTS:
        raise BinNotFound(f"{frame}: {len(points)} sampled pixels have depth between the clip planes "
                          f"[{camera.clip_start:g}, {camera.clip_end:g}] m; too few to measure a bin")
    depth_m = float(np.median(points[:, 2]))
    tol = max(0.002, 0.003 * depth_m)
    spacing = stride * depth_m / camera.fx
    planes = find_planes(points, tol, np.random.default_rng(0), min_points=max(MIN_POINTS, len(points) // 100))
    if not planes:
        raise BinNotFound(f"{frame}: no plane facing the camera in its depth (is it a depth image of the bin, "
                          "and its camera the frames' camera?)")
    rise = max(RISE_M, 3 * tol)
    floors = [f for plane, _ in planes for f in _floors(points, plane, tol, rise, spacing)]
    if not floors:
        raise BinNotFound(f"{frame}: no bin: none of its {len(planes)} plane(s) holds a rectangular floor with "
                          "walls rising on three sides or more")
    best = max(floors, key=lambda f: len(f.members))
    return _measure(points, best, planes, tol, rise, spacing, frame)


def _grid(xy: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, tuple[int, int], np.ndarray]:
    origin = xy.min(0)
    ij = np.floor((xy - origin) / cell).astype(np.intp)
    shape = (int(ij[:, 1].max()) + 1, int(ij[:, 0].max()) + 1)
    return ij[:, 0], ij[:, 1], shape, origin


def _floors(points: np.ndarray, plane: Plane, tol: float, rise: float, spacing: float) -> list[_Floor]:
    """The rectangular floors with walls on ``plane`` (module docstring, step 2)."""
    h = plane.height(points)
    near = (h > -tol) & (h < MAX_WALL_M)
    if near.sum() < MIN_POINTS:
        return []
    e1, e2 = plane_axes(plane.normal)
    index = np.flatnonzero(near)
    p = points[near]
    xy = np.stack([p @ e1, p @ e2], axis=1)
    cell = max(2.0 * spacing, 0.002)
    ix, iy, shape, origin = _grid(xy, cell)
    if shape[0] * shape[1] > 4e7:  # a plane seen to the horizon: no bin floor
        return []
    hn = h[near]
    floor = np.zeros(shape, np.uint8)
    floor[iy[hn < tol], ix[hn < tol]] = 1
    risen = np.zeros(shape, bool)
    risen[iy[hn >= rise], ix[hn >= rise]] = True
    k = max(3, int(math.ceil(CLOSE_M / cell)) | 1)
    closed = cv2.morphologyEx(floor, cv2.MORPH_CLOSE, np.ones((k, k), np.uint8))
    closed[risen] = 0
    count, labels, stats, _ = cv2.connectedComponentsWithStats(closed, connectivity=8)
    min_cells = (MIN_SIDE_M / cell) ** 2
    walls_xy, walls_h = xy[hn >= rise], hn[hn >= rise]
    out = []
    # each region alone, and the pieces together (a pile's parts cut the floor it covers into pieces)
    pieces = [label for label in range(1, count) if stats[label, cv2.CC_STAT_AREA] >= MIN_PIECE_CELLS]
    groups = [([label], MIN_FILL) for label in pieces if stats[label, cv2.CC_STAT_AREA] >= min_cells]
    if len(pieces) > 1:
        groups.append((pieces, MIN_FILL_PIECES))
    for group, min_fill in groups:
        inside = np.isin(labels, group)
        area = int(np.count_nonzero(inside))
        cells = np.argwhere(inside)[:, ::-1].astype(np.float32)
        (cu, cv), (w, l), angle = cv2.minAreaRect(cells)
        if min(w, l) * cell < MIN_SIDE_M or area < min_fill * w * l:
            continue
        t = math.radians(angle)
        u = np.array([math.cos(t), math.sin(t)])
        centre2 = origin + (np.array([cu, cv]) + 0.5) * cell
        half = (w * cell / 2, l * cell / 2)
        walls = _sides_with_walls(walls_xy - centre2, walls_h, u, half, spacing)
        if walls < 3:
            continue
        centre = centre2[0] * e1 + centre2[1] * e2 - plane.offset * plane.normal
        axes = (u[0] * e1 + u[1] * e2, -u[1] * e1 + u[0] * e2)
        members = index[(hn < tol) & inside[iy, ix]]
        out.append(_Floor(plane, centre, axes, half, walls, area * cell * cell, members))
    return out


def _sides_with_walls(q: np.ndarray, h: np.ndarray, u: np.ndarray, half: tuple[float, float],
                      spacing: float) -> int:  # fmt: skip
    """How many sides of the rectangle (half sides ``half`` along ``u`` and its normal) have wall points
    (``q``: risen points relative to its centre, plane coordinates)."""
    a = q @ u
    b = q @ np.array([-u[1], u[0]])
    n = 0
    for along, other, half_along, half_other in ((a, b, half[0], half[1]), (b, a, half[1], half[0])):
        inside = np.abs(other) <= half_other + INSIDE_BAND_M
        for sign in (1.0, -1.0):
            out = sign * along
            band = inside & (out >= half_along - INSIDE_BAND_M) & (out <= half_along + SIDE_BAND_M)
            if np.count_nonzero(band) < WALL_POINTS_PER_SAMPLE * 2 * half_other / spacing:
                continue
            # a wall runs along the side: its points in most tenths of the side's length
            tenths = np.clip(((other[band] + half_other) / (2 * half_other) * 10).astype(np.intp), 0, 9)
            n += np.count_nonzero(np.bincount(tenths, minlength=10) >= 2) >= WALL_COVER_TENTHS
    return n


def _measure(points: np.ndarray, found: _Floor, planes: list[tuple[Plane, np.ndarray]], tol: float, rise: float,
             spacing: float, frame: str) -> BinView:  # fmt: skip
    """Step 3 and 4 of the module docstring on the chosen floor."""
    ax, ay = found.axes
    rel = points - found.centre
    a, b = rel @ ax, rel @ ay
    inside = (np.abs(a) < found.half[0] - 0.01) & (np.abs(b) < found.half[1] - 0.01)
    floor, _ = refit(points[inside], found.plane, tol)
    floor_in = inside & (np.abs(floor.height(points)) < tol)
    floor_rms = float(np.sqrt(np.mean(floor.height(points[floor_in]) ** 2))) if floor_in.any() else 0.0
    # the rectangle carried onto the refitted plane
    n = floor.normal
    centre = found.centre - floor.height(found.centre[None])[0] * n
    ax = ax - (ax @ n) * n
    ax /= np.linalg.norm(ax)
    ay = np.cross(n, ax)
    rel = points - centre
    a, b, h = rel @ ax, rel @ ay, floor.height(points)
    risen = (h >= rise) & (h <= MAX_WALL_M)
    sides = {}  # (axis index, sign) -> wall points of that side
    for k, (along, other) in enumerate(((a, b), (b, a))):
        for sign in (1.0, -1.0):
            out = sign * along
            band = (risen & (np.abs(other) <= found.half[1 - k] + INSIDE_BAND_M)
                    & (out >= found.half[k] - INSIDE_BAND_M) & (out <= found.half[k] + SIDE_BAND_M))
            if np.count_nonzero(band) >= WALL_POINTS_PER_SAMPLE * 2 * found.half[1 - k] / spacing:
                sides[(k, sign)] = band
    if not sides:
        raise BinNotFound(f"{frame}: no bin: its floor shows no walls")
    wall_height = float(np.median([np.percentile(h[m], 95) for m in sides.values()]))
    top = (h >= wall_height - max(0.005, 0.04 * wall_height)) & (h <= wall_height + 0.01)
    # the camera's foot on the floor, in the rectangle's frame: beyond a wall, the camera sees its outer face
    foot = -floor.offset * n - centre
    camera_out = {(k, sign): sign * (foot @ (ax, ay)[k]) > found.half[k] for k in (0, 1) for sign in (1.0, -1.0)}
    faces, rim_inner, widths = {}, {}, []
    for (k, sign), band in sides.items():
        coord = sign * (a, b)[k]
        other = np.abs((b, a)[k])  # away from the corners, where the other walls run across the band
        band = band & (other <= max(found.half[1 - k] - CORNER_M, found.half[1 - k] / 2))
        upper = band & (h >= 0.25 * wall_height) & (h <= wall_height + 0.01)
        if np.count_nonzero(upper) >= 5:
            faces[(k, sign)] = _densest(coord[upper], max(0.002, spacing))
        rim = coord[band & top]
        if len(rim) >= 5:
            lo, hi = np.percentile(rim, [10, 90])
            rim_inner[(k, sign)] = float(lo)
            widths.append((hi - lo) / 0.8)  # the middle 80 % of a uniform strip
    thickness = float(np.clip(np.median(widths), 0.001, 0.05)) if widths else 0.002
    # the rim's inner edge where the rim is seen, else the face the camera sees (beyond the wall: the outer one)
    faces = {key: rim_inner.get(key, face - (thickness if camera_out[key] else 0.0)) for key, face in faces.items()}
    edges = {}
    for k, along in enumerate((a, b)):
        for sign in (1.0, -1.0):
            coord = sign * along
            # the floor's region reaches this far (its inliers, a stray thousandth left out)
            floor_edge = float(np.percentile(coord[found.members], 99.9))
            if (k, sign) in faces:
                edges[(k, sign)] = max(faces[(k, sign)], floor_edge)
                continue
            # no wall seen on this side: the rims running towards it end at its wall
            rims = np.zeros(len(points), bool)
            for (k2, s2), band in sides.items():
                if k2 != k:
                    rims |= band & top
            rim_end = float(np.percentile(coord[rims], 99)) - thickness if rims.sum() >= 5 else -math.inf
            edges[(k, sign)] = max(floor_edge, rim_end)
    import os
    if os.environ.get("CELL_DEBUG"):
        print(frame, {key: round(float(v), 4) for key, v in edges.items()}, {key: round(v, 4) for key, v in faces.items()}, found.half)
    lengths = [edges[(k, 1.0)] + edges[(k, -1.0)] for k in (0, 1)]
    shift = [(edges[(k, 1.0)] - edges[(k, -1.0)]) / 2 for k in (0, 1)]
    centre = centre + shift[0] * ax + shift[1] * ay
    if lengths[0] > lengths[1]:
        lengths, ax = lengths[::-1], ay
    support, drop, angle = _support(points, planes, floor, centre, ax, lengths, thickness, tol)
    return BinView(frame, floor, centre, ax, (float(lengths[0]), float(lengths[1])), wall_height, thickness,
                   len(sides), support, drop, angle, floor_rms, len(points))


def _densest(values: np.ndarray, width: float) -> float:
    """Where ``values`` are densest: the median of those within a bin and a half of the histogram's peak
    (bins of ``width``, smoothed over three)."""
    lo_v, hi_v = float(values.min()), float(values.max())
    bins = max(1, int(math.ceil((hi_v - lo_v) / width)) + 1)
    counts, edges = np.histogram(values, bins=bins, range=(lo_v, lo_v + bins * width))
    peak = int(np.argmax(np.convolve(counts, np.ones(3) / 3, mode="same")))
    centre = (edges[peak] + edges[peak + 1]) / 2
    return float(np.median(values[np.abs(values - centre) <= 1.5 * width]))


def _support(points: np.ndarray, planes: list[tuple[Plane, np.ndarray]], floor: Plane, centre: np.ndarray,
             ax: np.ndarray, sides: list[float], thickness: float, tol: float
             ) -> tuple[Plane | None, float | None, float | None]:  # fmt: skip
    """The plane the bin stands on (module docstring, step 4): (plane, drop, angle) or Nones."""
    ay = np.cross(floor.normal, ax)
    best, best_count = None, 0
    for plane, inliers in planes:
        angle = floor.angle_deg(plane)
        if angle > SUPPORT_ANGLE_DEG:
            continue
        along = float(plane.normal @ floor.normal)
        drop = plane.height(centre[None])[0] / along  # the floor's normal line down to the plane
        if drop < -tol:
            continue  # above the floor
        rel = points[inliers] - centre
        outside = (np.abs(rel @ ax) > sides[0] / 2 + thickness + 0.02) | (np.abs(rel @ ay) > sides[1] / 2 + thickness + 0.02)
        count = int(np.count_nonzero(outside))
        if count > max(best_count, 0.5 * inliers.sum()):
            best, best_count = (plane, max(float(drop), 0.0), angle), count
    return best if best is not None else (None, None, None)
