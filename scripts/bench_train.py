"""Training throughput of the real pipeline (data -> encode -> forward -> loss -> backward -> step),
for the speed options of the CPU: memory format, mixed precision, DataLoader workers, scene cache.

    python scripts/bench_train.py --data <IPA dataset> [--steps 60] [--warmup 15]
    python scripts/bench_train.py --data <dir> --arms fp32 bf16+cl --workers 0 1

Each arm runs ``train.py``'s own components (Hydra config ``train`` with the arm's overrides) in a
Lightning ``Trainer`` for ``warmup + steps`` optimizer steps and times the last ``steps`` (a
callback reads the clock at every batch end); validation and checkpoints are off. Prints images/s
per arm and the speed-up over the first arm. Run it on a quiet machine: another busy process on
the two cores halves every figure.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import lightning as L  # noqa: E402
import torch  # noqa: E402
from hydra import compose, initialize_config_dir  # noqa: E402

from opnet.cli.build import build_components, build_datamodule  # noqa: E402
from opnet.fileio.atomic import append_csv_rows  # noqa: E402
from opnet.hardware import resolve_precision  # noqa: E402
from opnet.paths import config_dir  # noqa: E402

ARMS: dict[str, list[str]] = {
    "fp32": ["trainer.precision=32", "model.channels_last=false"],
    "cl": ["trainer.precision=32", "model.channels_last=true"],
    "bf16": ["trainer.precision=bf16-mixed", "model.channels_last=false"],
    "bf16+cl": ["trainer.precision=bf16-mixed", "model.channels_last=true"],
}


class StepClock(L.Callback):
    """Wall-clock time of every training batch end."""

    def __init__(self) -> None:
        self.times: list[float] = []

    def on_train_batch_end(self, *args: Any) -> None:
        self.times.append(time.perf_counter())


def measure(overrides: list[str], steps: int, warmup: int) -> float:
    """Training images/s of the config with ``overrides`` over ``steps`` steps after ``warmup``."""
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose("train", overrides=overrides)
    L.seed_everything(0, workers=True)
    comps = build_components(cfg)
    dm = build_datamodule(cfg, comps.obj, train=True)
    clock = StepClock()
    trainer = L.Trainer(
        accelerator="cpu", devices=1, precision=resolve_precision(cfg.trainer.precision, "cpu"), max_steps=warmup + steps,
        limit_val_batches=0, logger=False, enable_checkpointing=False, enable_progress_bar=False,
        enable_model_summary=False, callbacks=[clock], num_sanity_val_steps=0,
    )  # fmt: skip
    trainer.fit(comps.system, datamodule=dm)
    elapsed = clock.times[-1] - clock.times[warmup - 1]
    return steps * int(cfg.data.batch_size) / elapsed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True, help="an IPA-layout dataset folder")
    parser.add_argument("--object", default=None, help="object config name (default: from the dataset)")
    parser.add_argument("--arms", nargs="+", default=list(ARMS), choices=list(ARMS))
    parser.add_argument("--workers", nargs="+", type=int, default=[0])
    parser.add_argument("--cache", nargs="+", default=["true"], choices=["true", "false"])
    parser.add_argument("--steps", type=int, default=60)
    parser.add_argument("--warmup", type=int, default=15)
    parser.add_argument("--extra", nargs="*", default=[], help="further Hydra overrides for every arm")
    parser.add_argument("--out", type=Path, help="append the rows to this CSV (e.g. results/speed/train.csv)")
    args = parser.parse_args(argv)
    import json

    obj = args.object or json.loads((args.data / "object.json").read_text())["name"]
    base = [f"object={obj}", "data=ipa", f"data.root={args.data.resolve()}", *args.extra]
    rows = []
    for cache in args.cache:
        for workers in args.workers:
            for arm in args.arms:
                overrides = [*base, *ARMS[arm], f"data.num_workers={workers}", f"data.cache={cache}"]
                ips = measure(overrides, args.steps, args.warmup)
                rows.append((arm, workers, cache, ips))
                print(f"  {arm:8s} workers={workers} cache={cache}: {ips:6.1f} images/s", flush=True)
    ref = rows[0][3]
    print(f"\ntorch {torch.__version__}, {torch.get_num_threads()} threads, batch from the config, "
          f"{args.steps} timed steps after {args.warmup}")  # fmt: skip
    print("| arm | DataLoader workers | scene cache | train images/s | speed-up |")
    print("|---|---|---|---|---|")
    for arm, workers, cache, ips in rows:
        print(f"| {arm} | {workers} | {cache} | {ips:.1f} | {ips / ref:.2f}x |")
    if args.out is not None:
        append_csv_rows(args.out, ["arm", "workers", "cache", "images_per_s"],
                    [[arm, workers, cache, f"{ips:.1f}"] for arm, workers, cache, ips in rows])
    return 0


if __name__ == "__main__":
    sys.exit(main())
