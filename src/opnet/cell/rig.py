"""A cell's measurements in the generator's terms (:mod:`opnet.synthesis.layout`, :class:`SceneConfig`).

The generator hangs its camera over the world origin, the point of the bin floor that the image centre
looks at, and tilts it about that point by ``camera_tilt_deg`` towards ``camera_azimuth_deg``; so, from
the bin floor's plane as the camera sees it (unit normal ``n`` towards the camera, camera frame):

- ``camera_tilt_deg = acos(-n_z)``, the angle between the optical axis and the floor's normal;
- ``camera_azimuth_deg = atan2(n_y, -n_x)``: the tilted generator camera sees the floor's normal as
  ``(-cos az sin tilt, sin az sin tilt, -cos tilt)``;
- ``camera_height``: the depth (camera z) at which the ray of the image centre ``((W-1)/2, (H-1)/2)``
  meets the floor, the generator's distance from the camera to the world origin. It differs from the
  distance along the optical axis where the principal point lies off the image centre (by 0.56 % for the
  IPD Photoneo tilted 20 degrees: 1 cm at 1.78 m);
- the world frame: z up from the floor, the origin where the image centre meets it, x and y as the
  generator's tilted camera has them (:func:`world_from_camera`); ``bin_area`` and a bin's yaw are in it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from opnet.cell.planes import Plane
from opnet.geometry.camera import Camera
from opnet.synthesis.layout import R_WORLD_CAM_DOWN, homogeneous, inverse_pose, tilted


def tilt_azimuth(normal: np.ndarray) -> tuple[float, float]:
    """(camera_tilt_deg, camera_azimuth_deg) of a floor whose normal (towards the camera) the camera sees as
    ``normal``; the azimuth is 0 for a camera looking straight down."""
    n = np.asarray(normal, dtype=np.float64)
    tilt = math.degrees(math.acos(float(np.clip(-n[2], -1.0, 1.0))))
    return tilt, (math.degrees(math.atan2(n[1], -n[0])) if tilt > 1e-9 else 0.0)


def image_centre(camera: Camera) -> tuple[float, float]:
    """The pixel (u, v) at the centre of the image."""
    return (camera.width - 1) / 2.0, (camera.height - 1) / 2.0


def generator_height(plane: Plane, camera: Camera) -> float:
    """``camera_height`` of a floor ``plane``: the depth at which the image centre's ray meets it."""
    return plane.ray_depth(*image_centre(camera), camera)


def axis_height(plane: Plane) -> float:
    """The distance from the camera to ``plane`` along the optical axis."""
    return plane.offset / max(-float(plane.normal[2]), 1e-12)


def world_from_camera(plane: Plane, camera: Camera) -> np.ndarray:
    """(4, 4) T_world_cam of the generator's world for a camera over the floor ``plane``: the generator's
    rotation for the plane's tilt and azimuth, the origin where the image centre's ray meets the floor."""
    tilt, azimuth = tilt_azimuth(plane.normal)
    R = tilted(homogeneous(R_WORLD_CAM_DOWN, np.zeros(3)), tilt, azimuth)[:3, :3]
    u, v = image_centre(camera)
    depth = generator_height(plane, camera)
    origin = np.array([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0]) * depth
    return homogeneous(R, -R @ origin)


def to_world(T_world_cam: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(N, 3) camera-frame points in the world frame."""
    return np.asarray(points) @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]


def bin_placement(T_world_cam: np.ndarray, centre: np.ndarray, axis: np.ndarray) -> tuple[float, float, float]:
    """(x, y, yaw degrees in (-90, 90]) of a bin whose floor centre and first side's direction the camera
    sees as ``centre`` and ``axis`` (the yaw of a rectangle is defined up to a half turn)."""
    x, y, _ = to_world(T_world_cam, centre[None])[0]
    a = T_world_cam[:3, :3] @ axis
    yaw = math.degrees(math.atan2(a[1], a[0]))
    yaw = (yaw + 90.0) % 180.0 - 90.0
    return float(x), float(y), 90.0 if yaw == -90.0 else yaw


def outer_corners(sides: Sequence[float], thickness: float, x: float, y: float, yaw_deg: float,
                  z: float) -> np.ndarray:  # fmt: skip
    """(4, 3) world corners of a bin's outer outline (inner ``sides`` + the walls) at height ``z``."""
    a, b = sides[0] / 2 + thickness, sides[1] / 2 + thickness
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    return np.array([[x + c * sa * a - s * sb * b, y + s * sa * a + c * sb * b, z]
                     for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))])


def anywhere_in(area: Sequence[float], sides: Sequence[float], thickness: float, z: float) -> np.ndarray:
    """World points of a bin's outer outline at height ``z`` wherever ``area`` = [x0, y0, x1, y1] lets its
    centre stand, in any yaw (every 15 degrees)."""
    x0, y0, x1, y1 = area
    return np.concatenate([outer_corners(sides, thickness, x, y, yaw, z) for x in (x0, x1) for y in (y0, y1)
                           for yaw in np.arange(0.0, 180.0, 15.0)])


def camera_depths(T_world_cam: np.ndarray, points_world: np.ndarray) -> np.ndarray:
    """(N,) camera z of world points."""
    T = inverse_pose(T_world_cam)
    return np.asarray(points_world) @ T[2, :3] + T[2, 3]


def working_volume(T_world_cam: np.ndarray, area: Sequence[float], sides: Sequence[float], thickness: float,
                   wall_height: float, margin: float) -> tuple[float, float]:  # fmt: skip
    """Clip planes (metres) holding the bin wherever the area lets it stand, in any yaw: from ``margin``
    above its rim to ``margin`` below its floor."""
    top = camera_depths(T_world_cam, anywhere_in(area, sides, thickness, wall_height + margin))
    bottom = camera_depths(T_world_cam, anywhere_in(area, sides, thickness, -thickness - margin))
    return float(top.min()), float(bottom.max())


def in_view(T_world_cam: np.ndarray, camera: Camera, points_world: np.ndarray) -> np.ndarray:
    """(N,) whether the camera sees each world point inside its image (in front of it)."""
    T = inverse_pose(T_world_cam)
    p = np.asarray(points_world) @ T[:3, :3].T + T[:3, 3]
    z = np.where(p[:, 2] > 1e-9, p[:, 2], np.nan)
    u, v = camera.fx * p[:, 0] / z + camera.cx, camera.fy * p[:, 1] / z + camera.cy
    with np.errstate(invalid="ignore"):
        return (u >= -0.5) & (u <= camera.width - 0.5) & (v >= -0.5) & (v <= camera.height - 0.5)


def working_area(T_world_cam: np.ndarray, camera: Camera, centres: np.ndarray, margin: float
                 ) -> tuple[tuple[float, float, float, float], float]:  # fmt: skip
    """The rectangle [x0, y0, x1, y1] (world metres) of the bin centres ``centres`` (N, 2) grown by
    ``margin``, shrunk where needed so that the camera sees its corners (the generator's rule); the area
    and the margin used."""
    lo, hi = centres.min(0), centres.max(0)
    for step in range(41):  # the margin in steps of 2.5 % down to none
        m = margin * (1.0 - step / 40.0)
        area = (float(lo[0] - m), float(lo[1] - m), float(hi[0] + m), float(hi[1] + m))
        corners = np.array([[x, y, 0.0] for x in (area[0], area[2]) for y in (area[1], area[3])])
        if in_view(T_world_cam, camera, corners).all():
            return area, m
    return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])), 0.0


def crop_side(sides: Sequence[float], thickness: float) -> float:
    """``data.roi=auto:S``: 1.1 x the bin's outer diagonal (in any yaw, with the bin finder's error to
    spare), rounded up to 5 cm."""
    diagonal = math.hypot(sides[0] + 2 * thickness, sides[1] + 2 * thickness)
    return math.ceil(round(1.1 * diagonal * 20, 9)) / 20
