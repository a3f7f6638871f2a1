"""``python train.py ...``: fit, test the best checkpoint, write results and example predictions."""

from __future__ import annotations

import logging
import time
import zipfile
from pathlib import Path
from typing import Any

import lightning as L
from hydra.utils import instantiate
from omegaconf import DictConfig

from opnet.cli.build import (
    absolutize_paths,
    plain,
    build_components,
    build_datamodule,
    check_scene_address,
    checkpoint_config,
    load_checkpoint,
    read_checkpoint,
    require_checkpoint_file,
)
from opnet.cli.console import format_duration, report, result_summary
from opnet.cli.eval import evaluate_split
from opnet.hardware import configure_matmul_precision, precision_path, resolve_precision

log = logging.getLogger(__name__)


def resolve_ckpt_path(ckpt_path: str | None, output_dir: Path) -> str | None:
    """``"last"`` means ``<run dir>/checkpoints/last.ckpt`` (None if it does not exist yet)."""
    if ckpt_path in (None, "", "null"):
        return None
    if ckpt_path == "last":
        last = output_dir / "checkpoints" / "last.ckpt"
        if not last.is_file():
            log.warning("ckpt_path=last but %s does not exist: starting from scratch", last)
            return None
        return check_checkpoint_file(last)
    return check_checkpoint_file(require_checkpoint_file(ckpt_path))


def check_checkpoint_file(path: Path) -> str:
    """``path`` if it is a complete checkpoint archive (torch's zip format, every member's CRC
    intact) whose saved config names only opnet's own components; a file cut off by a crash or a
    full disk is named instead of failing deep in torch, an altered one is refused."""
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
    except (zipfile.BadZipFile, OSError, EOFError) as e:
        raise ValueError(f"{path}: truncated or corrupt checkpoint ({e}); resume from another one, "
                         "or delete it to start from scratch") from None
    if bad is not None:
        raise ValueError(f"{path}: corrupt checkpoint (member {bad} fails its CRC check)")
    checkpoint_config(read_checkpoint(path), path)  # resuming restores no config, but a checkpoint is data
    return str(path)


def build_trainer(cfg: DictConfig) -> L.Trainer:
    callbacks = [instantiate(c) for c in (cfg.get("callbacks") or {}).values() if c is not None]
    logger = instantiate(cfg.logger) if cfg.get("logger") is not None else False
    requested, accelerator = cfg.trainer.get("precision", "32"), str(cfg.trainer.get("accelerator", "cpu"))
    precision = resolve_precision(requested, accelerator)
    log.info(precision_path(requested, accelerator))
    configure_matmul_precision(accelerator)  # TF32 tensor cores for the fp32 matrix products on a GPU
    return instantiate(cfg.trainer, callbacks=callbacks, logger=logger, precision=precision)


def run(cfg: DictConfig) -> dict[str, Any]:
    """Entry logic of train.py. Returns the test summary (empty if ``test=false``)."""
    started = time.monotonic()
    absolutize_paths(cfg)
    if cfg.seed is not None and (isinstance(cfg.seed, bool) or not isinstance(cfg.seed, int)):
        raise ValueError(f"seed={cfg.seed!r}: expected a whole number")
    L.seed_everything(cfg.seed, workers=True)
    output_dir = Path(cfg.paths.output_dir)
    check_scene_address(cfg)
    tune_stride = tune_decoding_stride(cfg.get("tune_decoding"))
    if any(cfg.get(key) is not None for key in ("part_pixels", "part_cells", "flat_part")):
        from opnet.cli.sizing import command_line_keys, settings_for_flat_part, size_to_part
        from opnet.objects.config import object_from_config

        part = object_from_config(plain(cfg.object))
        for line in [*size_to_part(cfg, part.diameter), settings_for_flat_part(cfg, part.mesh, command_line_keys())]:
            if line:
                log.info(line)
    comps = build_components(cfg)
    datamodule = build_datamodule(cfg, comps.obj, train=True)
    trainer = build_trainer(cfg)
    # validation averages on the model's device or on the host (+inference.device_side=; auto: on a GPU)
    comps.system.configure_decoding((cfg.get("inference") or {}).get("device_side", "auto"))
    trainer.fit(comps.system, datamodule=datamodule, ckpt_path=resolve_ckpt_path(cfg.get("ckpt_path"), output_dir),
                weights_only=True)  # explicit: TORCH_FORCE_NO_WEIGHTS_ONLY_LOAD cannot turn it off
    result: dict[str, Any] = {}
    best = _best_checkpoint(trainer) if trainer.is_global_zero else None
    if tune_stride is not None and trainer.is_global_zero:
        from opnet.cli.decoding_search import tune_in_place, tuned_line

        report([tuned_line(tune_in_place(best, tune_stride, output_dir / "tune_val")) if best else
                "decoding      : kept as configured (no checkpoint was kept to tune it in)"])
    if cfg.get("test", True) and trainer.is_global_zero:
        system = comps.system
        if best:
            system, _ = load_checkpoint(best)
        system.configure_inference(cfg.get("inference"))  # fused fp32: the poses of fp32 eager, faster
        out = output_dir / "test"
        result = evaluate_split(system, datamodule, "test", out, examples=int(cfg.get("example_predictions", 0)))
        result["checkpoint"] = best
        lines = result_summary(result, str(out / "ap_table.md"), time.monotonic() - started, bool(cfg.get("verbose")))
        report(["", *lines,
                f"run directory : {output_dir}",
                f"checkpoint    : {best}",
                f"tensorboard   : tensorboard --logdir {output_dir}",
                f"test results  : {out}/summary.json, {out}/ap_table.md (per scene), {out}/results/",
                f"predictions   : {out}/predictions/"])
    elif trainer.is_global_zero:
        report(["", f"trained in {format_duration(time.monotonic() - started)} (test=false)",
                f"run directory : {output_dir}", f"checkpoints   : {output_dir}/checkpoints/"])
    return result


def tune_decoding_stride(value: Any) -> int | None:
    """``tune_decoding`` checked: None (the decoding as configured) or K >= 1 (tuned after training on every K-th
    validation scene).

    Raises:
        ValueError: anything else, one line naming the key.
    """
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        raise ValueError(f"tune_decoding={value!r}: expected null (the decoding as configured) or a whole number "
                         ">= 1 (tune it after training on every K-th validation scene)")
    return value


def _best_checkpoint(trainer: L.Trainer) -> str | None:
    cb = trainer.checkpoint_callback
    if cb is None:
        return None
    return cb.best_model_path or cb.last_model_path or None
