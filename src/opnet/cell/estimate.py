"""A cell from its frames: the bin found in each (:mod:`opnet.cell.bin_view`), put together in the generator's
terms (:mod:`opnet.cell.rig`) with the spread over the frames.

The camera stays while the bin may move between frames: the floor's plane is one (its normal the mean of
the frames', its distance their median), the camera's pose follows from it (or from a calibration,
``T_base_cam``, whose base z axis is the floor's normal: the frames then check it), and each frame's bin
stands somewhere on the floor in the generator's world frame. The working area holds where the bin stood
(plus a margin, shrunk where the camera would not see a corner; or given), the working volume holds the
bin anywhere in it in any yaw, from a margin above its rim to a margin below its floor.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from opnet.cell import rig
from opnet.cell.bin_view import BinView, find_bin
from opnet.cell.frames import Frame
from opnet.cell.planes import Plane, oriented
from opnet.geometry.camera import Camera

#: a calibration's base z axis and the frames' floor normal may differ this much (degrees)
EXTRINSICS_TOL_DEG = 3.0
#: below this tilt (degrees) the camera looks straight down and its azimuth means nothing (written as 0)
LEVEL_DEG = 0.1
#: the support counts as the ground under a raised bin from this drop below the floor on (metres)
RAISED_M = 0.02


@dataclass(frozen=True)
class Cell:
    """A cell measured from its frames.

    Attributes:
        camera: the camera (the camera file's), clip planes as given.
        views: the bin found in each frame.
        floor: the floor's plane over all frames (camera frame).
        T_world_cam: (4, 4) the generator's camera pose over that floor.
        placements: (N, 3) each frame's bin (x, y, yaw degrees) in the world frame.
        area, area_margin: the working area [x0, y0, x1, y1] and the margin it was grown by (None: given).
        clip: the working volume's (near, far) planes, metres; volume_margin its margin.
        extrinsics: the calibration's T_base_cam, or None; extrinsics_error_deg: the angle between its base
            z axis and the frames' floor normal.
    """

    camera: Camera
    views: tuple[BinView, ...]
    floor: Plane
    T_world_cam: np.ndarray
    placements: np.ndarray
    area: tuple[float, float, float, float]
    area_margin: float | None
    clip: tuple[float, float]
    volume_margin: float
    extrinsics: np.ndarray | None = None
    extrinsics_error_deg: float | None = None

    def _median(self, values: Sequence[float]) -> float:
        return float(np.median(values))

    @property
    def tilt_deg(self) -> float:
        return rig.tilt_azimuth(self.floor.normal)[0]

    @property
    def azimuth_deg(self) -> float:
        tilt, azimuth = rig.tilt_azimuth(self.floor.normal)
        return azimuth if tilt >= LEVEL_DEG else 0.0

    @property
    def camera_height(self) -> float:
        return rig.generator_height(self.floor, self.camera)

    @property
    def sides(self) -> tuple[float, float]:
        return self._median([v.sides[0] for v in self.views]), self._median([v.sides[1] for v in self.views])

    @property
    def wall_height(self) -> float:
        return self._median([v.wall_height for v in self.views])

    @property
    def thickness(self) -> float:
        return self._median([v.thickness for v in self.views])

    @property
    def support_drop(self) -> float | None:
        drops = [v.support_drop for v in self.views if v.support_drop is not None]
        return self._median(drops) if drops else None

    @property
    def clearance(self) -> float:
        """``bin_clearance``: how far the bin's underside stands above the plane it stands on (0: on it, or
        no support seen)."""
        drop = self.support_drop
        return 0.0 if drop is None or drop < self.thickness + RAISED_M else drop - self.thickness

    @property
    def crop_side(self) -> float:
        return rig.crop_side(self.sides, self.thickness)

    def per_frame(self) -> dict[str, np.ndarray]:
        """Each measured quantity per frame, for the spread: the camera's pose from each frame's own floor."""
        views = self.views
        pose = np.array([(*rig.tilt_azimuth(v.floor.normal), rig.generator_height(v.floor, self.camera))
                         for v in views])
        return {"camera_tilt_deg": pose[:, 0], "camera_azimuth_deg": pose[:, 1], "camera_height": pose[:, 2],
                "bin_inner": np.array([v.sides[0] for v in views]), "bin_inner_y": np.array([v.sides[1] for v in views]),
                "bin_wall_height": np.array([v.wall_height for v in views]),
                "bin_wall_thickness": np.array([v.thickness for v in views]),
                "support_drop": np.array([np.nan if v.support_drop is None else v.support_drop for v in views]),
                "x": self.placements[:, 0], "y": self.placements[:, 1], "yaw_deg": self.placements[:, 2]}


def read_extrinsics(path: Path) -> np.ndarray:
    """The camera-to-base transform of a YAML file (``T_base_cam: [[4 numbers] x 4]``, or the 4 x 4 list
    alone; metres): a rigid transform, or a ValueError naming the file and what is wrong."""
    from opnet.datasets.camera_file import read_yaml
    from opnet.geometry.frames import BASE_POSE_KEY, rigid_transform

    doc = read_yaml(path, "extrinsics YAML")
    if isinstance(doc, dict):
        if set(doc) != {BASE_POSE_KEY}:
            raise ValueError(f"{path}: expected one key, T_base_cam (a 4 x 4 camera-to-base transform), got "
                             f"{sorted(map(str, doc))}")
        doc = doc[BASE_POSE_KEY]
    return rigid_transform(doc, str(path))


def measure_cell(frames: list[Frame], camera: Camera, extrinsics: np.ndarray | None = None,
                 extrinsics_file: str = "--extrinsics", area: Sequence[float] | None = None,
                 area_margin: float = 0.1, volume_margin: float = 0.1,
                 views: Sequence[BinView] | None = None) -> Cell:  # fmt: skip
    """The cell of ``frames`` (module docstring); ``views``: their bins, when already found.

    Raises:
        BinNotFound: a frame without plane or bin (naming it).
        ValueError: a calibration the frames contradict (naming ``extrinsics_file``).
    """
    views = tuple(views) if views is not None else tuple(find_bin(f.depth, camera, f.name) for f in frames)
    normal = np.mean([v.floor.normal for v in views], axis=0)
    normal /= np.linalg.norm(normal)
    error = None
    if extrinsics is not None:
        up = extrinsics[:3, :3].T @ np.array([0.0, 0.0, 1.0])  # the base's z axis seen from the camera
        up = -up if up @ normal < 0 else up
        error = math.degrees(math.acos(float(np.clip(up @ normal, -1, 1))))
        if error > EXTRINSICS_TOL_DEG:
            raise ValueError(f"{extrinsics_file}: the base's z axis lies {error:.1f} degrees from the floor's normal the "
                             f"frames show (tolerance {EXTRINSICS_TOL_DEG:g}); a calibration of another camera or "
                             "mount, or a base that is not level with the floor")
        normal = up
    offset = float(np.median([-(normal @ v.centre) for v in views]))  # the floor through the bins' centres
    floor = oriented(normal, offset)
    T = rig.world_from_camera(floor, camera)
    placements = np.array([rig.bin_placement(T, v.centre, v.axis) for v in views])
    sides = (float(np.median([v.sides[0] for v in views])), float(np.median([v.sides[1] for v in views])))
    thickness = float(np.median([v.thickness for v in views]))
    wall = float(np.median([v.wall_height for v in views]))
    if area is None:
        area, margin = rig.working_area(T, camera, placements[:, :2], area_margin)
    else:
        area, margin = tuple(float(v) for v in area), None
    clip = rig.working_volume(T, area, sides, thickness, wall, volume_margin)
    return Cell(camera, views, floor, T, placements, area, margin, clip, volume_margin, extrinsics, error)


def spread_text(values: np.ndarray, digits: int) -> str:
    """``mean (min..max)`` of the frames' values, or the one value."""
    values = np.asarray(values, dtype=np.float64)
    values = values[np.isfinite(values)]
    if len(values) == 0:
        return "-"
    if len(values) == 1 or np.ptp(values) == 0:
        return f"{values[0]:.{digits}f}"
    return f"{values.mean():.{digits}f} ({values.min():.{digits}f}..{values.max():.{digits}f}, spread {np.ptp(values):.{digits}f})"
