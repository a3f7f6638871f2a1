"""Conversions between the internal OpenCV camera frame and the datasets' frames.

Convert at the reader/writer boundary and nowhere else (docs/formats.md#frames):
- Fraunhofer IPA: poses in a camera frame with x and y negated (docs/formats.md#fraunhofer-ipa-layout).
- Siléane: poses in a world frame; the camera pose ``(R_world_cam, t_world_cam)`` maps camera to
  world coordinates, ``X_w = R_world_cam X_c + t_world_cam`` (docs/formats.md#siléane-layout).
"""

from __future__ import annotations

import numpy as np

# x_ipa = FLIP_XY @ x_cv (a half-turn about z, so it is a proper rotation and its own inverse)
FLIP_XY = np.diag([-1.0, -1.0, 1.0])


def ipa_to_camera(R_ipa_obj: np.ndarray, t_ipa_obj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """IPA-frame poses (..., 3, 3), (..., 3) to the internal camera frame."""
    return FLIP_XY @ R_ipa_obj, t_ipa_obj @ FLIP_XY


def camera_to_ipa(R_cam_obj: np.ndarray, t_cam_obj: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Internal camera-frame poses (..., 3, 3), (..., 3) to the IPA frame."""
    return FLIP_XY @ R_cam_obj, t_cam_obj @ FLIP_XY


def world_to_camera(
    R_world_obj: np.ndarray, t_world_obj: np.ndarray, R_world_cam: np.ndarray, t_world_cam: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """World-frame object poses (..., 3, 3), (..., 3) to camera-frame poses, given the camera pose."""
    R_cam_world = R_world_cam.T
    return R_cam_world @ R_world_obj, (t_world_obj - t_world_cam) @ R_cam_world.T


def camera_to_world(
    R_cam_obj: np.ndarray, t_cam_obj: np.ndarray, R_world_cam: np.ndarray, t_world_cam: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame object poses (..., 3, 3), (..., 3) to world-frame poses, given the camera pose."""
    return R_world_cam @ R_cam_obj, t_cam_obj @ R_world_cam.T + t_world_cam
