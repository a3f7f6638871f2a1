"""A camera turned off vertical about the bin floor's centre (``scene.camera_tilt_deg``): its pose, the clip
planes its image needs, the largest tilt it takes; and the rigid transforms the scene's frames are made of
(:mod:`opnet.synthesis.layout` uses them, and re-exports them)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from opnet.geometry.camera import Camera


def homogeneous(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(3, 3) rotation and (3,) translation -> (4, 4) float64 rigid transform."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def inverse_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of a (4, 4) rigid transform (exact for the rotation part: R^T)."""
    R, t = T[:3, :3], T[:3, 3]
    return homogeneous(R.T, -R.T @ t)


def rotation_about(axis: np.ndarray, angle: float) -> np.ndarray:
    """(3, 3) rotation of ``angle`` radians about the unit vector ``axis`` (Rodrigues)."""
    x, y, z = np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


def tilted(T_world_cam: np.ndarray, tilt_deg: float, azimuth_deg: float) -> np.ndarray:
    """A downward camera pose turned about the bin floor's centre (the world origin) by ``tilt_deg``
    towards the horizontal direction ``azimuth_deg``: it keeps looking at the same point of the
    floor from the same distance."""
    phi = math.radians(azimuth_deg)
    axis = np.array([-math.sin(phi), math.cos(phi), 0.0])  # z x (cos phi, sin phi, 0)
    return homogeneous(rotation_about(axis, math.radians(tilt_deg)), np.zeros(3)) @ T_world_cam


def tilted_clip(camera: Camera, T_world_cam: np.ndarray, bin_geom: Any, diameter: float,
                cfg: Any) -> tuple[float, float]:  # fmt: skip
    """Clip planes of a tilted camera: from the nearest bin corner a part's diameter above the rim
    to the farthest point of the ground the image corners see (2 % and the jitters to spare)."""
    R, C = T_world_cam[:3, :3], T_world_cam[:3, 3]
    hx, hy = (side / 2.0 + bin_geom.thickness for side in bin_geom.sides)
    top = bin_geom.wall_height + diameter + bin_geom.outer * math.sin(math.radians(cfg.bin_tilt_deg))
    if cfg.bin_area is None:
        corners = np.array([[x, y, z] for x in (-hx, hx) for y in (-hy, hy) for z in (-bin_geom.thickness, top)])
    else:  # wherever the bin may stand: any yaw (a circle of its half diagonal) about any point of the area
        x0, y0, x1, y1, reach = *cfg.bin_area, math.hypot(hx, hy)
        corners = np.array([[x + reach * math.cos(a), y + reach * math.sin(a), z] for x in (x0, x1) for y in (y0, y1)
                            for a in np.radians(np.arange(0.0, 360.0, 15.0)) for z in (-bin_geom.thickness, top)])
    depth = (corners - C) @ R[:, 2]
    down = _corners_down(camera, R)
    if (down >= -1e-6).any():
        untilted = tilted(T_world_cam, -cfg.camera_tilt_deg, cfg.camera_azimuth_deg)[:3, :3]
        raise ValueError(f"scene config: camera_tilt_deg={cfg.camera_tilt_deg:g}: the image's corner reaches above the "
                         f"horizon; this camera takes a tilt below {_largest_tilt(camera, untilted, cfg):.1f} degrees "
                         f"towards camera_azimuth_deg={cfg.camera_azimuth_deg:g} (its corners see further off its axis "
                         "than half its field of view); tilt less or narrow the field of view")  # fmt: skip
    ground = (C[2] + bin_geom.thickness) / -down  # camera z where each corner ray meets the ground
    tilt = math.tan(math.radians(cfg.camera_jitter_deg))
    near = max(float(depth.min()) - cfg.camera_jitter_m, 0.1 * float(np.linalg.norm(C)))
    far = float(max(ground.max(), depth.max())) * (1.0 + tilt) * 1.02 + cfg.camera_jitter_m
    return near, far


def _corners_down(camera: Camera, R: np.ndarray) -> np.ndarray:
    """The world z of the rays through the image's four corners (camera z = 1) of a camera turned by ``R``."""
    rays = np.array([[(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0]
                     for u in (-0.5, camera.width - 0.5) for v in (-0.5, camera.height - 0.5)])  # fmt: skip
    return (rays @ R.T)[:, 2]


def _largest_tilt(camera: Camera, R_down: np.ndarray, cfg: Any) -> float:
    """The largest tilt (degrees, towards ``camera_azimuth_deg``) of the downward camera ``R_down`` whose image
    corners all stay below the horizon."""
    low, high = 0.0, 90.0
    pose = homogeneous(R_down, np.zeros(3))
    for _ in range(40):  # bisection to 1e-10 degrees
        mid = (low + high) / 2.0
        if (_corners_down(camera, tilted(pose, mid, cfg.camera_azimuth_deg)[:3, :3]) < -1e-6).all():
            low = mid
        else:
            high = mid
    return low
