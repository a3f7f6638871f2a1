"""The learning benchmark: per object, generate data, train within a fixed CPU budget, report the
held-out test AP with error diagnostics and the learning curve (AP against minutes of training).

    python scripts/bench/bench_learning.py                                   # the four objects, 30 min each
    python scripts/bench/bench_learning.py --objects bunny --minutes 10 --config paper
    python scripts/bench/bench_learning.py --objects zbracket --steps 4000   # a fixed step budget

Per object: a training set (``--train-cycles`` cycles of ``--drops`` drops, seed 0, 256 x 256) and
a test set of other cycles from another seed (seed 1) are generated (or completed) under
``--data-dir``; ``train.py`` then runs with ``data=ipa`` on the training set (10 % of its cycles
for validation and model selection) and ``data.test_root`` on the test set. The step budget is
``--minutes`` of training at the throughput measured on this machine for this configuration
(a short calibration run) unless ``--steps`` is given; the steps used are recorded, so that a
run can be repeated exactly with ``--steps``. The learning curve scores the test split at every
validation (reported only; the model is selected on validation AP).

Writes, under ``--out`` (default ``results/learning``): ``learning.csv`` (one row per final
model: object, config, parameterization, rotation, loss, steps, train_minutes, ap, map, f1 and
the diagnostics), ``curves.csv`` (object, config, train_minutes, val_ap, test_ap),
``curves.png`` and ``README.md`` (the tables). Runs go to ``--runs-dir``. Rows of earlier
invocations (other objects or configs) are kept; a re-run replaces its own rows.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from opnet.paths import REPO_ROOT
from opnet.studies import fmt, merge_csv
from opnet.studies.training import CURVE_FIELDS, calibrate_steps, summarize, train

OBJECTS = ("bunny", "ring_screw", "gear_shaft", "zbracket")
#: named configurations (Hydra overrides of train.py)
CONFIGS: dict[str, list[str]] = {
    "paper": ["parameterization=vanilla", "rotation=euler_zyz", "loss=paper"],
    "default": [],
}
#: per-object overrides of a configuration (the measured best parameterization of each object)
OBJECT_OVERRIDES: dict[str, dict[str, list[str]]] = {}
TARGETS = {"bunny": 0.6, "ring_screw": 0.6, "gear_shaft": 0.8, "zbracket": 0.5}
ROW_FIELDS = (
    "object", "config", "parameterization", "rotation", "loss", "model", "steps", "train_minutes", "images",
    "ap", "map", "f1", "target", "found", "no_hypothesis", "position", "orientation", "conflict",
    "confident_fp_per_scene", "duplicates_per_scene", "t_err_mm_p50", "r_err_deg_p50", "run",
)  # fmt: skip


def generate(obj: str, out: Path, cycles: int, drops: int, seed: int) -> None:
    """Generate (or complete) a dataset with ``generate.py`` (resumable, deterministic)."""
    cmd = [sys.executable, str(REPO_ROOT / "generate.py"), f"object={obj}", f"cycles={cycles}", f"drops={drops}",
           "workers=2", f"seed={seed}", "scene.resolution=256", f"out={out}", "progress=false", "previews=2"]  # fmt: skip
    print(f"[{obj}] data: {out} ({cycles} cycles x {drops} drops, seed {seed})", flush=True)
    subprocess.run(cmd, check=True, cwd=REPO_ROOT, stdout=subprocess.DEVNULL)


def write_readme(out: Path, rows: list[dict[str, Any]], command: str) -> None:
    rows = sorted(rows, key=lambda r: (OBJECTS.index(r["object"]) if r["object"] in OBJECTS else 99, -float(r["ap"])))
    lines = [
        "# Learning benchmark", "",
        "Held-out test AP (Brégier, max occlusion 0.5) of models trained on this 2-core CPU within a fixed "
        "budget, on synthetic scenes of other cycles and another seed than the training data. Best configuration "
        "per object first. Diagnostics: share of the instances to find that were found, or missed for want of any "
        "hypothesis near them, a position error > δ, an orientation error > δ, or a matching conflict; confident "
        "false positives (score ≥ 0.5) and duplicates per scene; median errors of the matched pairs.", "",
        f"Command: `{command}`", "",
        "| object | config | parameterization | rotation | loss | steps | train min | **test AP** | target | MAP "
        "| F1 | found % | no hyp % | position % | orientation % | conflict % | conf. FP/scene | dup/scene "
        "| t p50 mm | r p50 ° |",
        "|" + "---|" * 20,
    ]  # fmt: skip
    for r in rows:
        lines.append(
            f"| {r['object']} | {r['config']} | {r['parameterization']} | {r['rotation']} | {r['loss']} | "
            f"{fmt(r['steps'], 'int')} | {fmt(r['train_minutes'], 'f1')} | **{fmt(r['ap'])}** | {r['target']} | "
            f"{fmt(r['map'])} | {fmt(r['f1'])} | {fmt(r['found'], 'pct')} | {fmt(r['no_hypothesis'], 'pct')} | "
            f"{fmt(r['position'], 'pct')} | {fmt(r['orientation'], 'pct')} | {fmt(r['conflict'], 'pct')} | "
            f"{fmt(r['confident_fp_per_scene'], 'f1')} | {fmt(r['duplicates_per_scene'], 'f1')} | "
            f"{fmt(r['t_err_mm_p50'], 'f1')} | {fmt(r['r_err_deg_p50'], 'f1')} |"
        )
    lines += ["", "Learning curves (AP against minutes of training; solid: test, dashed: validation), also in "
              "`curves.csv`:", "", "![learning curves](curves.png)", ""]
    (out / "README.md").write_text("\n".join(lines))


def plot_curves(out: Path, curves: list[dict[str, Any]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for c in curves:
        groups.setdefault((c["object"], c["config"]), []).append(c)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for (obj, config), pts in sorted(groups.items()):
        tested = [p for p in pts if p["test_ap"] not in ("", None)]
        line, = ax.plot([float(p["train_minutes"]) for p in tested], [float(p["test_ap"]) for p in tested],
                        marker="o", ms=4, label=f"{obj} ({config}): test")  # fmt: skip
        ax.plot([float(p["train_minutes"]) for p in pts], [float(p["val_ap"]) for p in pts], ls="--", lw=1,
                color=line.get_color(), label=f"{obj} ({config}): validation")  # fmt: skip
    ax.set_xlabel("minutes of training (2 CPU cores)")
    ax.set_ylabel("AP (test: held-out seed; validation: held-out cycles)")
    ax.set_ylim(0, 1)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=120)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects", nargs="+", default=list(OBJECTS))
    parser.add_argument("--config", default="default", choices=list(CONFIGS))
    parser.add_argument("--minutes", type=float, default=30.0)
    parser.add_argument("--steps", type=int, default=None, help="fixed step budget (skips the calibration)")
    parser.add_argument("--train-cycles", type=int, default=400)
    parser.add_argument("--test-cycles", type=int, default=25)
    parser.add_argument("--drops", type=int, default=20)
    parser.add_argument("--data-dir", type=Path, default=REPO_ROOT / "outputs" / "data" / "learning")
    parser.add_argument("--runs-dir", type=Path, default=REPO_ROOT / "outputs" / "learning")
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "learning")
    parser.add_argument("--extra", nargs="*", default=[], help="further Hydra overrides of train.py")
    parser.add_argument("--test-every", type=int, default=3,
                        help="score the test split for the curve every this many epochs (validation AP: every epoch)")
    args = parser.parse_args(argv)
    command = "python scripts/bench/bench_learning.py " + " ".join(argv if argv is not None else sys.argv[1:])
    rows, curves = [], []
    for obj in args.objects:
        train_root = args.data_dir / f"{obj}_train_c{args.train_cycles}_d{args.drops}_s0"
        test_root = args.data_dir / f"{obj}_test_c{args.test_cycles}_d{args.drops}_s1"
        generate(obj, train_root, args.train_cycles, args.drops, 0)
        generate(obj, test_root, args.test_cycles, args.drops, 1)
        overrides = [f"object={obj}", "data=ipa", f"data.root={train_root}", f"data.test_root={test_root}",
                     *CONFIGS[args.config], *OBJECT_OVERRIDES.get(args.config, {}).get(obj, []), *args.extra]  # fmt: skip
        steps = args.steps or calibrate_steps(overrides, args.minutes)
        run_dir = args.runs_dir / f"{obj}_{args.config}"
        start = time.time()
        print(f"[{obj}] training {args.config}: {steps} steps -> {run_dir}", flush=True)
        train(overrides, run_dir, steps, args.test_every)
        row, curve = summarize(obj, args.config, run_dir, steps, TARGETS.get(obj, ""))
        print(f"[{obj}] test AP {row['ap']:.4f} after {row['train_minutes']:.1f} training minutes "
              f"({(time.time() - start) / 60:.1f} min wall)", flush=True)  # fmt: skip
        rows.append(row)
        curves += curve
    all_rows = merge_csv(args.out / "learning.csv", ROW_FIELDS, rows, ("object", "config"))
    all_curves = merge_csv(args.out / "curves.csv", CURVE_FIELDS, curves, ("object", "config"))
    write_readme(args.out, all_rows, command)
    plot_curves(args.out, all_curves)
    print((args.out / "README.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
