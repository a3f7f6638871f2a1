"""The dense-pile benchmark: Siléane-like bulk piles of 70-80 parts seen by the Siléane bunny
camera from above; per object, generate the training piles, train, and score piles of another
seed, all within one budget on this machine.

    python scripts/bench/bench_dense.py --objects bunny ring_screw --gen-cycles 96 --views 8 --minutes 40

Per object: training piles (``--gen-cycles`` cycles = ``--gen-cycles / --views`` simulated piles
of ``--drops`` parts, seed 0, ``scene=bulk``, ``--camera-file`` at the recipe's height sized to the part, or
at ``--camera-height`` as it stands) and test
piles of another seed (seed 1, one view per pile, ``--test-piles`` piles) are generated (or
completed) under ``--data-dir``; ``train.py experiment=dense`` trains on the training piles for
``--minutes`` (at the throughput calibrated on this machine, or ``--steps``) and is scored on
the test piles' scenes with at least ``--test-min-objects`` parts (default 70: the benchmark's
70-80-part piles). Generation minutes are measured while generating (a dataset that was already
complete counts the minutes recorded when it was made, in ``<data>/bench_generation.json``).

Writes ``dense.csv`` and ``README.md`` under ``--out`` (default ``results/dense``): per object and
configuration the held-out AP with the diagnostics and the budget split (generation minutes,
training minutes). Rows of earlier invocations (other objects or configurations) are kept.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from opnet.paths import REPO_ROOT
from opnet.studies import best_checkpoint, fmt, merge_csv, read_summary
from opnet.studies.results import DENSE_HEADLINE as HEADLINE
from opnet.studies.scenes import dense_scene
from opnet.studies.training import calibrate_steps, summarize, train

CAMERA = REPO_ROOT / "conf" / "cameras" / "sileane_bunny.yaml"
TARGET = 0.5
ROW_FIELDS = (
    "object", "config", "gen_minutes", "train_minutes", "total_minutes", "train_scenes", "piles", "views",
    "test_scenes", "steps", "ap", "map", "f1", "target", "found", "no_hypothesis", "position", "orientation",
    "conflict", "confident_fp_per_scene", "duplicates_per_scene", "t_err_mm_p50", "r_err_deg_p50", "run",
    "budget_minutes", "test_curve", "command", "extra_tests", "tuned",
)  # fmt: skip


def generate(obj: str, out: Path, cycles: int, drops: int, seed: int, views: int, camera: Path,
             height: float | None, workers: int = 2, physics: str | None = None, settings: list[str] | None = None) -> float:
    """Generate (or complete) dense piles (``settings``: further scene settings, ``KEY=VALUE``); returns the
    minutes it took to make them (recorded)."""
    from opnet.cli.evaluate import resolve_object
    from opnet.synthesis import generate_dataset

    record = out / "bench_generation.json"
    done = json.loads(record.read_text()) if record.is_file() else {"minutes": 0.0}
    scene = dense_scene(camera, height, views, physics, settings or ())
    print(f"[{obj}] data: {out} ({cycles} cycles = {-(-cycles // views)} piles x {views} views, {drops} drops, "
          f"seed {seed})", flush=True)
    start = time.perf_counter()
    report = generate_dataset(resolve_object(obj), out, cycles, drops, workers=workers, seed=seed, scene=scene,
                              progress=False, previews=2)
    if report.cycles_generated:
        done["minutes"] += (time.perf_counter() - start) / 60.0
        done["scenes_per_second"] = report.scenes_per_second
        record.write_text(json.dumps(done, indent=2) + "\n")
    print(f"[{obj}]   {report.cycles_generated} cycles made, {report.cycles_skipped} present; "
          f"{done['minutes']:.1f} generation minutes in all", flush=True)
    return float(done["minutes"])


def recipe_settings(obj: str, settings: list[str], views: int, camera: Path, height: float | None) -> list[str]:
    """The training piles' further scene settings with the recipe's ``scene.view_spin=auto`` decided for the part
    (``view_spin=true`` joins them where it turns the part's views), unless given."""
    from opnet.cli.evaluate import resolve_object
    from opnet.synthesis.spin import resolve_view_spin

    if any(kv.startswith("view_spin=") for kv in settings):
        return list(settings)
    scene = dense_scene(camera, height, views, None, settings)
    return [*settings, "view_spin=true"] if resolve_view_spin(scene, resolve_object(obj)).view_spin else list(settings)


def folder_tag(settings: list[str]) -> str:
    """The training piles' folder suffix of their further scene settings (``view_spin=false``, the generator's
    default, names none: the piles made before the recipe decided it keep their folder)."""
    return "".join(f"_{kv.replace('=', '-')}" for kv in settings if kv != "view_spin=false")


def tests_of(obj: str, specs: list[str]) -> list[str]:
    """The ``NAME=DIR`` of the ``[OBJECT:]NAME=DIR`` specs that apply to ``obj`` (all without OBJECT)."""
    out = []
    for spec in specs:
        target, sep, rest = spec.partition(":")
        if "=" not in (rest if sep else spec):
            raise SystemExit(f"error: --extra-test {spec!r}, expected [OBJECT:]NAME=DIR")
        if not sep or target == obj:
            out.append(rest if sep else spec)
    return out


def evaluate(ckpt: Path, dest: Path, test_root: str | None = None, extra: list[str] | None = None) -> dict[str, Any]:
    """eval.py's summary of ``ckpt`` (with the arguments ``extra``) on its own test split, or on all scenes of
    ``test_root``."""
    cmd = [sys.executable, str(REPO_ROOT / "eval.py"), f"ckpt={ckpt}", f"out={dest}", "examples=2",
           *([f"data.test_root={Path(test_root).resolve()}"] if test_root else []), *(extra or [])]
    with open(dest.with_suffix(".log"), "w") as log:
        subprocess.run(cmd, check=True, cwd=REPO_ROOT, stdout=log, stderr=subprocess.STDOUT)
    return json.loads((dest / "summary.json").read_text())


def extra_tests(ckpt: Path, run_dir: Path, tests: list[str], tag: str = "") -> str:
    """Score ``ckpt`` on each ``NAME=DIR`` dataset (all its scenes, e.g. piles another generator made,
    ``scripts/experiments/sileane/sileane_rerender.py``) with eval.py; ``NAME AP (found %)`` per dataset."""
    out = []
    for spec in tests:
        name, _, folder = spec.partition("=")
        s = evaluate(ckpt, run_dir / f"eval_{name}{tag}", folder)
        d = s["diagnostics"]
        out.append(f"{name} {s['ap']:.3f} (found {100 * d['matched'] / max(d['to_find'], 1):.0f} %, "
                   f"{s['num_scenes']} scenes)")
        print(f"  {name}{tag}: AP {s['ap']:.4f} on {s['num_scenes']} scenes of {folder}", flush=True)
    return "; ".join(out)


def recipe_tuning(run_dir: Path) -> dict[str, Any] | None:
    """What the run's recipe chose when it tuned its decoding after training (train.py's ``tune_decoding``;
    :func:`opnet.cli.decoding_search.tune_in_place`), None where it does not tune. A run trained before its
    recipe tuned (and so not trained again) is tuned now, as train.py would have, and its test scored again."""
    from opnet.tools import tune_decoding as td

    record = run_dir / "tune_val" / td.TUNED_RECORD
    if record.is_file():
        return json.loads(record.read_text())
    stride = recipe_setting(run_dir, "tune_decoding")
    if stride is None:
        return None
    ckpt = best_checkpoint(run_dir)
    assert ckpt is not None
    print(f"  {run_dir}: tuning the decoding after training, as its recipe now does", flush=True)
    tuned = td.tune_in_place(ckpt, int(stride), run_dir / "tune_val")
    evaluate(ckpt, run_dir / "test")
    return tuned


def recipe_setting(run_dir: Path, key: str) -> Any:
    """The run's config value of ``key``: as saved, or (a key its config predates) as its overrides compose now."""
    import yaml
    from hydra import compose, initialize_config_dir

    from opnet.paths import config_dir

    saved = yaml.safe_load((run_dir / ".hydra" / "config.yaml").read_text())
    if key in saved:
        return saved[key]
    overrides = [o for o in yaml.safe_load((run_dir / ".hydra" / "overrides.yaml").read_text())
                 if not o.startswith("hydra.")]
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        return compose(config_name="train", overrides=overrides).get(key)


def tuned_decoding(run_dir: Path, tests: list[str], recipe: dict[str, Any] | None, stride: int = 8) -> str:
    """A line for the table. Where the recipe tuned its decoding (``recipe``, :func:`recipe_tuning`): what it
    changed, and the test AP of the decoding as configured. Elsewhere the decoding tuned on the run's validation
    split (every ``stride``-th scene; ``opnet-tune-decoding``): where it differs from the configured one,
    ``checkpoints/tuned.ckpt`` decodes with it and is scored on the test split and ``tests``."""
    from opnet.tools import tune_decoding as td

    ckpt = best_checkpoint(run_dir)
    assert ckpt is not None
    if recipe is not None:
        if not recipe["changed"]:
            return "the recipe's tuning kept the configured decoding"
        s = evaluate(ckpt, run_dir / "test_configured", extra=td.decoding_arguments(recipe["configured"]))
        return f"the recipe tuned {recipe['changed']} on validation (configured decoding: AP {s['ap']:.3f})"
    split = td.RecordedSplit.record(str(ckpt), "val", stride)
    best, rows = td.search([split])
    td.write_table(rows, run_dir / "tune_val")
    if best == td.current_settings(split.parameterization):
        return "configured decoding is the best on validation"
    dest = run_dir / "checkpoints" / "tuned.ckpt"
    td.write_tuned_checkpoint(ckpt, dest, best)
    s = evaluate(dest, run_dir / "test_tuned")
    changed = {k: v for k, v in best.items() if td.current_settings(split.parameterization)[k] != v}
    others = extra_tests(dest, run_dir, tests, "_tuned")
    return f"{changed}: test AP {s['ap']:.3f}" + (f"; {others}" if others else "")


def split_sizes(run_dir: Path) -> dict[str, int]:
    """Scenes per split of a run, as its train.log reports them (training piles held out for
    validation or left out by ``data.train_groups`` are not training scenes)."""
    log = run_dir / "train.log"
    found = re.findall(r"dataset .*?: \{'train': (\d+), 'val': (\d+), 'test': (\d+)\}", log.read_text()) if log.is_file() else []
    return dict(zip(("train", "val", "test"), map(int, found[-1]), strict=True)) if found else {}


def test_curve(run_dir: Path) -> str:
    """The held-out test AP measured during a run: ``<train minutes>: <AP>`` at each test epoch."""
    path = REPO_ROOT / run_dir / "learning_curve.csv"
    if not path.is_file():
        return ""
    points = [r for r in csv.DictReader(path.open()) if r.get("test_ap")]
    return ", ".join(f"{float(r['train_minutes']):.0f}: {float(r['test_ap']):.3f}" for r in points)


def headline(rows: list[dict[str, Any]], config: str = HEADLINE) -> list[str]:
    """The README's first table: the ``config`` rows (the recipe within the 60-minute budget), with the
    budget split and the scores on the piles of the other generators."""
    picked = [r for r in rows if r["config"] == config]
    if not picked:
        return []
    lines = [f"## The recipe within 60 minutes (`--config {config}`)", "",
             "| object | generation min | training min | **total min** | training scenes | **test AP** | target | found % | "
             "t / r p50 | other generators' piles | decoding tuned on validation |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in picked:
        lines.append(f"| {r['object']} | {fmt(r['gen_minutes'], 'f1')} | {fmt(r['train_minutes'], 'f1')} | "
                     f"**{fmt(r['total_minutes'], 'f1')}** | {r['train_scenes']} | **{fmt(r['ap'])}** | {r['target']} | "
                     f"{fmt(r['found'], 'pct')} | {fmt(r['t_err_mm_p50'], 'f1')} mm / {fmt(r['r_err_deg_p50'], 'f1')}° | "
                     f"{r.get('extra_tests') or ''} | {r.get('tuned') or ''} |")
    lines += ["", "Commands:", ""]
    lines += [f"- {r['object']}: `{r.get('command') or '?'}`" for r in picked]
    return lines + ["", "## Every configuration measured", ""]


def write_readme(out: Path, rows: list[dict[str, Any]], title: str = "Dense-pile benchmark") -> None:
    learning = Path(os.path.relpath(REPO_ROOT / "results" / "learning" / "README.md", out.resolve())).as_posix()
    lines = [
        f"# {title}", "",
        "Siléane-like bulk piles (70-80 parts, most of them more than half hidden) seen from above by the camera of "
        "the Siléane bunny dataset (`conf/cameras/sileane_bunny.yaml`, 1.5 m above the floor for the bunny; for another "
        "part the recipe scales the rig by D / the bunny's D, `scene.rig_d`, except where the row's command gives "
        "`--camera-height`; the ring screw's rows were made at 1.5 m before the rig was sized).\n\nPer object, on this "
        "2-core CPU: training piles generated and a model trained within the budget; held-out AP (Brégier, max "
        "occlusion 0.5) on the scenes with at least 70 parts of piles of another seed. Diagnostics as in "
        f"[the learning benchmark]({learning}).\n\n*budget min*: the training budget the step count was "
        "calibrated for (`--minutes`: the throughput of 50 steps measured at the start); *train min*: the wall "
        "minutes the run took, which exceed the budget when other jobs shared the machine or validation took long; "
        "*test AP during training*: the held-out test AP at the test epochs (wall training minutes: AP), so the AP "
        "reached within a shorter budget can be read off.", "",
        "| object | config | gen min | budget min | train min | total min | train scenes (of piles x views made) | "
        "test scenes | **test AP** | target | MAP | F1 | found % | no hyp % | position % | orientation % | "
        "conflict % | conf. FP/scene | dup/scene | t p50 mm | r p50 ° | test AP during training | "
        "piles of other generators | decoding tuned on validation |",
        "|" + "---|" * 24,
    ]  # fmt: skip
    lines[4:4] = headline(rows)
    for r in rows:
        lines.append(
            f"| {r['object']} | {r['config']} | {fmt(r['gen_minutes'], 'f1')} | {fmt(r.get('budget_minutes', ''), 'f1')} | "
            f"{fmt(r['train_minutes'], 'f1')} | {fmt(r['total_minutes'], 'f1')} | {r['train_scenes']} ({r['piles']} x "
            f"{r['views']}) | {r['test_scenes']} | **{fmt(r['ap'])}** | {r['target']} | {fmt(r['map'])} | "
            f"{fmt(r['f1'])} | {fmt(r['found'], 'pct')} | {fmt(r['no_hypothesis'], 'pct')} | {fmt(r['position'], 'pct')} | "
            f"{fmt(r['orientation'], 'pct')} | {fmt(r['conflict'], 'pct')} | {fmt(r['confident_fp_per_scene'], 'f1')} | "
            f"{fmt(r['duplicates_per_scene'], 'f1')} | {fmt(r['t_err_mm_p50'], 'f1')} | {fmt(r['r_err_deg_p50'], 'f1')} | "
            f"{r.get('test_curve') or ''} | {r.get('extra_tests') or ''} | {r.get('tuned') or ''} |"
        )
    lines += ["", "Commands (one per row):", ""]
    lines += [f"- {r['object']} {r['config']}: `{r.get('command') or '?'}`" for r in rows]
    (out / "README.md").write_text("\n".join(lines) + "\n")


def repo_relative(arg: str) -> str:
    """A command-line argument as the table records it: a path inside the repository relative to its root."""
    path = Path(arg)
    if path.is_absolute() and path.resolve().is_relative_to(REPO_ROOT.resolve()):
        return str(path.resolve().relative_to(REPO_ROOT.resolve()))
    return arg


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", nargs="+", default=["bunny", "ring_screw"])
    ap.add_argument("--config", default="dense", help="name of this configuration in the table")
    ap.add_argument("--gen-cycles", type=int, default=96)
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--drops", type=int, default=75)
    ap.add_argument("--test-piles", type=int, default=12)
    ap.add_argument("--test-min-objects", type=int, default=70)
    ap.add_argument("--camera-file", type=Path, default=CAMERA)
    ap.add_argument("--camera-height", type=float, default=None,
                    help="metres above the bin floor, as it stands (default: the recipe's 1.5 m for the bunny's D, "
                         "scaled to the part; the benchmark rows made before the rig was sized used 1.5)")
    ap.add_argument("--minutes", type=float, default=40.0)
    ap.add_argument("--steps", type=int, default=None, help="fixed step budget (skips the calibration)")
    ap.add_argument("--data-dir", type=Path, default=REPO_ROOT / "outputs" / "data" / "dense")
    ap.add_argument("--runs-dir", type=Path, default=REPO_ROOT / "outputs" / "dense")
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "dense")
    ap.add_argument("--extra", nargs="*", default=[], help="further Hydra overrides of train.py")
    ap.add_argument("--train-scene", nargs="*", default=[], metavar="KEY=VALUE",
                    help="further scene settings of the training piles alone (e.g. view_spin=true); their folder is "
                         "named with them. The recipe's scene.view_spin=auto is decided for each part unless given")
    ap.add_argument("--extra-test", action="append", default=[], metavar="[OBJECT:]NAME=DIR",
                    help="also score the model (of OBJECT only, if given) on all scenes of DIR, e.g. "
                         "bunny:sileane=outputs/data/sileane_rerender (scripts/experiments/sileane/sileane_rerender.py)")
    ap.add_argument("--pybullet-piles", type=int, default=0, metavar="N",
                    help="also generate N one-view piles of seed 2 with the other physics engine (pybullet) and score "
                         "the model on them as the extra test 'pybullet' (0: none)")
    ap.add_argument("--validations", type=int, default=None,
                    help="validate this many times, evenly spaced, the last at the final step (default: every epoch)")
    ap.add_argument("--tune", action="store_true",
                    help="tune the decoding on validation; a better one goes into checkpoints/tuned.ckpt, scored too")
    ap.add_argument("--title", default="Dense-pile benchmark", help="the rendered page's heading")
    ap.add_argument("--generate-only", action="store_true", help="make (or complete) the datasets, then stop")
    ap.add_argument("--readme-only", action="store_true", help="re-render README.md from dense.csv, then stop")
    args = ap.parse_args(argv)
    if args.readme_only:
        rows = merge_csv(args.out / "dense.csv", ROW_FIELDS, [], ("object", "config"))
        for r in rows:
            r["test_curve"] = test_curve(Path(r["run"])) or r.get("test_curve", "")
            r["train_scenes"] = split_sizes(REPO_ROOT / r["run"]).get("train", r["train_scenes"])
        write_readme(args.out, merge_csv(args.out / "dense.csv", ROW_FIELDS, rows, ("object", "config")), args.title)
        print((args.out / "README.md").read_text())
        return 0
    command = shlex.join(["python", "scripts/bench/bench_dense.py",
                          *map(repo_relative, argv if argv is not None else sys.argv[1:])])
    for kv in args.train_scene:
        if not re.fullmatch(r"[a-z_]+=[A-Za-z0-9_.-]+", kv):
            raise SystemExit(f"error: --train-scene {kv!r}: expected KEY=VALUE (a scene setting, e.g. view_spin=true)")
    rows = []
    for obj in args.objects:
        settings = recipe_settings(obj, args.train_scene, args.views, args.camera_file, args.camera_height)
        # the training piles of other scene settings are other piles: a folder of their own
        train_tag = folder_tag(settings)
        train_root = args.data_dir / f"{obj}_train_c{args.gen_cycles}_v{args.views}_d{args.drops}_s0{train_tag}"
        test_root = args.data_dir / f"{obj}_test_p{args.test_piles}_d{args.drops}_s1"
        gen_minutes = generate(obj, train_root, args.gen_cycles, args.drops, 0, args.views, args.camera_file,
                               args.camera_height, settings=settings)
        generate(obj, test_root, args.test_piles, args.drops, 1, 1, args.camera_file, args.camera_height)
        tests = tests_of(obj, args.extra_test)
        unmade = []
        if args.pybullet_piles:
            other = args.data_dir / f"{obj}_pybullet_p{args.pybullet_piles}_d{args.drops}_s2"
            try:
                generate(obj, other, args.pybullet_piles, args.drops, 2, 1, args.camera_file, args.camera_height,
                         physics="pybullet")
                tests.append(f"pybullet={other}")
            except RuntimeError as exc:  # a pile the other engine cannot make costs that test, not the part's run
                print(f"[{obj}] the other engine's test set was not made, the run goes on without it: {exc}",
                      flush=True)
                unmade.append(f"pybullet not made: {exc}")
        if args.generate_only:
            continue
        overrides = ["experiment=dense", f"object={obj}", "data=ipa", f"data.root={train_root}", "data.generate=null",
                     f"data.test_root={test_root}", f"data.test_min_objects={args.test_min_objects}", *args.extra]
        steps = args.steps or calibrate_steps(overrides, args.minutes)
        run_dir = args.runs_dir / f"{obj}_{args.config}"
        print(f"[{obj}] training {args.config}: {steps} steps -> {run_dir}", flush=True)
        train(overrides, run_dir, steps, test_every=4, validations=args.validations)
        recipe = recipe_tuning(run_dir)
        row, _ = summarize(obj, args.config, run_dir, steps)
        summary = read_summary(run_dir)
        row.update(gen_minutes=gen_minutes, total_minutes=gen_minutes + float(row["train_minutes"]),
                   train_scenes=split_sizes(run_dir).get("train", args.gen_cycles * args.drops),
                   piles=-(-args.gen_cycles // args.views),
                   views=args.views, test_scenes=summary["num_scenes"], target=TARGET,
                   budget_minutes="" if args.steps else args.minutes, test_curve=test_curve(run_dir), command=command,
                   extra_tests="; ".join(filter(None, [extra_tests(best_checkpoint(run_dir), run_dir, tests), *unmade])),
                   tuned=tuned_decoding(run_dir, tests, recipe) if args.tune or recipe else "")
        print(f"[{obj}] test AP {row['ap']:.4f} ({row['gen_minutes']:.1f} generation + {row['train_minutes']:.1f} "
              f"training minutes)", flush=True)
        rows.append(row)
    if args.generate_only:
        return 0
    all_rows = merge_csv(args.out / "dense.csv", ROW_FIELDS, rows, ("object", "config"))
    write_readme(args.out, all_rows, args.title)
    print((args.out / "README.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
