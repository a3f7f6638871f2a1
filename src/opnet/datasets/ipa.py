"""Fraunhofer IPA Bin-Picking layout: reading and writing scenes (docs/formats.md#fraunhofer-ipa-layout).

```
<root>/parameter.json
<root>/gt/cycle_XXXX/NNN.csv                         written last: a complete CSV = a complete scene
<root>/p_depth/cycle_XXXX/NNN_depth_uint16.png       uint16, clip-normalized, 65535 = no depth
<root>/p_segmentation/cycle_XXXX/NNN_segmentation.png  uint8, k = CSV id k, 0 = bin, 255 = nothing
```
NNN is the number of objects in the scene (000 = the empty bin). Real and synthetic data go
through the same reader (docs/formats.md#fraunhofer-ipa-layout). Records are in the internal camera
frame; the IPA frame (x and y negated) exists only inside :mod:`opnet.datasets.ipa_csv`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from opnet.datasets.ipa_csv import IPAGroundTruth, read_ipa_csv, write_ipa_csv
from opnet.datasets.ipa_params import (
    PARAMETER_FILE,
    IPAParameters,
    read_parameters,
    write_parameters,
)
from opnet.datasets.png import decode_depth, encode_depth, read_png, write_png
from opnet.datasets.record import SceneRecord
from opnet.geometry.camera import Camera
from opnet.metrics.records import GroundTruthSet

__all__ = [
    "IPADataset",
    "IPAParameters",
    "read_ipa_scene",
    "read_parameters",
    "write_ipa_scene",
    "write_parameters",
]

SEG_BACKGROUND = 255
MAX_INSTANCE_ID = 254  # uint8 segmentation, 0 = bin and 255 = background are taken


def scene_files(cycle: int, n: int) -> dict[str, str]:
    """The files of scene ``n`` of ``cycle`` relative to the dataset folder, ``/``-separated:
    keys "csv", "depth", "segmentation"."""
    folder = f"cycle_{cycle:04d}"
    return {
        "csv": f"gt/{folder}/{n:03d}.csv",
        "depth": f"p_depth/{folder}/{n:03d}_depth_uint16.png",
        "segmentation": f"p_segmentation/{folder}/{n:03d}_segmentation.png",
    }


def scene_paths(root: str | Path, cycle: int, n: int) -> dict[str, Path]:
    """The files of scene ``n`` of ``cycle``: keys "csv", "depth", "segmentation"."""
    root = Path(root)
    return {key: root / name for key, name in scene_files(cycle, n).items()}


def write_ipa_scene(
    root: Path,
    cycle: int,
    record: SceneRecord,
    bin_pose: tuple[np.ndarray, np.ndarray],
    object_class: int = 1,
) -> None:
    """Write one scene: depth PNG, segmentation PNG, then the CSV, each atomically.

    The scene number NNN is ``record.num_objects``. The CSV's id column is ``record.instance_id``
    (must be 1..254), both visibility columns are ``record.visibility``. In the segmentation PNG,
    record value 0 ("no object") becomes 255; the bin is not rendered separately, so it is 255 too
    (IPA data uses 0 for the bin). Same inputs give the same bytes.

    Args:
        root: dataset folder (created if needed).
        cycle: cycle number (folder ``cycle_XXXX``).
        record: the scene, internal camera frame.
        bin_pose: (R_cam_bin (3, 3), t_cam_bin (3,) metres), internal camera frame.
        object_class: value of the CSV ``class`` column for every object.
    Raises:
        ValueError: bad instance ids or segmentation values, or ``record.camera`` differs from the
            folder's existing ``parameter.json``.
    """
    ids = np.asarray(record.instance_id, dtype=np.int64)
    if len(ids) and (
        ids.min() < 1 or ids.max() > MAX_INSTANCE_ID or len(np.unique(ids)) != len(ids)
    ):
        raise ValueError(
            f"scene {record.name!r}: instance ids must be unique and in 1..{MAX_INSTANCE_ID} "
            f"(uint8 IPA segmentation), got {ids.tolist()}"
        )
    _check_camera(Path(root), record.camera)
    paths = scene_paths(root, cycle, record.num_objects)
    cam = record.camera
    write_png(paths["depth"], encode_depth(record.depth, cam.clip_start, cam.clip_end))
    write_png(paths["segmentation"], _segmentation_png(record, ids))
    gt = IPAGroundTruth(
        instance_id=ids,
        object_class=np.full(len(ids), object_class, dtype=np.int64),
        R_cam_obj=record.R_cam_obj,
        t_cam_obj=record.t_cam_obj,
        visibility_o=record.visibility,
        visibility_p=record.visibility,
        R_cam_bin=np.asarray(bin_pose[0], dtype=np.float64),
        t_cam_bin=np.asarray(bin_pose[1], dtype=np.float64),
    )
    write_ipa_csv(paths["csv"], gt)


def _segmentation_png(record: SceneRecord, ids: np.ndarray) -> np.ndarray:
    shape = (record.camera.height, record.camera.width)
    if record.segmentation is None:
        return np.full(shape, SEG_BACKGROUND, dtype=np.uint8)
    seg = np.asarray(record.segmentation)
    unknown = np.setdiff1d(np.unique(seg), np.concatenate([[0], ids]))
    if len(unknown):
        raise ValueError(
            f"scene {record.name!r}: segmentation values {unknown[:10].tolist()} "
            f"are neither 0 nor an instance id"
        )
    return np.where(seg == 0, SEG_BACKGROUND, seg).astype(np.uint8)


def _check_camera(root: Path, camera: Camera) -> None:
    if not (root / PARAMETER_FILE).exists():
        return
    expected = read_parameters(root).camera()
    same = (camera.width, camera.height) == (expected.width, expected.height) and all(
        math.isclose(getattr(camera, k), getattr(expected, k), rel_tol=1e-9, abs_tol=1e-9)
        for k in ("fx", "fy", "cx", "cy", "clip_start", "clip_end")
    )
    if not same:
        raise ValueError(
            f"{root / PARAMETER_FILE}: describes {expected}, "
            f"but the scene was rendered with {camera}"
        )


def read_ipa_scene(
    root: str | Path, cycle: int, n: int, params: IPAParameters, object_name: str | None = None
) -> SceneRecord:
    """Read scene ``n`` of ``cycle`` into a record (internal camera frame, metres).

    The record's segmentation holds the CSV id k for object pixels and 0 for the bin, the background
    and any value that is no object's id; ``instance_id`` are the CSV ids, ``visibility`` the
    perspective score ``visibility_score_p`` (unclipped). A missing segmentation PNG gives None.

    Raises:
        FileNotFoundError: no CSV or no depth PNG.
        ValueError: a malformed file (the message names it).
    """
    paths = scene_paths(root, cycle, n)
    camera = params.camera()
    gt = read_ipa_csv(paths["csv"])
    shape = (camera.height, camera.width)
    depth = decode_depth(
        read_png(paths["depth"], np.uint16, shape), camera.clip_start, camera.clip_end
    )
    segmentation = None
    if paths["segmentation"].exists():
        lut = np.zeros(256, dtype=np.int32)
        ids = gt.instance_id[gt.instance_id <= MAX_INSTANCE_ID]
        lut[ids] = ids
        segmentation = lut[read_png(paths["segmentation"], np.uint8, shape)]
    return SceneRecord(
        name=f"cycle_{cycle:04d}_{n:03d}",
        depth=depth,
        camera=camera,
        segmentation=segmentation,
        R_cam_obj=gt.R_cam_obj,
        t_cam_obj=gt.t_cam_obj,
        visibility=gt.visibility_p,
        instance_id=gt.instance_id,
        object_name=object_name if object_name is not None else default_object_name(root),
    )


def default_object_name(root: str | Path) -> str:
    """The object of a dataset folder from its name: ``SileaneBunny_part_2`` -> ``SileaneBunny``."""
    return re.sub(r"_part_\d+$", "", Path(root).resolve().name)


class IPADataset:
    """The scenes of an IPA dataset folder, in (cycle, NNN) order.

    Args:
        root: the folder holding ``parameter.json`` and ``gt/``.
        cycles: keep only these cycles (any iterable of ints, e.g. ``range(250, 500)``).
        min_objects: keep only scenes with at least this many objects.
        include_empty: keep scene 000 (the empty bin) of each cycle.
        object_name: the records' ``object_name``; default from the folder name.
    """

    def __init__(
        self,
        root: str | Path,
        cycles: Iterable[int] | None = None,
        min_objects: int = 0,
        include_empty: bool = True,
        object_name: str | None = None,
    ) -> None:
        self.root = Path(root)
        self.params = read_parameters(self.root)
        self.camera = self.params.camera()
        self.object_name = (
            object_name if object_name is not None else default_object_name(self.root)
        )
        wanted = None if cycles is None else set(cycles)
        self._scenes = [
            (c, n)
            for c, n in _find_scenes(self.root)
            if (wanted is None or c in wanted) and n >= min_objects and (include_empty or n > 0)
        ]

    def scenes(self) -> list[tuple[int, int]]:
        """(cycle, NNN) of every selected scene whose CSV exists, sorted."""
        return list(self._scenes)

    def cycles(self) -> list[int]:
        """The cycles that have at least one selected scene, sorted."""
        return sorted({c for c, _ in self._scenes})

    def __len__(self) -> int:
        return len(self._scenes)

    def __getitem__(self, i: int) -> SceneRecord:
        cycle, n = self._scenes[i]
        return self.read(cycle, n)

    def read(self, cycle: int, n: int) -> SceneRecord:
        """The record of scene ``n`` of ``cycle`` (need not be among the selected scenes)."""
        return read_ipa_scene(self.root, cycle, n, self.params, self.object_name)

    def scene_name(self, i: int) -> str:
        cycle, n = self._scenes[i]
        return f"cycle_{cycle:04d}_{n:03d}"

    def source_files(self) -> list[str]:
        """Every file the selected scenes are read from, present or not, relative to ``root``:
        ``parameter.json``, then each scene's CSV, depth and segmentation PNGs (what a cache of
        the records depends on; strings, as building paths would cost more than their ``stat``)."""
        files = [PARAMETER_FILE]
        for cycle, n in self._scenes:
            files += scene_files(cycle, n).values()
        return files

    def read_ground_truth(self, cycle: int, n: int) -> GroundTruthSet:
        """Ground truth of scene ``n`` of ``cycle`` from its CSV alone, internal camera frame.

        ``occlusion_rate = 1 - clip(visibility_score_p, 0, 1)``, ``segmentation_id`` = CSV id.
        """
        gt = read_ipa_csv(scene_paths(self.root, cycle, n)["csv"])
        return GroundTruthSet(
            gt.R_cam_obj, gt.t_cam_obj, 1.0 - np.clip(gt.visibility_p, 0.0, 1.0), gt.instance_id
        )


def _find_scenes(root: Path) -> list[tuple[int, int]]:
    gt_dir = root / "gt"
    if not gt_dir.is_dir():
        raise FileNotFoundError(
            f"{gt_dir}: folder not found (an IPA dataset folder needs gt/cycle_XXXX/NNN.csv)"
        )
    found = []
    for cycle_dir in gt_dir.iterdir():
        m = re.fullmatch(r"cycle_(\d+)", cycle_dir.name)
        if m and cycle_dir.is_dir():
            found += [
                (int(m.group(1)), int(f.stem))
                for f in cycle_dir.iterdir()
                if re.fullmatch(r"\d+\.csv", f.name) and f.is_file()
            ]
    return sorted(found)
