"""One geometry module: rotations, Euler conventions, camera projection, frames, symmetry and the
symmetry-aware pose distance. The metric, the loss, the clustering and the parameterizations all
call it (docs/code.md).

Names are imported on first use (PEP 562), so that ``opnet.geometry.camera`` and the numpy-only
modules load without PyTorch (the ONNX deployment path, :mod:`opnet.deploy`).
"""

from __future__ import annotations

from opnet._lazy import lazy_exports

_WHERE = {
    "Camera": "camera",
    "PoseSpace": "distance",
    "camera_to_ipa": "frames",
    "camera_to_world": "frames",
    "ipa_to_camera": "frames",
    "world_to_camera": "frames",
    "DEFAULT_EULER": "rotations",
    "axis_angle_rotation": "rotations",
    "euler_to_matrix": "rotations",
    "matrix_to_euler": "rotations",
    "matrix_to_quaternion": "rotations",
    "orthonormality_error": "rotations",
    "project_to_so3": "rotations",
    "quaternion_to_matrix": "rotations",
    "rotation_angle": "rotations",
    "Symmetry": "symmetry",
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _WHERE)
