"""One geometry module: rotations, Euler conventions, camera projection, frames, symmetry and the
symmetry-aware pose distance. The metric, the loss, the clustering and the parameterizations all
call it (architecture.md, central decision 5)."""

from opnet.geometry.camera import Camera
from opnet.geometry.distance import PoseSpace
from opnet.geometry.frames import camera_to_ipa, camera_to_world, ipa_to_camera, world_to_camera
from opnet.geometry.rotations import (
    DEFAULT_EULER,
    axis_angle_rotation,
    euler_to_matrix,
    matrix_to_euler,
    matrix_to_quaternion,
    orthonormality_error,
    project_to_so3,
    quaternion_to_matrix,
    rotation_angle,
)
from opnet.geometry.symmetry import Symmetry

__all__ = [
    "DEFAULT_EULER",
    "Camera",
    "PoseSpace",
    "Symmetry",
    "axis_angle_rotation",
    "camera_to_ipa",
    "camera_to_world",
    "euler_to_matrix",
    "ipa_to_camera",
    "matrix_to_euler",
    "matrix_to_quaternion",
    "orthonormality_error",
    "project_to_so3",
    "quaternion_to_matrix",
    "rotation_angle",
    "world_to_camera",
]
