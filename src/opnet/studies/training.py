"""Training runs of a fixed budget, as the learning benchmarks make them: the training throughput of
a config (train.py's own components in a Lightning ``Trainer``), the steps that fill some minutes at
that throughput, ``train.py`` for a number of steps, and a finished run's result row."""

from __future__ import annotations

import csv
import os
import time
from pathlib import Path
from typing import Any

import lightning as L

from opnet.paths import REPO_ROOT, config_dir
from opnet.studies import compose_train, diagnostic_shares, read_summary, run_train

#: the learning curve's columns of a result table (``learning_curve.csv``'s, behind object and config)
CURVE_FIELDS = ("object", "config", "epoch", "step", "train_minutes", "val_ap", "test_ap")


class StepClock(L.Callback):
    """Wall-clock time of every training batch end."""

    def __init__(self) -> None:
        self.times: list[float] = []

    def on_train_batch_end(self, *args: Any) -> None:
        self.times.append(time.perf_counter())


def measure(overrides: list[str], steps: int, warmup: int, accelerator: str = "cpu",
            network_alone: bool = False) -> tuple[float, float | None, dict[str, Any]]:  # fmt: skip
    """Training images/s of the config with ``overrides`` over ``steps`` steps after ``warmup``,
    the network alone's at the same batch size and precision (None unless ``network_alone``), and
    what was measured (network preset, batch size, precision)."""
    import torch

    from opnet.cli.build import build_components, build_datamodule
    from opnet.hardware import resolve_precision
    from opnet.models.stats import train_images_per_s

    cfg = compose_train(overrides)
    L.seed_everything(0, workers=True)
    comps = build_components(cfg)
    dm = build_datamodule(cfg, comps.obj, train=True)
    clock = StepClock()
    precision = resolve_precision(cfg.trainer.precision, accelerator)
    trainer = L.Trainer(
        accelerator=accelerator, devices=1, precision=precision, max_steps=warmup + steps,
        limit_val_batches=0, logger=False, enable_checkpointing=False, enable_progress_bar=False,
        enable_model_summary=False, callbacks=[clock], num_sanity_val_steps=0,
    )  # fmt: skip
    trainer.fit(comps.system, datamodule=dm)
    elapsed = clock.times[-1] - clock.times[warmup - 1]
    batch = int(cfg.data.batch_size)
    alone = None
    if network_alone:  # the trained weights are changed no further: the copy on the device is measured
        device = torch.device("cuda" if accelerator == "gpu" else "cpu")
        alone = train_images_per_s(comps.system.backbone.to(device), batch, int(cfg.data.input_size), steps, warmup,
                                   fast=str(precision).startswith("bf16"))  # fmt: skip
    return steps * batch / elapsed, alone, {"network": model_preset(overrides), "batch": batch, "precision": str(precision)}


def model_preset(overrides: list[str]) -> str:
    """The ``conf/model`` preset the overrides select: the last ``model=``, else the experiment's, else train.yaml's."""
    chosen = [o.split("=", 1)[1] for o in overrides if o.startswith("model=")]
    if chosen:
        return chosen[-1]
    from omegaconf import DictConfig, OmegaConf

    experiments = [o.split("=", 1)[1] for o in overrides if o.startswith("experiment=")]
    sources = [config_dir() / "experiment" / f"{e}.yaml" for e in experiments[-1:]] + [config_dir() / "train.yaml"]
    for source in sources:
        for entry in OmegaConf.load(source).get("defaults", []):
            if isinstance(entry, DictConfig):
                for key, value in entry.items():
                    if key.removeprefix("override ").strip("/") == "model":
                        return str(value)
    return "?"


def calibrate_steps(overrides: list[str], minutes: float) -> int:
    """Optimizer steps that fill ``minutes`` of training at the measured images/s."""
    ips = measure(overrides, steps=40, warmup=10)[0]
    batch = int(compose_train(overrides).data.batch_size)
    steps = int(minutes * 60 * ips / batch)
    print(f"  calibration: {ips:.1f} images/s -> {steps} steps for {minutes:g} min", flush=True)
    return steps


def validation_schedule(steps: int, validations: int) -> list[str]:
    """train.py overrides that validate ``validations`` times, evenly spaced in optimizer steps, the
    last at the final step (at epoch ends, a step budget that ends mid-epoch leaves its last steps,
    those at the lowest learning rate, out of the model selection)."""
    every = max(1, steps // max(1, validations))
    return ["trainer.check_val_every_n_epoch=null", f"+trainer.val_check_interval={every}"]


def train(overrides: list[str], run_dir: Path, steps: int, test_every: int = 1, validations: int | None = None) -> None:
    """train.py for ``steps`` optimizer steps (the last rounded down to a validation with ``validations``),
    its console in ``<run_dir>/bench_stdout.log``. A run that :func:`finished` with these overrides is not
    trained again (a benchmark run again scores it again: another test set, the decoding tuned)."""
    schedule = []
    if validations:
        schedule = validation_schedule(steps, validations)
        steps = steps - steps % max(1, steps // validations)
    full = [*overrides, f"trainer.max_steps={steps}", "trainer.max_epochs=100000", "trainer.enable_progress_bar=false",
            *schedule, f"callbacks.learning_curve.test_every={test_every}"]
    if finished(run_dir, full, steps):
        print(f"{run_dir}: trained and tested with these overrides already, not trained again", flush=True)
        return
    run_train(full, run_dir, run_dir / "bench_stdout.log")


def finished(run_dir: Path, overrides: list[str], steps: int) -> bool:
    """Whether ``run_dir`` holds a run of train.py with exactly ``overrides`` (Hydra's record) that reached
    step ``steps`` (its learning curve) and was tested (``test/summary.json``)."""
    import yaml

    record = run_dir / ".hydra" / "overrides.yaml"
    curve = run_dir / "learning_curve.csv"
    if read_summary(run_dir) is None or not record.is_file() or not curve.is_file():
        return False
    recorded = [o for o in yaml.safe_load(record.read_text()) or [] if not o.startswith("hydra.run.dir=")]
    rows = list(csv.DictReader(curve.open()))
    return recorded == list(overrides) and bool(rows) and int(rows[-1]["step"]) >= steps


def summarize(obj: str, config: str, run_dir: Path, steps: int, target: object = "") -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The result row (choices, steps, training minutes, test AP, ``target``, diagnostics) and the curve
    rows of a finished run."""
    import yaml

    summary = read_summary(run_dir)
    if summary is None:
        raise FileNotFoundError(f"{run_dir}: no test/summary.json")
    choices = yaml.safe_load((run_dir / ".hydra" / "hydra.yaml").read_text())["hydra"]["runtime"]["choices"]
    curve = list(csv.DictReader((run_dir / "learning_curve.csv").open()))
    row = {
        "object": obj, "config": config, "parameterization": choices.get("parameterization"),
        "rotation": choices.get("rotation"), "loss": choices.get("loss"), "model": choices.get("model"),
        "steps": steps, "train_minutes": float(curve[-1]["train_minutes"]) if curve else float("nan"),
        "images": int(curve[-1]["images"]) if curve else 0,
        "ap": summary["ap"], "map": summary["map"], "f1": summary["f1"], "target": target,
        **diagnostic_shares(summary), "run": os.path.relpath(run_dir, REPO_ROOT),
    }  # fmt: skip
    curves = [{"object": obj, "config": config, **{k: r[k] for k in CURVE_FIELDS[2:]}} for r in curve]
    return row, curves


__all__ = ["CURVE_FIELDS", "StepClock", "calibrate_steps", "measure", "model_preset", "summarize", "train",
           "validation_schedule"]
