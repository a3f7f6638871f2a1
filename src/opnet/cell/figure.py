"""A cell's quantities drawn on one of its frames (a PNG): the depth, the floor's plane, the bin's inner outline
at its floor and rim, the working area, the generator's world axes and the image centre's ray to the floor.
OpenCV only."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from opnet.cell import rig
from opnet.cell.bin_view import BinView
from opnet.cell.estimate import Cell
from opnet.fileio.atomic import write_bytes_atomic

#: the drawing's width, pixels
WIDTH = 1100
#: BGR colours
FLOOR, RIM, AREA, CENTRE = (60, 200, 60), (0, 140, 255), (255, 80, 255), (0, 255, 255)
AXES = ((0, 0, 255), (0, 200, 0), (255, 120, 0))


def _project(cell: Cell, points_cam: np.ndarray, scale: float) -> np.ndarray:
    c = cell.camera
    p = np.asarray(points_cam, dtype=np.float64)
    return np.stack([(c.fx * p[:, 0] / p[:, 2] + c.cx) * scale, (c.fy * p[:, 1] / p[:, 2] + c.cy) * scale], 1)


def _from_world(cell: Cell, points_world: np.ndarray) -> np.ndarray:
    T = np.linalg.inv(cell.T_world_cam)
    return np.asarray(points_world) @ T[:3, :3].T + T[:3, 3]


def _poly(img: np.ndarray, pts: np.ndarray, colour: tuple[int, int, int], width: int = 2) -> None:
    cv2.polylines(img, [np.round(pts * 16).astype(np.int32)], True, colour, width, cv2.LINE_AA, shift=4)


def _text(img: np.ndarray, lines: list[str], y0: int = 22) -> None:
    """White lines on a darkened band at the top."""
    img[: y0 + 22 * len(lines) - 12] = (0.35 * img[: y0 + 22 * len(lines) - 12]).astype(np.uint8)
    for i, line in enumerate(lines):
        cv2.putText(img, line, (10, y0 + 22 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (255, 255, 255), 1, cv2.LINE_AA)


def draw_cell(cell: Cell, depth: np.ndarray, view: BinView, out: Path, title: str) -> None:
    """Draw ``cell`` on the frame ``depth`` (whose bin is ``view``) into the PNG ``out`` (atomic)."""
    scale = WIDTH / depth.shape[1]
    size = (WIDTH, int(round(depth.shape[0] * scale)))
    near, far = cell.clip
    grey = np.clip((np.nan_to_num(depth, nan=far) - near) / max(far - near, 1e-6), 0, 1)
    img = cv2.cvtColor(cv2.resize((255 - 200 * grey).astype(np.uint8), size, interpolation=cv2.INTER_AREA),
                       cv2.COLOR_GRAY2BGR)
    img[cv2.resize(np.isnan(depth).astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0] = (40, 20, 20)
    # the floor's plane: pixels within 1 cm of it, tinted
    c = cell.camera
    v, u = np.mgrid[0 : depth.shape[0], 0 : depth.shape[1]]
    pts = np.stack([(u - c.cx) * depth / c.fx, (v - c.cy) * depth / c.fy, depth], -1)
    on_floor = np.abs(view.floor.height(pts.reshape(-1, 3))).reshape(depth.shape) < 0.01
    tint = cv2.resize(on_floor.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    img[tint] = (0.5 * img[tint] + 0.5 * np.array(FLOOR)).astype(np.uint8)
    _poly(img, _project(cell, view.corners(0.0), scale), FLOOR)
    _poly(img, _project(cell, view.rim_corners(), scale), RIM)
    x0, y0, x1, y1 = cell.area
    area = np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])
    _poly(img, _project(cell, _from_world(cell, area), scale), AREA)
    # the world axes at the origin (where the image centre's ray meets the floor), 0.1 m long
    o = _project(cell, _from_world(cell, np.zeros((1, 3))), scale)[0]
    for k, colour in enumerate(AXES):
        tip = _project(cell, _from_world(cell, np.eye(3)[k : k + 1] * 0.1), scale)[0]
        cv2.arrowedLine(img, tuple(np.round(o).astype(int)), tuple(np.round(tip).astype(int)), colour, 2, cv2.LINE_AA,
                        tipLength=0.2)
        cv2.putText(img, "xyz"[k], tuple(np.round(tip + 4).astype(int)), cv2.FONT_HERSHEY_SIMPLEX, 0.5, colour, 1)
    u0, v0 = rig.image_centre(c)
    cv2.drawMarker(img, (int(round(u0 * scale)), int(round(v0 * scale))), CENTRE, cv2.MARKER_CROSS, 18, 2)
    centre = _project(cell, view.centre[None], scale)[0]
    cv2.circle(img, tuple(np.round(centre).astype(int)), 5, RIM, -1, cv2.LINE_AA)
    sides, wall = cell.sides, cell.wall_height
    _text(img, [title,
                f"camera_tilt_deg {cell.tilt_deg:.2f}, camera_azimuth_deg {cell.azimuth_deg:.2f} (world axes x red, "
                f"y green, z blue)",
                f"camera_height {cell.camera_height:.4f} m: depth of the floor at the image centre (yellow cross)",
                f"bin inner {sides[0]:.3f} x {sides[1]:.3f} m at the floor (green) and rim (orange), walls "
                f"{wall:.3f} m",
                f"bin_area (the bin centre, magenta) [{x0:.2f}, {y0:.2f}, {x1:.2f}, {y1:.2f}] m; "
                f"working volume {near:.2f}-{far:.2f} m"])
    ok, png = cv2.imencode(".png", img)
    if not ok:
        raise ValueError(f"{out}: could not encode the drawing")
    write_bytes_atomic(out, png.tobytes())


__all__ = ["draw_cell"]
