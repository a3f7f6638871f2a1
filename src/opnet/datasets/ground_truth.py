"""Scene records and dataset folders to evaluation ground truth (Siléane JSON, one file a scene).

The official converter's rules (docs/formats.md#siléane-layout): ``occlusion_rate = 1 - clip(visibility,
0, 1)`` and ``segmentation_id`` = the instance id. Poses stay in the internal camera frame: the
Brégier distance is invariant to a common change of frame, so camera-frame ground truth evaluates
camera-frame hypotheses exactly as the world-frame originals would evaluate world-frame ones.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Literal

from opnet.datasets.ipa import IPADataset
from opnet.datasets.record import SceneRecord
from opnet.datasets.sileane import SileaneDataset
from opnet.datasets.sileane_json import write_gt_json
from opnet.metrics.records import GroundTruthSet


def record_to_ground_truth(record: SceneRecord) -> GroundTruthSet:
    """The record's ground truth: camera-frame R (N, 3, 3), t (N, 3) metres, occlusion, ids."""
    return GroundTruthSet(
        record.R_cam_obj, record.t_cam_obj, record.occlusion_rate, record.instance_id
    )


def write_sileane_ground_truth(records: Iterable[SceneRecord], out_dir: Path) -> list[Path]:
    """Write ``<out_dir>/<record.name>.json`` per record (camera frame); returns the files written.

    Raises:
        ValueError: two records share a name (one file would overwrite the other).
    """
    return write_ground_truth_files(((r.name, record_to_ground_truth(r)) for r in records), out_dir)


def write_ground_truth_files(
    scenes: Iterable[tuple[str, GroundTruthSet]], out_dir: Path
) -> list[Path]:
    """Write ``<out_dir>/<name>.json`` per (name, ground truth) pair; returns the files written."""
    out_dir = Path(out_dir)
    written: dict[str, Path] = {}
    for name, gt in scenes:
        if name in written:
            raise ValueError(
                f"{out_dir}: two scenes are named {name!r}; scene names must be unique"
            )
        written[name] = out_dir / f"{name}.json"
        write_gt_json(written[name], gt)
    return list(written.values())


def dataset_ground_truth(
    dataset: IPADataset | SileaneDataset, frame: Literal["camera", "world"] = "camera"
) -> Iterator[tuple[str, GroundTruthSet]]:
    """(scene name, ground truth) for every scene, read from the annotation files alone (no images).

    Args:
        dataset: an opened folder.
        frame: "camera" (internal camera frame) or "world" (Siléane only: the poses as stored).
    Raises:
        ValueError: ``frame="world"`` for an IPA folder (its annotations are camera-frame only).
    """
    if isinstance(dataset, IPADataset):
        if frame != "camera":
            raise ValueError(
                f"{dataset.root}: IPA ground truth is in the camera frame only, not {frame!r}"
            )
        for i, (cycle, n) in enumerate(dataset.scenes()):
            yield dataset.scene_name(i), dataset.read_ground_truth(cycle, n)
    else:
        for scene in dataset.scenes():
            yield scene, dataset.read_ground_truth(scene, frame=frame)
