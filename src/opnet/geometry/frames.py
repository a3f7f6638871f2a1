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


#: the key of a camera's pose in the robot's base frame (camera YAML, cell file, checkpoint, ONNX metadata)
BASE_POSE_KEY = "T_base_cam"
#: a camera this far from the base (metres) is a calibration in millimetres
MAX_BASE_DISTANCE_M = 20.0


def rigid_transform(value: object, source: str, key: str = BASE_POSE_KEY) -> np.ndarray:
    """``value`` (4 x 4 numbers, or 16 in a row; metres) as a float64 rigid transform: a rotation
    (orthonormal, determinant +1), a translation and the last row 0 0 0 1.

    Raises:
        ValueError: one line, ``<source>: <key> ...``, saying what is wrong.
    """
    try:
        T = np.array(value, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{source}: {key} is not a 4 x 4 list of numbers") from None
    if T.shape == (16,):
        T = T.reshape(4, 4)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise ValueError(f"{source}: {key} must be 4 x 4 finite numbers, got shape {T.shape}")
    R = T[:3, :3]
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
        raise ValueError(f"{source}: {key}'s last row is {T[3].tolist()}, expected [0, 0, 0, 1] (not a rigid transform)")
    error = float(np.abs(R.T @ R - np.eye(3)).max())
    if error > 1e-3 or np.linalg.det(R) < 0:
        what = "a reflection (determinant -1)" if error <= 1e-3 else f"R^T R differs from the identity by {error:.2g}"
        raise ValueError(f"{source}: {key}'s rotation is no rotation ({what}): not a rigid transform")
    if np.linalg.norm(T[:3, 3]) > MAX_BASE_DISTANCE_M:
        raise ValueError(f"{source}: {key} puts the camera {np.linalg.norm(T[:3, 3]):.4g} m from the base; "
                         "the translation is in metres (millimetres? divide by 1000)")
    return T


def camera_to_base(R_cam_obj: np.ndarray, t_cam_obj: np.ndarray, T_base_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame object poses (..., 3, 3), (..., 3) in the robot's base frame, given ``T_base_cam``
    (4 x 4, camera to base): ``X_base = T_base_cam X_cam``."""
    T = np.asarray(T_base_cam, dtype=np.float64)
    return camera_to_world(np.asarray(R_cam_obj, np.float64), np.asarray(t_cam_obj, np.float64), T[:3, :3], T[:3, 3])
