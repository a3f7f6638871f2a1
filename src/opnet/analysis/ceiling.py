"""Ceiling study: the AP each parameterization reaches with a perfect network (opnet-oracle).

Every scene is brought to the network input, encoded, and its target decoded as if it were the
network output; the Brégier evaluator then scores the hypotheses. The only losses are the
instances a parameterization cannot represent (:meth:`Parameterization.assigned`), so the AP is
an upper bound of what a network trained with it can reach. For vanilla OP-Net the dropped
required instances (occlusion <= 0.5) are also split by cause: origin outside the image, origin
outside the clip range, or another object's origin in the same cell.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import hydra.utils
import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf

from opnet.data.preprocess import network_camera, resize_segmentation
from opnet.datasets.record import SceneRecord
from opnet.geometry.camera import Camera
from opnet.metrics.bregier import evaluate_scenes
from opnet.metrics.records import GroundTruthSet, HypothesisSet
from opnet.objects import ObjectModel, object_from_config
from opnet.parameterizations.base import GroundTruthBatch, Parameterization
from opnet.parameterizations.positions import CameraBatch, project_origins
from opnet.parameterizations.vanilla import VanillaParameterization
from opnet.paths import config_dir

MAX_OCCLUSION = 0.5
OBJECT_FILE = "object.json"


@dataclass(frozen=True)
class CeilingResult:
    """One (parameterization, object) cell of the study.

    Attributes:
        ap: AP of the decoded perfect outputs (NaN when the data lacks what the variant needs).
        dropped_fraction: the fraction of required instances (occlusion <= 0.5) the
            parameterization cannot represent.
        required, dropped: the counts behind ``dropped_fraction``.
    """

    parameterization: str
    object: str
    ap: float
    dropped_fraction: float
    required: int
    dropped: int


@dataclass(frozen=True)
class VanillaDrops:
    """Why vanilla OP-Net drops required instances of one object (counts)."""

    object: str
    required: int
    outside_image: int
    outside_clip: int
    shared_cell: int


@dataclass
class CeilingReport:
    """Results of a ceiling study, printable and writable as ceiling.md / ceiling.csv."""

    results: list[CeilingResult] = field(default_factory=list)
    vanilla_drops: list[VanillaDrops] = field(default_factory=list)

    def table(self) -> str:
        """Markdown table: rows parameterizations, columns objects, cells "AP (dropped %)"."""
        objects = list(dict.fromkeys(r.object for r in self.results))
        names = list(dict.fromkeys(r.parameterization for r in self.results))
        cell = {(r.parameterization, r.object): r for r in self.results}
        lines = [
            "| parameterization | " + " | ".join(objects) + " |",
            "|---" * (len(objects) + 1) + "|",
        ]
        for name in names:
            values = [_format_cell(cell.get((name, obj))) for obj in objects]
            lines.append(f"| {name} | " + " | ".join(values) + " |")
        return "\n".join(lines)

    def markdown(self) -> str:
        drops = [
            "| object | required | dropped: origin outside image | origin outside clip range "
            "| shared cell |",
            "|---|---|---|---|---|",
        ]
        for d in self.vanilla_drops:
            drops.append(
                f"| {d.object} | {d.required} | {d.outside_image} | {d.outside_clip} "
                f"| {d.shared_cell} |"
            )
        return (
            "\n\n".join(
                (
                    "# Parameterization ceiling: AP of a perfect network",
                    "Each scene is encoded and its target decoded as the network output, "
                    "then scored with the "
                    f"Brégier evaluator (max occlusion {MAX_OCCLUSION}). "
                    "Cells: AP (fraction of required "
                    "instances, occlusion <= 0.5, that the parameterization cannot represent).",
                    self.table(),
                    "## Why vanilla OP-Net drops required instances",
                    "\n".join(drops),
                )
            )
            + "\n"
        )

    def write(self, out_dir: str | Path) -> None:
        """Write ceiling.md and ceiling.csv (parameterization, object, ap, dropped_fraction)."""
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        (out / "ceiling.md").write_text(self.markdown())
        with open(out / "ceiling.csv", "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["parameterization", "object", "ap", "dropped_fraction"])
            for r in self.results:
                writer.writerow(
                    [r.parameterization, r.object, f"{r.ap:.6f}", f"{r.dropped_fraction:.6f}"]
                )


def _format_cell(result: CeilingResult | None) -> str:
    if result is None or math.isnan(result.ap):
        return "n/a"
    return f"{result.ap:.3f} ({100 * result.dropped_fraction:.1f} %)"


def network_ground_truth(
    records: Sequence[SceneRecord], size: int = 128
) -> tuple[GroundTruthBatch, list[Camera]]:
    """Ground truth of scenes at network-input resolution, and the network-input cameras.

    The segmentation is resized too (None if any scene lacks one).
    """
    cameras, items = [], []
    with_segmentation = all(r.segmentation is not None for r in records)
    for record in records:
        camera = network_camera(record.camera, size)
        seg = (
            resize_segmentation(record.segmentation, record.camera, size)
            if with_segmentation
            else None
        )
        cameras.append(camera)
        items.append(
            (
                record.R_cam_obj,
                record.t_cam_obj,
                np.clip(record.visibility, 0, 1),
                record.instance_id,
                seg,
            )
        )
    return GroundTruthBatch.from_arrays(items), cameras


def ceiling_for_object(
    obj: ObjectModel,
    records: Sequence[SceneRecord],
    configs: Mapping[str, DictConfig],
    size: int = 128,
    chunk: int = 64,
) -> tuple[list[CeilingResult], VanillaDrops]:
    """AP and dropped fraction of every parameterization config on the scenes of one object.

    Scenes are encoded ``chunk`` at a time; a variant that needs instance masks gets AP NaN when a
    scene has none.
    """
    batches = [
        network_ground_truth(records[i : i + chunk], size) for i in range(0, len(records), chunk)
    ]
    required = np.concatenate([(gt.visibility >= 1 - MAX_OCCLUSION).numpy() for gt, _ in batches])
    n_required = int(required.sum())
    results = []
    for name, cfg in configs.items():
        param: Parameterization = hydra.utils.instantiate(cfg, obj=obj)
        if param.needs_segmentation and any(gt.segmentation is None for gt, _ in batches):
            results.append(CeilingResult(name, obj.name, math.nan, math.nan, n_required, -1))
            continue
        hyps: list[HypothesisSet] = []
        assigned = []
        for gt, cameras in batches:
            hyps.extend(param.decode(param.encode(gt, cameras), cameras))
            assigned.append(param.assigned(gt, cameras).numpy())
        dropped = int((required & ~np.concatenate(assigned)).sum())
        ap = evaluate_scenes(_scenes(records, hyps), obj.pose_space, max_occlusion=MAX_OCCLUSION).ap
        results.append(
            CeilingResult(name, obj.name, ap, dropped / max(n_required, 1), n_required, dropped)
        )
    grid = next(
        (
            int(c.grid)
            for c in configs.values()
            if str(c.get("_target_", "")).endswith("VanillaParameterization")
        ),
        16,
    )
    drops = [vanilla_drop_causes(obj, gt, cameras, grid) for gt, cameras in batches]
    total = VanillaDrops(
        obj.name,
        *(
            sum(getattr(d, f) for d in drops)
            for f in ("required", "outside_image", "outside_clip", "shared_cell")
        ),
    )
    return results, total


def vanilla_drop_causes(
    obj: ObjectModel, gt: GroundTruthBatch, cameras: Sequence[Camera], grid: int = 16
) -> VanillaDrops:
    """Split the required instances vanilla OP-Net cannot represent by cause."""
    vanilla = VanillaParameterization(obj, grid)
    required = gt.visibility >= 1 - MAX_OCCLUSION
    dropped = required & ~vanilla.assigned(gt, cameras)
    proj = project_origins(gt.t_cam_obj, gt.batch_index, CameraBatch.of(cameras, gt.batch_size))
    outside_image = dropped & ~proj.cells(grid).inside
    outside_clip = dropped & ~outside_image & ~proj.in_range
    shared = dropped & ~outside_image & ~outside_clip
    return VanillaDrops(
        obj.name,
        int(required.sum()),
        int(outside_image.sum()),
        int(outside_clip.sum()),
        int(shared.sum()),
    )


def _scenes(
    records: Sequence[SceneRecord], hyps: Sequence[HypothesisSet]
) -> dict[str, tuple[GroundTruthSet, HypothesisSet]]:
    return {
        r.name: (GroundTruthSet(r.R_cam_obj, r.t_cam_obj, r.occlusion_rate, r.instance_id), h)
        for r, h in zip(records, hyps, strict=True)
    }


def parameterization_configs(folder: str | Path | None = None) -> dict[str, DictConfig]:
    """The configs of ``conf/parameterization/`` (or ``folder``), by file stem."""
    folder = Path(folder) if folder is not None else config_dir() / "parameterization"
    configs = {p.stem: OmegaConf.load(p) for p in sorted(folder.glob("*.yaml"))}
    if not configs:
        raise ValueError(f"{folder}: no parameterization configs (*.yaml) found")
    return configs  # type: ignore[return-value]


def dataset_object(root: str | Path, fallback: str | None = None) -> ObjectModel:
    """The object of a dataset: its ``object.json`` (an object config), else the ``fallback`` name.

    Relative ``mesh`` / ``poseutils`` paths in ``object.json`` are taken relative to the dataset.
    """
    root = Path(root)
    path = root / OBJECT_FILE
    if path.is_file():
        cfg = json.loads(path.read_text())
        if not isinstance(cfg, dict):
            raise ValueError(
                f"{path}: expected a JSON object (an object config), got {type(cfg).__name__}"
            )
        for key in ("mesh", "poseutils"):
            if cfg.get(key) and not Path(cfg[key]).is_absolute():
                cfg[key] = str(root / cfg[key])
        return object_from_config(cfg)
    if fallback is None:
        raise ValueError(f"{root}: no {OBJECT_FILE}; name the object with --object")
    from opnet.cli.evaluate import (
        resolve_object,
    )  # the CLI's resolver: built-ins and conf/object/*.yaml

    return resolve_object(fallback)


def run_ceiling_study(
    datasets: Sequence[tuple[ObjectModel, Sequence[SceneRecord]]],
    configs: Mapping[str, DictConfig] | None = None,
    size: int = 128,
) -> CeilingReport:
    """The study over several datasets (one object each)."""
    configs = parameterization_configs() if configs is None else configs
    report = CeilingReport()
    with torch.no_grad():
        for obj, records in datasets:
            results, drops = ceiling_for_object(obj, records, configs, size)
            report.results.extend(results)
            report.vanilla_drops.append(drops)
    return report
