"""``python generate.py object=<name> cycles=<int> drops=<int> workers=<int> out=<dir> seed=<int>``.

Entry logic of the data generator (conf/generate.yaml): builds the object from its config group
(``conf/object/<name>.yaml``, or ``object.mesh=/path/x.stl object.symmetry.kind=cyclic ...``) and
the scene settings from ``scene.*``, then calls :func:`opnet.synthesis.generate_dataset`.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from opnet._repr import short_repr
from opnet.cli.locks import writer_lock
from opnet.objects import object_from_config
from opnet.synthesis import GenerationReport, SceneConfig, generate_dataset

log = logging.getLogger(__name__)


def whole_number(value: Any, key: str) -> int:
    """A config value that must be a whole number (``cycles=abc``, ``seed=1.5`` named, not ``int()``'s
    message); ``true`` is not 1."""
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{key}={short_repr(value)}: expected a whole number")
    return value


def run(cfg: DictConfig) -> GenerationReport:
    """Generate (or complete) the dataset ``cfg.out``; returns the report (also logged).

    Relative paths (``out``, ``object.mesh``) are relative to the working directory; ``object.json``
    stores the mesh path made absolute. The run holds the lock on ``out`` (:func:`opnet.cli.locks.writer_lock`):
    a second run into the folder of a running one stops at once instead of claiming the same cycles.
    """
    out = Path(str(cfg.out))
    with writer_lock(out, "out="):
        object_config = OmegaConf.to_container(cfg.object, resolve=True)
        scene = SceneConfig.from_dict(OmegaConf.to_container(cfg.scene, resolve=True))
        obj = object_from_config(object_config)
        report = generate_dataset(
            obj,
            out,
            cycles=whole_number(cfg.cycles, "cycles"),
            drops=whole_number(cfg.drops, "drops"),
            workers=whole_number(cfg.workers, "workers"),
            seed=whole_number(cfg.seed, "seed"),
            scene=scene,
            progress=bool(cfg.get("progress", True)),
            previews=whole_number(cfg.get("previews", 4), "previews"),
            object_config=object_config,
            sensor=OmegaConf.to_container(cfg.sensor, resolve=True) if cfg.get("sensor") is not None else None,
        )
    log.info(
        "%s: %d cycles generated, %d already complete; %d scenes in %.1f s (%.2f scenes/s after %.1f s start-up); "
        "re-drops %d, unsettled drops %d",
        report.out, report.cycles_generated, report.cycles_skipped, report.scenes_written, report.seconds,
        report.scenes_per_second, report.startup_seconds, report.redrops, report.unsettled,
    )
    return report
