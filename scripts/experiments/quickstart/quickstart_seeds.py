"""The quickstart over seeds and precision paths: the spread a user should expect, and what the
machine changes.

    python scripts/experiments/quickstart/quickstart_seeds.py --seeds 0 1 2 --precision auto 32

Runs ``python train.py experiment=quickstart seed=S trainer.precision=P`` as the README prints it
(the training seed varies; the data are the quickstart's own, generated once with its seed 0 into a
temporary root, or ``--keep``), and records each run's held-out test AP, MAP, F1, share of parts
found and wall time with the machine facts that change the model: the CPU, whether it computes
bf16 natively, and the precision path the run took (``auto`` is bf16 mixed on such CPUs, else
fp32; ``32`` forces fp32). The first run's wall time includes the data generation
(``with_generation``); the others reuse the data.

Rows go to ``--out`` (default ``results/quickstart/seeds.csv``), keyed by (CPU, precision path,
seed): a run already recorded for this CPU is skipped unless ``--force``, so an interrupted sweep
resumes. ``scripts/dev/readme_figures.py`` renders the mean ± sd per precision path next to the
quickstart's figure.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from opnet.hardware import cpu_has_native_bf16, resolve_precision
from opnet.paths import REPO_ROOT
from opnet.studies import merge_csv, train_command
from opnet.studies.results import cpu_model, seed_spread

FIELDS = ("cpu", "native_bf16", "precision_path", "seed", "ap", "map", "f1", "found", "wall_s", "with_generation",
          "torch", "date", "command")  # fmt: skip
KEY = ("cpu", "precision_path", "seed")


def path_name(precision: str) -> str:
    """The numeric path ``trainer.precision=<precision>`` takes on this CPU: ``bf16`` or ``fp32``."""
    return "bf16" if str(resolve_precision(precision, "cpu")).startswith("bf16") else "fp32"


def run_one(root: Path, seed: int, precision: str) -> dict[str, Any]:
    """One quickstart run in ``root`` (its data under ``root/outputs``); the row to record."""
    run_dir = root / f"run_{precision}_{seed}"
    data_present = (root / "outputs" / "data").is_dir() and any((root / "outputs" / "data").iterdir())
    argv = ["experiment=quickstart", f"seed={seed}", f"trainer.precision={precision}"]
    env = {**os.environ, "OPNET_ROOT": str(root), "PYOPENGL_PLATFORM": "egl"}
    start = time.monotonic()
    proc = subprocess.run(train_command(argv, run_dir), cwd=REPO_ROOT, env=env, capture_output=True, text=True)
    wall = time.monotonic() - start
    if proc.returncode:
        raise RuntimeError(f"quickstart seed {seed}, precision {precision} failed (exit {proc.returncode}):\n"
                           f"{proc.stderr[-3000:]}")
    summary = json.loads((run_dir / "test" / "summary.json").read_text())
    diag = summary["diagnostics"]
    import torch

    return {
        "cpu": cpu_model(), "native_bf16": cpu_has_native_bf16(), "precision_path": path_name(precision),
        "seed": seed, "ap": round(summary["ap"], 4), "map": round(summary["map"], 4), "f1": round(summary["f1"], 4),
        "found": round(diag["matched"] / max(diag["to_find"], 1), 4), "wall_s": round(wall, 1),
        "with_generation": not data_present, "torch": torch.__version__, "date": time.strftime("%Y-%m-%d"),
        "command": "python train.py " + " ".join(argv),
    }  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--precision", nargs="+", default=["auto"],
                        help="trainer.precision values to run (auto: bf16 where native, else fp32; 32: fp32)")
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "quickstart" / "seeds.csv")
    parser.add_argument("--keep", type=Path, help="run in this folder and keep it (else a temporary one)")
    parser.add_argument("--force", action="store_true", help="run again what this CPU already recorded")
    args = parser.parse_args(argv)
    if any(s < 0 for s in args.seeds):
        parser.error("--seeds: seeds are non-negative integers")
    root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="opnet_quickstart_seeds_"))
    root.mkdir(parents=True, exist_ok=True)
    import csv

    done = list(csv.DictReader(args.out.open())) if args.out.is_file() else []
    cpu = cpu_model()
    for precision in args.precision:
        for seed in args.seeds:
            key = (cpu, path_name(precision), str(seed))
            if not args.force and any(tuple(str(r[k]) for k in KEY) == key for r in done):
                print(f"seed {seed}, {key[1]}: recorded for this CPU, skipped (--force runs it again)", flush=True)
                continue
            row = run_one(root, seed, precision)
            done = merge_csv(args.out, FIELDS, [row], KEY)
            print(f"seed {seed}, {row['precision_path']}: test AP {row['ap']:.4f}, {row['wall_s']:.0f} s"
                  f"{' (with generation)' if row['with_generation'] else ''}", flush=True)
    if not args.keep:
        import shutil

        shutil.rmtree(root, ignore_errors=True)
    print("\n| CPU | precision path | seeds | test AP mean ± sd | wall (s, without generation) |\n|---|---|---|---|---|")
    for g in seed_spread(done):
        print(f"| {g['cpu']} | {g['precision_path']} | {len(g['seeds'])} | {g['ap_mean']:.3f} ± {g['ap_sd']:.3f} | "
              f"{g['wall_s']:.0f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
