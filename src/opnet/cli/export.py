"""``python export.py ckpt=<path> [format=onnx] [out=<file>] [expect_parameterization=<name>]``.

Writes the ONNX graph with its metadata (:mod:`opnet.deploy.export`) and, with ``check=true``,
runs it in ONNX Runtime on recorded inputs (the first test images of the checkpoint's dataset
when they are on disk, else synthetic piles of boxes) and prints the largest difference to PyTorch.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig

from opnet.cli.build import load_checkpoint, require_checkpoint_file
from opnet.cli.tools import require_writable
from opnet.datasets.outputs import is_within
from opnet.deploy.export import (
    FORMATS,
    export_onnx,
    max_abs_difference,
    parameterization_name,
    reference_outputs,
)

log = logging.getLogger(__name__)


def synthetic_inputs(size: int, n: int = 2, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` normalized depth images of random boxes on a floor, and a plausible input camera."""
    rng = np.random.default_rng(seed)
    images = np.full((n, 1, size, size), 0.8, np.float32)
    for img in images:
        for _ in range(12):
            x, y = rng.integers(0, size - size // 6, 2)
            w, h = rng.integers(size // 16, size // 6, 2)
            img[0, y : y + h, x : x + w] = np.minimum(img[0, y : y + h, x : x + w], rng.uniform(0.3, 0.75))
    f = size * 1.07
    cams = np.array([[f, f, (size - 1) / 2, (size - 1) / 2, size, size, 0.6, 1.4]] * n, dtype=np.float64)
    return images, cams


#: the self-check's largest accepted difference between ONNX Runtime and PyTorch (presence and
#: visibility in [0, 1], translations in metres, rotation matrix entries)
CHECK_TOLERANCE = 1e-3


def run(cfg: DictConfig) -> dict[str, Any]:
    """Export; returns the metadata (with ``max_abs_difference`` when checked)."""
    fmt = str(cfg.format).lower()
    if fmt not in FORMATS:
        raise ValueError(f"format={cfg.format!r}: unknown export format; expected one of {', '.join(FORMATS)}")
    ckpt = require_checkpoint_file(str(cfg.ckpt))
    out = Path(str(cfg.out)) if cfg.get("out") else ckpt.with_suffix(f".{fmt}")
    if is_within(out, ckpt):
        raise ValueError(f"out={out}: the checkpoint itself; the export would replace it, choose another out=")
    if out.exists() and not out.is_file():  # /dev/null, a folder, a FIFO: never replaced
        raise ValueError(f"out={out}: exists and is not a regular file; choose another out=")
    if out.suffix.lower() != f".{fmt}":
        what = out.suffix or "a file without suffix"
        raise ValueError(f"out={out}: an {fmt.upper()} export is written to a .{fmt} file, not {what} (a checkpoint or "
                         "another file it would replace); choose another out=")
    if out.exists() and not cfg.get("overwrite", False):
        raise ValueError(f"{out}: exists already; pass overwrite=true to replace it, or choose another out=")
    require_writable(out, "out=")  # a read-only folder: refused before the export, named as out
    system, run_cfg = load_checkpoint(ckpt)
    name = parameterization_name(system.parameterization)
    wanted = cfg.get("expect_parameterization")
    if wanted is not None and str(wanted).lower() != name:
        raise ValueError(f"{ckpt}: a checkpoint of the {name!r} parameterization, not {str(wanted)!r} as "
                         f"expect_parameterization={wanted} says; drop the option or export the right checkpoint")
    start = time.perf_counter()
    meta = export_onnx(system, run_cfg, ckpt.resolve(), out)
    print(f"exported {name} ({meta['object']}, {meta['rotation']}, input {meta['input']['size']}^2, "
          f"{meta['slots']} slot(s) x {meta['grid_size']}^2 cells) to {out} "
          f"({out.stat().st_size / 1e6:.1f} MB, {time.perf_counter() - start:.1f} s)")
    if cfg.get("check", True):
        from opnet.deploy.runtime import OnnxPoseEstimator

        images, cams = synthetic_inputs(meta["input"]["size"])
        estimator = OnnxPoseEstimator(out)
        diff = max_abs_difference(estimator.run(images, cams), reference_outputs(system, images, cams))
        meta["max_abs_difference"] = diff
        print("ONNX Runtime vs PyTorch, largest difference over every cell: "
              + ", ".join(f"{k} {v:.1e}" for k, v in diff.items()))
        failed = {k: v for k, v in diff.items() if not v <= CHECK_TOLERANCE}  # NaN fails too
        if failed:
            out.unlink(missing_ok=True)
            raise ValueError(f"{out}: the exported graph differs from PyTorch ("
                             + ", ".join(f"{k} {v:.3g}" for k, v in failed.items())
                             + f" > {CHECK_TOLERANCE:g}); the file was removed")
    print(f"deploy without PyTorch: from opnet.deploy.runtime import OnnxPoseEstimator; "
          f"OnnxPoseEstimator('{out}').predict(depth_m, camera)")
    return meta
