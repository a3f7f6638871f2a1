"""2 x 2 A/B of the depth-sensor model: train on ideal vs sensor-model depth, test on both.

    python scripts/experiments/sensor/sensor_ab.py [--work outputs/sensor_ab] [--sensor structured_light]
        [--object shaft] [--out results/sensor] [train.py overrides ...]

Both arms are the README's quickstart recipe (``train.py experiment=quickstart``: same object,
150 cycles x 10 drops at 256 px, small network, 18 epochs, seed 0), one with ``sensor=ideal`` and
one with ``sensor=<sensor>``; nothing else differs. Both are scored with ``eval.py`` on the same
two held-out test sets of 15 cycles generated with another seed (1): one ideal, one with the
sensor model. Every step is skipped when its output exists (re-run to complete an interrupted
table). Writes ``ab.csv`` and ``ab.md`` to ``--out`` and prints the table.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
from pathlib import Path

from opnet.paths import REPO_ROOT
from opnet.studies import read_summary, run_logged, run_train

TEST_SEED = 1


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--work", type=Path, default=REPO_ROOT / "outputs" / "sensor_ab")
    ap.add_argument("--sensor", default="structured_light")
    ap.add_argument("--object", default="shaft")
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "sensor")
    ap.add_argument("--test-cycles", type=int, default=15)
    args, overrides = ap.parse_known_args()
    work = args.work.resolve()
    env = {**os.environ, "OPNET_ROOT": str(work), "PYOPENGL_PLATFORM": "egl"}
    sensors = ["ideal", args.sensor]

    tests = {}
    for s in sensors:
        out = work / f"test_{s}"
        if not (out / "generation.json").exists() or not any((out / "gt").glob("cycle_*")):
            print(f"generating the held-out test set ({s}) ...", flush=True)
        run_logged([sys.executable, "generate.py", f"object={args.object}", f"cycles={args.test_cycles}", "drops=10", "workers=2",
              f"seed={TEST_SEED}", "scene.resolution=256", f"sensor={s}", f"out={out}", "progress=false"],
             work / "logs" / f"generate_test_{s}.log", env=env)  # completes or confirms an existing set
        tests[s] = out

    models = {}
    for s in sensors:
        run_dir = work / f"run_{s}"
        if not (run_dir / "test" / "summary.json").exists():
            print(f"training the {s} arm (quickstart recipe) ...", flush=True)
            run_train(["experiment=quickstart", f"object={args.object}", f"sensor={s}", "example_predictions=0",
                       *overrides], run_dir, work / "logs" / f"train_{s}.log", env=env)
        best = sorted((run_dir / "checkpoints").glob("epoch*.ckpt"))
        if not best:
            raise SystemExit(f"{run_dir}/checkpoints: no epoch*.ckpt")
        models[s] = best[-1]

    rows = []
    for train_s in sensors:
        for test_s in sensors:
            out = work / f"eval_{train_s}_on_{test_s}"
            if not (out / "summary.json").exists():
                print(f"scoring the {train_s} model on {test_s} test scenes ...", flush=True)
                run_logged([sys.executable, "eval.py", f"ckpt={models[train_s]}", f"data.test_root={tests[test_s]}",
                            f"out={out}", "examples=0"], work / "logs" / f"eval_{train_s}_on_{test_s}.log", env=env)
            summary = read_summary(out, ".")
            diag = summary.get("diagnostics", {})
            rows.append({"train_sensor": train_s, "test_sensor": test_s, "ap": round(summary["ap"], 4),
                         "map": round(summary["map"], 4),
                         "found": round(diag.get("matched", 0) / max(diag.get("to_find", 1), 1), 4),
                         "scenes": summary["scenes"], "object": args.object,
                         "checkpoint": models[train_s].name})

    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "ab.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    ap_of = {(r["train_sensor"], r["test_sensor"]): r["ap"] for r in rows}
    lines = [f"| trained on \\ tested on | {sensors[0]} | {sensors[1]} |", "|---|---|---|"]
    for t in sensors:
        lines.append(f"| {t} | {ap_of[(t, sensors[0])]:.4f} | {ap_of[(t, sensors[1])]:.4f} |")
    table = "\n".join(lines)
    note = (f"AP (Brégier) on {rows[0]['scenes']} held-out scenes each ({args.object}, seed {TEST_SEED}); both arms: "
            f"`python train.py experiment=quickstart object={args.object} sensor=<arm>`")
    (args.out / "ab.md").write_text(table + "\n\n" + note + "\n")
    print(table)
    print(note)


if __name__ == "__main__":
    main()
