"""The scene record: one depth image with its camera and ground truth, whatever the source.

Every reader (IPA, Siléane) and the synthetic generator produce this, in the internal OpenCV
camera frame and metres (docs/formats.md#frames), so everything downstream has one code path.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from opnet.geometry.camera import Camera


@dataclass
class SceneRecord:
    """One scene.

    Attributes:
        name: unique scene name within its dataset, e.g. "cycle_0003_012" or "bunny_3_070".
        depth: (H, W) float32 z-depth in metres, camera frame; NaN where depth is missing.
        camera: intrinsics and clip planes of ``depth``.
        segmentation: (H, W) int32 instance ids (0 = background / bin), or None.
        R_cam_obj: (N, 3, 3) float64 object-to-camera rotations.
        t_cam_obj: (N, 3) float64 object origins in the camera frame, metres.
        visibility: (N,) float64 visible fraction in [0, 1] (1 - occlusion rate).
        instance_id: (N,) int64 value of each object in ``segmentation``.
        object_name: name of the object class (one class per scene).
    """

    name: str
    depth: np.ndarray
    camera: Camera
    segmentation: np.ndarray | None = None
    R_cam_obj: np.ndarray = field(default_factory=lambda: np.zeros((0, 3, 3)))
    t_cam_obj: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    visibility: np.ndarray = field(default_factory=lambda: np.zeros(0))
    instance_id: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    object_name: str = ""

    def __post_init__(self) -> None:
        n = len(self.t_cam_obj)
        shapes = {
            "R_cam_obj": (self.R_cam_obj.shape, (n, 3, 3)),
            "t_cam_obj": (self.t_cam_obj.shape, (n, 3)),
            "visibility": (self.visibility.shape, (n,)),
            "instance_id": (self.instance_id.shape, (n,)),
            "depth": (self.depth.shape, (self.camera.height, self.camera.width)),
        }
        for key, (got, want) in shapes.items():
            if tuple(got) != want:
                raise ValueError(f"scene {self.name!r}: {key} has shape {tuple(got)}, expected {want}")
        if self.segmentation is not None and self.segmentation.shape != self.depth.shape:
            raise ValueError(
                f"scene {self.name!r}: segmentation shape {self.segmentation.shape} != depth shape {self.depth.shape}"
            )

    @property
    def num_objects(self) -> int:
        return len(self.t_cam_obj)

    @property
    def occlusion_rate(self) -> np.ndarray:
        """(N,) 1 - visibility, clipped to [0, 1] (the Siléane ground-truth field)."""
        return 1.0 - np.clip(self.visibility, 0.0, 1.0)
