"""The camera's pose relative to the bin, measured from ground truth of parts lying flat.

A real frame's BOP ``scene_camera.json`` often gives the identity for ``cam_R_w2c`` (the world is
the camera), so the tilt of the camera over the bin is not written anywhere. Parts that lie flat on
the bin floor tell it: their thin axis is the floor's normal. From the ground truth of a split
(poses in the camera frame), this module estimates the generator's settings of
:mod:`opnet.synthesis.layout` that put a camera in the same place:

- the floor normal ``n`` (pointing at the camera): the mean of the parts' thin axes (each turned to
  face the camera), then ``camera_tilt_deg = acos(-n_z)``;
- ``camera_azimuth_deg = atan2(n_y, -n_x)``: the generator's camera, tilted towards the azimuth,
  sees the floor normal as ``(-cos az sin tilt, sin az sin tilt, -cos tilt)``, so the image of a
  generated scene is oriented as the real one;
- ``camera_height``: the distance from the camera to the floor plane along the optical axis ray
  through the parts' centre, i.e. the distance at which the generator places it
  (median of the parts' distances to the plane, plus half their thickness).

    python -m opnet.synthesis.camera_pose ../shared/data/ipd_real_obj18/test --object-id 18

(where the split's ``scene_camera.json`` gives ``cam_R_w2c`` / ``cam_t_w2c`` of a world frame with z up
and the floor at z = 0, the settings they imply are printed too: :func:`pose_from_w2c`) prints the scene overrides (``scene.camera_tilt_deg=... scene.camera_azimuth_deg=...
scene.camera_height=...``) and the spread over the parts (a part that does not lie flat shows up as
a large deviation).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class CameraPose:
    """The generator's camera settings of one rig, and how well the parts agree (degrees)."""

    camera_height: float
    camera_tilt_deg: float
    camera_azimuth_deg: float
    parts: int
    normal_spread_deg: float

    def overrides(self) -> str:
        return (f"scene.camera_height={self.camera_height:.4f} scene.camera_tilt_deg={self.camera_tilt_deg:.2f} "
                f"scene.camera_azimuth_deg={self.camera_azimuth_deg:.2f}")


def thin_axis(vertices: np.ndarray) -> tuple[np.ndarray, float]:
    """The principal axis of least spread of a part's vertices (model frame), and its thickness
    (metres) along it."""
    centred = vertices - vertices.mean(0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    axis = vectors[:, 0]
    along = vertices @ axis
    return axis, float(np.ptp(along))


def estimate_pose(R_cam_obj: np.ndarray, t_cam_obj: np.ndarray, axis: np.ndarray, thickness: float) -> CameraPose:
    """The camera settings from the poses (N, 3, 3), (N, 3) of parts lying flat whose thin axis
    (model frame) is ``axis``."""
    if len(R_cam_obj) == 0:
        raise ValueError("camera pose: no parts to measure the floor from")
    normals = _normals(R_cam_obj, t_cam_obj, axis)
    n = normals.mean(0)
    n /= np.linalg.norm(n)
    spread = np.degrees(np.arccos(np.clip(normals @ n, -1, 1)))
    tilt = math.degrees(math.acos(float(np.clip(-n[2], -1, 1))))
    azimuth = math.degrees(math.atan2(n[1], -n[0])) if tilt > 1e-9 else 0.0
    # the floor plane: the parts' centres lie half a thickness above it; the generator's camera
    # sits at camera_height from the point of the floor its optical axis meets
    distance = float(np.median(-(t_cam_obj @ n))) + thickness / 2  # camera to the floor plane, along n
    height = distance / max(-n[2], 1e-9)  # along the optical axis to the floor
    return CameraPose(height, tilt, azimuth, len(R_cam_obj), float(spread.max()))


def pose_from_w2c(R_w2c: np.ndarray, t_w2c: np.ndarray) -> CameraPose:
    """The generator's camera settings from a camera pose in a world frame whose z axis is up and
    whose plane z = 0 is the bin floor (a BOP ``scene_camera.json`` entry's ``cam_R_w2c``, and
    ``cam_t_w2c`` in metres): the floor normal seen from the camera gives tilt and azimuth as
    :func:`estimate_pose` does, the camera centre's height over the floor the distance along the
    optical axis.

    Raises:
        ValueError: the camera is not above the floor looking down at it.
    """
    R = np.asarray(R_w2c, dtype=np.float64).reshape(3, 3)
    n = R[:, 2]  # world up, camera frame: it points at the camera (from the floor)
    centre = -R.T @ np.asarray(t_w2c, dtype=np.float64).reshape(3)
    if centre[2] <= 0 or n[2] >= 0:
        raise ValueError(f"camera pose: the camera at world height {centre[2]:.3f} m does not look down at the "
                         "floor z = 0 (cam_R_w2c / cam_t_w2c of a world frame with z up and the floor at z = 0)")
    tilt = math.degrees(math.acos(float(np.clip(-n[2], -1, 1))))
    azimuth = math.degrees(math.atan2(n[1], -n[0])) if tilt > 1e-9 else 0.0
    return CameraPose(float(centre[2] / -n[2]), tilt, azimuth, 0, 0.0)


def bop_camera_poses(split: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """The (R_w2c, t_w2c metres) of every image of a BOP split whose ``scene_camera.json`` gives a
    world frame other than the camera's own (``cam_R_w2c`` not the identity)."""
    import json

    poses = []
    for path in sorted(Path(split).glob("*/scene_camera.json")):
        for entry in json.loads(path.read_text()).values():
            if "cam_R_w2c" not in entry or "cam_t_w2c" not in entry:
                continue
            R = np.asarray(entry["cam_R_w2c"], dtype=np.float64).reshape(3, 3)
            if not np.allclose(R, np.eye(3)):
                poses.append((R, np.asarray(entry["cam_t_w2c"], dtype=np.float64).reshape(3) / 1000.0))
    return poses


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("split", type=Path, help="a BOP split folder (or any dataset opnet reads) with ground truth")
    parser.add_argument("--object-id", type=int, default=None, help="BOP obj_id of the parts")
    parser.add_argument("--object", default=None, help="object config name or built-in (default: the BOP models)")
    parser.add_argument("--max-tilt-spread", type=float, default=10.0,
                        help="parts whose thin axis deviates more (degrees) from the mean are left out")
    args = parser.parse_args(argv)
    try:
        from opnet.datasets import open_dataset

        dataset = open_dataset(args.split, object_id=args.object_id)
        if args.object:
            from opnet.objects.library import builtin_object

            obj = builtin_object(args.object)
        else:
            from opnet.objects.bop import bop_object
            from opnet.datasets.bop import models_dir_of

            obj = bop_object(models_dir_of(args.split), args.object_id or 1)
        axis, thickness = thin_axis(np.asarray(obj.mesh.vertices))
        R = np.concatenate([dataset[i].R_cam_obj for i in range(len(dataset))])
        t = np.concatenate([dataset[i].t_cam_obj for i in range(len(dataset))])
        pose = estimate_pose(R, t, axis, thickness)
        keep = np.degrees(np.arccos(np.clip(_normals(R, t, axis) @ _normal(pose), -1, 1))) <= args.max_tilt_spread
        if not keep.all():
            pose = estimate_pose(R[keep], t[keep], axis, thickness)
    except (ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{pose.parts} parts (of {len(R)}), thin-axis spread {pose.normal_spread_deg:.1f} deg, thickness "
          f"{1000 * thickness:.1f} mm\n{pose.overrides()}")
    written = bop_camera_poses(args.split) if args.split.is_dir() else []
    if written:  # the camera's own record of its pose over the floor, where the split has one
        try:
            print(f"from scene_camera.json (cam_R_w2c, cam_t_w2c of image 0; {len(written)} images): "
                  f"{pose_from_w2c(*written[0]).overrides()}")
        except ValueError as e:
            print(f"scene_camera.json: {e}")
    return 0


def _normals(R: np.ndarray, t: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The parts' thin axes (N, 3) in the camera frame, each turned to face the camera."""
    normals = np.einsum("nij,j->ni", R, axis)
    return normals * -np.sign(np.einsum("ni,ni->n", normals, t))[:, None]


def _normal(pose: CameraPose) -> np.ndarray:
    az, tilt = math.radians(pose.camera_azimuth_deg), math.radians(pose.camera_tilt_deg)
    return np.array([-math.cos(az) * math.sin(tilt), math.sin(az) * math.sin(tilt), -math.cos(tilt)])


if __name__ == "__main__":
    sys.exit(main())
