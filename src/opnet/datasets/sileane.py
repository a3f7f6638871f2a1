"""Siléane dataset layout: reading scenes (docs/formats.md#siléane-layout).

```
<root>/camera_params.txt        one camera for the whole folder (pose: camera -> world)
<root>/depth/<scene>.PNG        uint16, clip-normalized, 65535 = no depth (also .png)
<root>/segmentation/<scene>.PNG uint16 instance image, value = GT segmentation_id (also .png)
<root>/gt/<scene>.json          ground truth, world frame
```
Records are in the internal camera frame (Siléane's camera already is the OpenCV one, with no
half-pixel shift: ``x = (u - cu) z / fu``); the ground truth is moved there from the world frame
with the camera pose. Folders holding only ``gt/`` (like the official evaluation sample) still give
their ground truth through :meth:`SileaneDataset.read_ground_truth`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import numpy as np

from opnet.datasets.png import decode_depth, read_png
from opnet.datasets.record import SceneRecord
from opnet.datasets.sileane_json import read_gt_json, scene_files
from opnet.fileio.files import read_text
from opnet.geometry.camera import Camera
from opnet.geometry.frames import world_to_camera
from opnet.geometry.pose_numpy import quaternion_to_matrix
from opnet.metrics.records import GroundTruthSet

CAMERA_FILE = "camera_params.txt"
_CAMERA_KEYS = {
    "width": 1, "height": 1, "fu": 1, "fv": 1, "cu": 1, "cv": 1,
    "clip_start": 1, "clip_end": 1, "location": 3, "rotation": 4,
}  # fmt: skip


def read_camera_params(path: str | Path) -> tuple[Camera, np.ndarray, np.ndarray]:
    """Read ``camera_params.txt``: ``key<TAB or spaces>value(s)`` lines, ``#`` comments.

    Args:
        path: the file, or the dataset folder holding it.
    Returns:
        camera (internal OpenCV frame); R_world_cam (3, 3) float64 and t_world_cam (3,) float64
        metres, the camera pose: ``X_world = R_world_cam @ X_cam + t_world_cam``.
    Raises:
        FileNotFoundError: no such file.
        ValueError: a missing, repeated or unparsable key (the message names file, key and line).
    """
    path = Path(path)
    if path.is_dir():
        path = path / CAMERA_FILE
    lines = read_text(path).splitlines()
    values: dict[str, list[float]] = {}
    for number, line in enumerate(lines, start=1):
        tokens = line.split("#", 1)[0].split()
        if not tokens or tokens[0] not in _CAMERA_KEYS:
            continue
        key, size = tokens[0], _CAMERA_KEYS[tokens[0]]
        try:
            numbers = [float(x) for x in tokens[1:]]
        except ValueError:
            numbers = []
        if len(numbers) != size or not all(math.isfinite(x) for x in numbers) or key in values:
            raise ValueError(
                f"{path}: line {number}: {key!r} needs {size} number(s) given once, "
                f"got {tokens[1:]}"
            )
        values[key] = numbers
    missing = [k for k in _CAMERA_KEYS if k not in values]
    if missing:
        raise ValueError(f"{path}: missing key(s) {missing}")
    q = np.array(values["rotation"])
    if np.linalg.norm(q) < 1e-6:
        raise ValueError(
            f"{path}: 'rotation' must be a unit quaternion (w x y z), got {values['rotation']}"
        )
    v = {k: x[0] for k, x in values.items() if len(x) == 1}
    if not (v["width"].is_integer() and v["height"].is_integer()):
        raise ValueError(
            f"{path}: 'width' and 'height' must be integers, got {v['width']}, {v['height']}"
        )
    try:
        camera = Camera(
            v["fu"],
            v["fv"],
            v["cu"],
            v["cv"],
            int(v["width"]),
            int(v["height"]),
            v["clip_start"],
            v["clip_end"],
        )
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    camera.check_plausible(str(path))
    return camera, quaternion_to_matrix(q), np.array(values["location"])


class SileaneDataset:
    """The scenes of a Siléane dataset folder: the basenames of ``gt/*.json``, sorted.

    Args:
        root: the dataset folder (e.g. ``bunny/``); the records' ``object_name`` is its name.
    Attributes:
        camera, R_world_cam, t_world_cam: from ``camera_params.txt``; None without that file.
    """

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self._gt_files = scene_files(self.root / "gt")
        self.object_name = self.root.resolve().name
        self.camera: Camera | None = None
        self.R_world_cam: np.ndarray | None = None
        self.t_world_cam: np.ndarray | None = None
        if (self.root / CAMERA_FILE).exists():
            self.camera, self.R_world_cam, self.t_world_cam = read_camera_params(
                self.root / CAMERA_FILE
            )

    def scenes(self) -> list[str]:
        """Scene names (``gt/<scene>.json`` basenames), sorted."""
        return list(self._gt_files)

    def __len__(self) -> int:
        return len(self._gt_files)

    def __getitem__(self, i: int) -> SceneRecord:
        return self.read(self.scenes()[i])

    def scene_name(self, i: int) -> str:
        return self.scenes()[i]

    def source_files(self) -> list[str]:
        """Every file the scenes are read from, present or not, relative to ``root``:
        ``camera_params.txt``, then each scene's ground truth JSON and its depth and segmentation
        PNGs under both suffixes."""
        files = [CAMERA_FILE]
        for scene, gt in self._gt_files.items():
            files += [f"gt/{gt.name}", f"depth/{scene}.PNG", f"depth/{scene}.png",
                      f"segmentation/{scene}.PNG", f"segmentation/{scene}.png"]
        return files

    def read_ground_truth(
        self, scene: str, frame: Literal["world", "camera"] = "world"
    ) -> GroundTruthSet:
        """Ground truth of ``scene`` from its JSON alone, in the world (as stored) or camera frame.

        Raises:
            KeyError: unknown scene.
            FileNotFoundError: ``frame="camera"`` without ``camera_params.txt``.
        """
        if scene not in self._gt_files:
            raise KeyError(f"{self.root / 'gt'}: no ground truth for scene {scene!r}")
        gt = read_gt_json(self._gt_files[scene])
        if frame == "world":
            return gt
        if frame != "camera":
            raise ValueError(f"frame must be 'world' or 'camera', got {frame!r}")
        R_wc, t_wc = self._camera_pose()
        R, t = world_to_camera(gt.R, gt.t, R_wc, t_wc)
        return GroundTruthSet(R, t, gt.occlusion_rate, gt.segmentation_id)

    def _camera_pose(self) -> tuple[np.ndarray, np.ndarray]:
        if self.R_world_cam is None or self.t_world_cam is None:
            raise FileNotFoundError(
                f"{self.root / CAMERA_FILE}: file not found (needed for camera-frame data)"
            )
        return self.R_world_cam, self.t_world_cam

    def read(self, scene: str) -> SceneRecord:
        """The record of ``scene``: depth, segmentation (if present) and camera-frame ground truth.

        The segmentation keeps each GT instance's ``segmentation_id``, every other pixel is 0.

        Raises:
            FileNotFoundError: no ``camera_params.txt`` or no depth image.
            ValueError: malformed files.
        """
        gt = self.read_ground_truth(scene, frame="camera")
        camera = self.camera
        assert camera is not None  # _camera_pose raised otherwise
        shape = (camera.height, camera.width)
        depth_png = self._image("depth", scene)
        if depth_png is None:
            raise FileNotFoundError(
                f"{self.root / 'depth' / scene}.PNG: file not found (also tried .png)"
            )
        depth = decode_depth(
            read_png(depth_png, np.uint16, shape), camera.clip_start, camera.clip_end
        )
        segmentation = None
        seg_png = self._image("segmentation", scene)
        if seg_png is not None:
            raw = read_png(seg_png, np.uint16, shape).astype(np.int32)
            segmentation = np.where(np.isin(raw, gt.segmentation_id), raw, 0).astype(np.int32)
        return SceneRecord(
            name=scene,
            depth=depth,
            camera=camera,
            segmentation=segmentation,
            R_cam_obj=gt.R,
            t_cam_obj=gt.t,
            visibility=1.0 - gt.occlusion_rate,
            instance_id=gt.segmentation_id,
            object_name=self.object_name,
        )

    def _image(self, folder: str, scene: str) -> Path | None:
        for suffix in (".PNG", ".png"):
            path = self.root / folder / f"{scene}{suffix}"
            if path.is_file():
                return path
        return None
