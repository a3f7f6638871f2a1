"""A/B evidence for the learning changes: the same object, data, seed and step budget with and
without each change, scored on the same held-out scenes (one table).

    python scripts/experiments/learning/ab_learning.py --train <IPA dir> --test <IPA dir> [--foreign <IPA dir>]
        [--object bunny] [--steps 2000] [--arms A0 A1 ...] [--runs-dir outputs/ab] [--out results/learning]

Arms (``ARMS``; each is ``train.py`` with the listed overrides, fp32 unless it says otherwise):
the paper's formulation, then one change at a time (balanced loss, continuous 6-D rotation,
tuned decoding, cell-offset positions for AP, bf16 at the same steps and at the same minutes,
random viewing conditions). A ``tuned`` arm re-uses the model of its base arm and decodes the
test split with the decoding settings that ``opnet-tune-decoding``'s search finds best on
the *validation* split. ``--foreign`` adds a column: AP on scenes of another camera set-up.
Finished arms (same overrides, ``test/summary.json`` present) are not trained again. Writes
``ab.md`` and ``ab.csv`` to ``--out``.

    python scripts/experiments/learning/ab_learning.py --collect results/learning/ab_runs.yaml --runs-dir <dir>

``--collect`` builds the table from finished ``train.py`` runs listed in a YAML spec (arm, change,
run name under ``--runs-dir``, optionally ``tune: true``: decode the run's model with the
settings found best on its validation split, or ``decoding``: fixed settings): each row shows the
run's own overrides, so every cell can be re-run with ``python train.py <overrides>``; test AP and
diagnostics are read from the run's ``test/summary.json`` (scored by ``train.py`` on the same
held-out set) unless the arm re-decodes.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import os
import sys
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from opnet.paths import REPO_ROOT
from opnet.studies import best_checkpoint, run_train

FP32 = ["trainer.precision=32"]
#: name -> (what changes, base arm of a tuned arm or None, train.py overrides)
ARMS: dict[str, tuple[str, str | None, list[str]]] = {
    "V0": ("vanilla, the paper's formulation", None, ["parameterization=vanilla", "formulation=paper", *FP32]),
    "V1": ("V0 + balanced loss", None, ["parameterization=vanilla", "formulation=paper", "loss=balanced", *FP32]),
    "V1b": ("V0 + continuous 6-D rotation (paper loss: L2 on its channels)", None,
            ["parameterization=vanilla", "formulation=paper", "rotation=r6d", *FP32]),
    "V2": ("V1 + continuous 6-D rotation", None,
           ["parameterization=vanilla", "formulation=paper", "loss=balanced", "rotation=r6d", *FP32]),
    "V3": ("V2 + decoding tuned on validation", "V2", []),
    "V4": ("V2 in bf16 (same steps)", None,
           ["parameterization=vanilla", "formulation=paper", "loss=balanced", "rotation=r6d", "trainer.precision=bf16-mixed"]),
    "V5": ("V4 for the minutes V2 trained (more steps)", None,
           ["parameterization=vanilla", "formulation=paper", "loss=balanced", "rotation=r6d", "trainer.precision=bf16-mixed"]),
    "A0": ("AP, the paper's formulation (enlarged-image positions)", None, ["parameterization=ap", "formulation=paper", *FP32]),
    "A1": ("A0 + balanced loss", None, ["parameterization=ap", "formulation=paper", "loss=balanced", *FP32]),
    "A2": ("A1 + continuous 6-D rotation", None,
           ["parameterization=ap", "formulation=paper", "loss=balanced", "rotation=r6d", *FP32]),
    "A3": ("A2 + cell-offset positions", None, ["parameterization=ap", "formulation=paper", "loss=balanced",
                                                 "rotation=r6d", "multi_cell_position=cell_offset", *FP32]),
    "A4": ("A3 + decoding tuned on validation", "A3", []),
    "R0": ("ours (formulation=ours, bf16)", None, ["parameterization=vanilla", "trainer.precision=bf16-mixed"]),
    "R1": ("R0 + random viewing conditions (augmentation=robust)", None,
           ["parameterization=vanilla", "trainer.precision=bf16-mixed", "augmentation=robust"]),
}  # fmt: skip
FIELDS = ("arm", "change", "steps", "train_minutes", "ap", "map", "f1", "found", "no_hypothesis", "position",
          "orientation", "conflict", "confident_fp_per_scene", "foreign_ap", "decoding", "run")  # fmt: skip


def overrides_of(run: Path) -> list[str] | None:
    import yaml

    path = run / ".hydra" / "overrides.yaml"
    return yaml.safe_load(path.read_text()) if path.is_file() else None


def train_arm(run: Path, overrides: list[str]) -> None:
    if (run / "test" / "summary.json").is_file() and overrides_of(run) == overrides:
        print(f"  {run.name}: done already", flush=True)
        return
    print(f"  {run.name}: training", flush=True)
    run_train(overrides, run, run / "ab_stdout.log")


def train_minutes(run: Path) -> float:
    """Minutes of training of a finished run (its learning curve's last row)."""
    return float(list(csv.DictReader((run / "learning_curve.csv").open()))[-1]["train_minutes"])


def evaluate(ckpt: Path, data_root: Path, settings: dict[str, Any] | None) -> dict[str, Any]:
    """Test AP and diagnostics of a checkpoint on all scenes of ``data_root``, decoding with
    ``settings`` (None: as configured)."""
    from omegaconf import OmegaConf
    from torch.utils.data import DataLoader

    from opnet.cli.build import build_datamodule, load_checkpoint
    from opnet.data.sample import collate
    from opnet.evaluation import evaluate as run_evaluators
    from opnet.evaluation import scoring
    from opnet.tools.tune_decoding import decoder

    system, cfg = load_checkpoint(ckpt)
    if settings is not None:
        system.parameterization = decoder(system.parameterization, settings)
    cfg = OmegaConf.merge(cfg, {"data": {"root": str(data_root), "test_root": str(data_root), "generate": None}})
    dm = build_datamodule(cfg, system.parameterization.obj, train=False)
    dm.setup("test")
    loader = DataLoader(dm.splits["test"], batch_size=16, collate_fn=collate)
    summary, diag = run_evaluators(system, loader, scoring(system))
    return {"summary": summary.to_dict(), "diagnostics": diag.to_dict()}


RESULT_HEADER = ("change | steps | train min | **test AP** | MAP | F1 | found % | no hyp % | position % "
                 "| orientation % | conf. FP/scene")


def result_cells(r: dict[str, Any]) -> str:
    """The cells of :data:`RESULT_HEADER` for one row."""
    return (f"{r['change']} | {r['steps']} | {r['train_minutes']} | **{r['ap']:.3f}** | {r['map']:.3f} | "
            f"{r['f1']:.3f} | {100 * r['found']:.1f} | {100 * r['no_hypothesis']:.1f} | {100 * r['position']:.1f} | "
            f"{100 * r['orientation']:.1f} | {r['confident_fp_per_scene']:.2f}")  # fmt: skip


def row_of(arm: str, change: str, run: Path, result: dict[str, Any], steps: int) -> dict[str, Any]:
    s, d = result["summary"], result["diagnostics"]
    n = max(d["to_find"], 1)
    curve = list(csv.DictReader((run / "learning_curve.csv").open())) if (run / "learning_curve.csv").is_file() else []
    return {
        "arm": arm, "change": change, "steps": steps,
        "train_minutes": round(float(curve[-1]["train_minutes"]), 1) if curve else "",
        "ap": s["ap"], "map": s["map"], "f1": s["f1"], "found": d["matched"] / n,
        "no_hypothesis": d["no_hypothesis"] / n, "position": d["position"] / n, "orientation": d["orientation"] / n,
        "conflict": d["conflict"] / n, "confident_fp_per_scene": d["confident_false_positives"] / max(s["num_scenes"], 1),
        "run": os.path.relpath(run, REPO_ROOT),
    }  # fmt: skip


def run_overrides(run: Path) -> str:
    """The method of a finished run as explicit ``train.py`` overrides, read from its composed
    config (so that they re-run it whatever the defaults are today)."""
    import yaml

    c = yaml.safe_load((run / ".hydra" / "config.yaml").read_text())
    rot, loss, p = c["rotation"], c["loss"], c["parameterization"]
    rotation = "r6d" if rot["_target_"].endswith("SixDCodec") else f"euler_{str(rot.get('convention', 'zyz')).lower()}"
    out = [f"parameterization={run_choice(run, 'parameterization')}", f"rotation={rotation}",
           f"loss.orientation={loss['orientation']}", f"loss.position={loss.get('position', 'channels')}"]  # fmt: skip
    out += [f"loss.{k}={loss[k]}" for k in ("lambda_pos", "lambda_pose", "lambda_ori") if float(loss.get(k, 1.0)) != 1.0]
    if "position" in p:  # an interpolation of the top-level key in newer configs
        position = c.get("multi_cell_position", "enlarged") if "${" in str(p["position"]) else p["position"]
        out.append(f"multi_cell_position={position}")
    if p.get("averaging"):
        out += ["parameterization.averaging=true", f"parameterization.averaging_eps={p['averaging_eps']}",
                f"parameterization.averaging_score={p['averaging_score']}"]  # fmt: skip
    else:
        out.append("parameterization.averaging=false")
    out += [f"parameterization.score={p.get('score', 'p')}", f"trainer.precision={c['trainer']['precision']}",
            f"augmentation={run_choice(run, 'augmentation')}"]  # fmt: skip
    return " ".join(out)


def run_choice(run: Path, group: str) -> str:
    import yaml

    return str(yaml.safe_load((run / ".hydra" / "hydra.yaml").read_text())["hydra"]["runtime"]["choices"].get(group))


def collect(spec_path: Path, runs_dir: Path, out: Path) -> list[dict[str, Any]]:
    """The A/B table of finished runs listed in ``spec_path`` (see the module docstring)."""
    import yaml

    from opnet.tools.tune_decoding import RecordedSplit, search

    spec = yaml.safe_load(spec_path.read_text())
    rows = []
    for arm in spec["arms"]:
        run = runs_dir / arm["run"]
        if not (run / "test" / "summary.json").is_file():
            raise FileNotFoundError(f"{spec_path}: arm {arm['arm']}: no finished run at {run}")
        settings = arm.get("decoding")
        if arm.get("tune"):
            settings, _ = search([RecordedSplit.record(str(best_checkpoint(run)), "val")])
        if settings is None:
            summary = json.loads((run / "test" / "summary.json").read_text())
            result = {"summary": summary, "diagnostics": summary["diagnostics"]}
        else:
            test_root = yaml.safe_load((run / ".hydra" / "config.yaml").read_text())["data"]["test_root"]
            result = evaluate(best_checkpoint(run), Path(test_root), settings)
        steps = next((o.split("=")[1] for o in overrides_of(run) or [] if o.startswith("trainer.max_steps=")), "")
        row = row_of(arm["arm"], arm["change"], run, result, steps)
        row.update(object=arm.get("object", spec.get("object", "")), overrides=run_overrides(run),
                   decoding="configured" if settings is None else json.dumps(settings, sort_keys=True))  # fmt: skip
        rows.append(row)
        print(f"{arm['arm']}: test AP {row['ap']:.4f}", flush=True)
    lines = [spec.get("title", "A/B"), "", f"| arm | object | {RESULT_HEADER} | decoding | overrides |",
             "|" + "---|" * 15]  # fmt: skip
    lines += [f"| {r['arm']} | {r['object']} | {result_cells(r)} | {r['decoding']} | `{r['overrides']}` |" for r in rows]
    notes = spec.get("notes")
    write_tables(out, ("object", *FIELDS, "overrides"), rows, lines + (["", notes] if notes else []))
    return rows


def write_tables(out: Path, fields: tuple[str, ...], rows: list[dict[str, Any]], lines: list[str]) -> None:
    """``ab.csv`` (the rows) and ``ab.md`` (the markdown ``lines``) under ``out``; prints the table."""
    out.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    (out / "ab.csv").write_text(buf.getvalue())
    (out / "ab.md").write_text("\n".join(lines).rstrip("\n") + "\n")
    print("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--collect", type=Path, default=None, help="YAML spec of finished runs (no training)")
    parser.add_argument("--train", type=Path)
    parser.add_argument("--test", type=Path)
    parser.add_argument("--foreign", type=Path, default=None)
    parser.add_argument("--object", default="bunny")
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--arms", nargs="+", default=list(ARMS))
    parser.add_argument("--runs-dir", type=Path, default=REPO_ROOT / "outputs" / "ab")
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "learning")
    args = parser.parse_args(argv)
    if args.collect is not None:
        collect(args.collect, args.runs_dir, args.out)
        return 0
    if args.train is None or args.test is None:
        parser.error("--train and --test are required (or --collect)")
    from opnet.tools.tune_decoding import RecordedSplit, search

    base = [f"object={args.object}", "data=ipa", f"data.root={args.train.resolve()}",
            f"data.test_root={args.test.resolve()}", "data.num_workers=0", "trainer.max_epochs=100000",
            "trainer.enable_progress_bar=false", "example_predictions=0"]  # fmt: skip
    rows = []
    for arm in [a for a in ARMS if a in args.arms]:
        change, tuned_from, extra = ARMS[arm]
        steps = args.steps
        if arm == "V5":  # bf16 for as many minutes as fp32 (V2) trained: steps scaled by the speed-up
            minutes = {a: train_minutes(args.runs_dir / f"{args.object}_{a}") for a in ("V2", "V4")}
            steps = round(args.steps * minutes["V2"] / minutes["V4"])
        if tuned_from is None:
            run = args.runs_dir / f"{args.object}_{arm}"
            train_arm(run, [*base, *extra, f"trainer.max_steps={steps}"])
            ckpt, settings = best_checkpoint(run), None
        else:
            run = args.runs_dir / f"{args.object}_{tuned_from}"
            ckpt = best_checkpoint(run)
            settings, _ = search([RecordedSplit.record(str(ckpt), "val")])
        result = evaluate(ckpt, args.test, settings)
        row = row_of(arm, change, run, result, steps)
        row["decoding"] = "configured" if settings is None else json.dumps(settings, sort_keys=True)
        if args.foreign is not None:
            row["foreign_ap"] = evaluate(ckpt, args.foreign, settings)["summary"]["ap"]
        rows.append(row)
        print(f"{arm}: test AP {row['ap']:.4f}" + (f", foreign AP {row['foreign_ap']:.4f}" if args.foreign else ""), flush=True)
    lines = [f"A/B on {args.object}: {args.steps} steps each (batch 16), seed 0, same data; test AP on "
             f"{args.test.name}" + (f", foreign AP on {args.foreign.name}" if args.foreign else ""), "",
             f"| arm | {RESULT_HEADER} | foreign AP |", "|" + "---|" * 13]  # fmt: skip
    lines += [f"| {r['arm']} | {result_cells(r)} | "
              f"{'' if r.get('foreign_ap') in (None, '') else format(r['foreign_ap'], '.3f')} |" for r in rows]  # fmt: skip
    write_tables(args.out, FIELDS, rows, lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
