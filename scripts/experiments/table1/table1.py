"""The paper's Table I on this machine: every parameterization x object x seed at one step budget.

    python scripts/experiments/table1/table1.py --objects bunny,ring_screw,gear_shaft --seeds 0 1 2 --steps 1350
    python scripts/experiments/table1/table1.py --collect            # only re-make results/table1/ from the finished runs
    python scripts/experiments/table1/table1.py --combine results/table1/vanilla_eve_ap results/table1/z_mp_si
                                                  # one table from tables made at different times

Each arm is ``python train.py experiment=table1 object=O parameterization=P seed=S
trainer.max_steps=N`` in ``--runs-dir``/``P_O_sS`` (its console in ``console.log``); an arm whose
``test/summary.json`` exists is not run again, so an interrupted table resumes. Arms run one after
another (they share the machine); ``--jobs K`` runs K at once, for a GPU that several arms share
(``scripts/dev/gpu_check.sh`` runs an object's arms that way on a lent GPU machine). Then ``--out`` (default ``results/table1/``) gets
``README.md`` and ``table1.csv``: per object and parameterization the mean ± sample sd of the
held-out test AP over the seeds, the share of required parts found and the median errors, and the
paper's number beside it (Table I of Kleeberger et al., ICRA 2021: its bunny, pepper and T-LESS 20 are
the Siléane ones, its ring screw and gear shaft the Fraunhofer IPA ones), plus the two acceptance checks (AP >= vanilla on
two of three objects; EVE >= vanilla). The table comes twice: with the configured decoding (the
settings tuned once on bunny-vanilla, ``decoding=tuned``), and with the decoding of each arm tuned on
its own validation split (``opnet-tune-decoding``, cached in the arm's ``decoding_tuned.json``;
``--no-tune`` skips it), then scored on the held-out test split.

On a lent GPU machine (``results/table1/pepper_tless20``): each object's dataset is generated here
(``python train.py experiment=table1 object=pepper trainer.max_steps=1 test=false``) and packed
(``scripts/dev/carry_dataset.py``); there ``ONLY="install import unpack arms" ARMS_DATA=<archive>
ARMS_OBJECT=pepper ARMS_S=380 OPNET_SHARED=<a folder with the meshes> scripts/dev/gpu_check.sh`` trains
its 18 arms at once and brings back ``arms_pepper.tar.gz``; here ``--collect --runs-dir <unpacked>
--objects pepper,tless20 --machine "<the GPU>"`` makes the table. ``ARMS_S`` also stops the arms'
fitting 150 s before it ends (``trainer.max_time``): an arm stopped that way is marked in
``arms.csv`` (``time_limited``, ``steps``: its last validation) and counted in the README.

``--combine DIR ...`` makes ``--out`` from tables this script wrote earlier (each ``DIR`` with its
``table1.csv`` and the machine line of its ``README.md``; a table made on another machine or day
keeps its source named beside every row): one table in the paper's order, the first ``DIR`` that
has a cell giving it, and the cells two tables both have side by side (the same arms on two
machines: how far the rest of the table compares).

``experiment=table1`` (conf/experiment/table1.yaml) is the small preset on 20-part piles
generated once per object. The default budget, 1350 steps of batch 16 per arm, is the quickstart's
measured training length on this 2-core CPU (about 4.5 minutes in bf16): 6 x 3 x 3 = 54 arms take
about four hours.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import os
import re
import statistics
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

from opnet.paths import REPO_ROOT, best_checkpoint
from opnet.studies import mean_sd, train_command
from opnet.studies.sweeps import PAPER_ORDER, cell_text, collect, table

#: Table I of the paper (OP-Net with L_ori1 is "vanilla"), on the objects opnet ships configs for
PAPER = {
    "vanilla": {"bunny": 0.92, "ring_screw": 0.88, "gear_shaft": 0.99, "pepper": 0.98, "tless20": 0.85},
    "eve": {"bunny": 0.92, "ring_screw": 0.94, "gear_shaft": 0.98, "pepper": 0.97, "tless20": 0.88},
    "ap": {"bunny": 0.92, "ring_screw": 0.96, "gear_shaft": 0.99, "pepper": 0.99, "tless20": 0.87},
    "z": {"bunny": 0.85, "ring_screw": 0.92, "gear_shaft": 0.95, "pepper": 0.95, "tless20": 0.84},
    "mp": {"bunny": 0.92, "ring_screw": 0.84, "gear_shaft": 0.95, "pepper": 0.91, "tless20": 0.70},
    "si": {"bunny": 0.30, "ring_screw": 0.56, "gear_shaft": 0.88, "pepper": 0.97, "tless20": 0.46},
}
DEFAULT_STEPS = 1350
#: the two decodings of every table, as its README names them
DECODINGS = {"configured": "configured (`decoding=tuned`: the bunny-vanilla settings for every arm)",
             "tuned on val": ("tuned per arm on its own validation split (`opnet-tune-decoding`; the test split "
                              "never seen by the tuning)")}


def _names(folder: str) -> list[str]:
    return sorted(p.stem for p in (REPO_ROOT / "conf" / folder).glob("*.yaml"))


def _choice(text: str, known: list[str], flag: str) -> list[str]:
    values = [v.strip() for v in text.split(",") if v.strip()]
    if not values:
        raise ValueError(f"{flag}: empty; expected some of {known}")
    unknown = [v for v in values if v not in known]
    if unknown:
        raise ValueError(f"{flag}: unknown {unknown}; expected some of {known}")
    return list(dict.fromkeys(values))


def parse(argv: list[str] | None) -> argparse.Namespace:
    """The request, checked: every mistake is one line naming the flag (ValueError)."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--objects", default="bunny,ring_screw,gear_shaft")
    ap.add_argument("--parameterizations", default=",".join(PAPER_ORDER))
    ap.add_argument("--seeds", nargs="*", type=int, default=[0, 1, 2])
    ap.add_argument("--steps", type=int, default=DEFAULT_STEPS, help="optimizer steps per arm (the equal budget)")
    ap.add_argument("--runs-dir", type=Path, default=REPO_ROOT / "outputs" / "table1")
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "table1")
    ap.add_argument("--extra", nargs="*", default=[], help="more train.py overrides for every arm")
    ap.add_argument("--collect", action="store_true", help="only aggregate the finished arms")
    ap.add_argument("--no-tune", dest="tune", action="store_false",
                    help="skip tuning each arm's decoding on its validation split")
    ap.add_argument("--dry-run", action="store_true", help="print the arms' commands, run nothing")
    ap.add_argument("--jobs", type=int, default=1,
                    help="arms trained at once (one GPU shared; each builds its own scene cache and gets "
                         "cores / jobs threads); with tuning, each arm is tuned as soon as it is trained")
    ap.add_argument("--machine", default=None,
                    help="where the arms ran, for a table collected from arms trained on another machine "
                         "(default: this machine's CPU)")
    ap.add_argument("--tune-run", type=Path, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--combine", nargs="+", type=Path, default=None, metavar="DIR",
                    help="only merge tables written earlier (DIR/table1.csv) into --out")
    args = ap.parse_args(argv)
    if args.combine is not None:
        missing = [str(d) for d in args.combine if not (d / "table1.csv").is_file()]
        if missing:
            raise ValueError(f"--combine: no table1.csv in {missing}")
        return args
    args.objects = _choice(args.objects, _names("object"), "--objects")
    args.parameterizations = _choice(args.parameterizations, _names("parameterization"), "--parameterizations")
    if not args.seeds:
        raise ValueError("--seeds: none given; a spread needs at least one seed (three for the table)")
    if any(s < 0 for s in args.seeds) or len(set(args.seeds)) != len(args.seeds):
        raise ValueError(f"--seeds {args.seeds}: expected distinct integers >= 0")
    if args.steps < 1:
        raise ValueError(f"--steps {args.steps}: expected an integer >= 1")
    if args.jobs < 1:
        raise ValueError(f"--jobs {args.jobs}: expected an integer >= 1")
    return args


def arms(args: argparse.Namespace) -> list[tuple[Path, list[str]]]:
    """(run folder, train.py command) of every arm, objects outermost (each object's data made once)."""
    out = []
    for obj in args.objects:
        for param in args.parameterizations:
            for seed in args.seeds:
                run = args.runs_dir / f"{param}_{obj}_s{seed}"
                cmd = train_command(["experiment=table1", f"object={obj}", f"parameterization={param}", f"seed={seed}",
                                     f"trainer.max_steps={args.steps}", "trainer.enable_progress_bar=false", *args.extra],
                                    run)
                if args.jobs > 1:  # arms at once would all build one shared scene cache at the same time
                    cmd.insert(-1, f"data.cache_dir={run / 'cache'}")
                out.append((run, cmd))
    return out


def run_arms(todo: list[tuple[Path, list[str]]], jobs: int = 1, tune: bool = False) -> list[str]:
    """Run the unfinished arms, ``jobs`` at a time (each then tuned, with ``tune``, in a process of
    its own); returns the names of the arms that failed."""
    threads = max(1, (os.cpu_count() or 1) // jobs)
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)} if jobs > 1 else None

    def one(k: int, run: Path, cmd: list[str]) -> str | None:
        if not (run / "test" / "summary.json").is_file():
            run.mkdir(parents=True, exist_ok=True)
            start = time.perf_counter()
            with (run / "console.log").open("w") as log:
                code = subprocess.run(cmd, cwd=REPO_ROOT, stdout=log, stderr=subprocess.STDOUT, env=env, check=False).returncode
            state = "done" if code == 0 else f"FAILED (exit {code}, see {run / 'console.log'})"
            print(f"[{k}/{len(todo)}] {run.name}: {state} in {time.perf_counter() - start:.0f} s", flush=True)
            if code:
                return run.name
        if tune and jobs > 1 and not (run / "decoding_tuned.json").is_file():
            with (run / "tune.log").open("w") as log:
                subprocess.run([sys.executable, __file__, "--tune-run", str(run)], cwd=REPO_ROOT, stdout=log,
                               stderr=subprocess.STDOUT, env=env, check=False)
        return None

    if jobs == 1:
        results = [one(k, run, cmd) for k, (run, cmd) in enumerate(todo, 1)]
    else:
        with ThreadPoolExecutor(jobs) as pool:
            results = list(pool.map(lambda a: one(*a), [(k, run, cmd) for k, (run, cmd) in enumerate(todo, 1)]))
    return [name for name in results if name]


#: what Lightning logs when ``trainer.max_time`` stops an arm before its steps
TIME_LIMITED = "Time limit reached"


def steps_done(run: Path) -> int | None:
    """The optimizer step of the arm's last validation (``learning_curve.csv``): the model its test
    scored was chosen among those; short of the budget when a time limit stopped the arm."""
    curve = run / "learning_curve.csv"
    if not curve.is_file():
        return None
    last = list(csv.DictReader(curve.open()))[-1:]
    return int(last[0]["step"]) if last and str(last[0].get("step", "")).isdigit() else None


def _mean(values: list[float | None]) -> float | None:
    known = [v for v in values if v is not None]
    return statistics.fmean(known) if known else None


def tuned_decoding(run: Path) -> dict[str, object] | None:
    """Decoding tuned on the arm's validation split (opnet-tune-decoding), then its held-out
    test scored with it; cached in ``decoding_tuned.json``. None for an arm without a checkpoint."""
    cache = run / "decoding_tuned.json"
    if cache.is_file():
        return json.loads(cache.read_text())
    ckpt = best_checkpoint(run)
    if ckpt is None:
        print(f"warning: {run.name}: no checkpoint, decoding not tuned", file=sys.stderr)
        return None
    from opnet.metrics.diagnostics import diagnose
    from opnet.tools import tune_decoding

    with contextlib.redirect_stdout(io.StringIO()):
        best, _ = tune_decoding.search([tune_decoding.RecordedSplit.record(str(ckpt), "val")])
        test = tune_decoding.RecordedSplit.record(str(ckpt), "test")
    obj = test.parameterization.obj
    scenes = test.scenes(best)
    diag = diagnose(scenes, obj.pose_space, obj.diameter, max_occlusion=test.max_occlusion)
    result = {"settings": best, "checkpoint": ckpt.name, "ap": test.ap(best),
              "found": diag.matched / diag.to_find if diag.to_find else None,
              "t_err_mm_p50": diag.t_err_mm_p50, "r_err_deg_p50": diag.r_err_deg_p50}
    tmp = cache.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, indent=1))
    os.replace(tmp, cache)
    return result


def with_tuned(rows: list[dict[str, object]], runs_dir: Path) -> list[dict[str, object]]:
    """The arms' rows scored with their tuned decoding (arms that could not be tuned left out)."""
    out = []
    for r in rows:
        tuned = tuned_decoding(runs_dir / str(r["run"]))
        if tuned is not None:
            out.append({**r, **{k: tuned[k] for k in ("ap", "found", "t_err_mm_p50", "r_err_deg_p50")},
                        "decoding": "tuned on val"})
    return out


def short_of_budget(rows: list[dict[str, object]], steps: int) -> str:
    """The README's sentence on arms whose last validation came before ``steps`` (a time limit)."""
    short = sorted(int(r["steps"] or 0) for r in rows if r.get("time_limited"))  # type: ignore[call-overload]
    if not short:
        return ""
    return (f" **{len(short)} of {len(rows)} arms stopped short of the {steps} steps (a time limit): their last "
            f"validation, whose checkpoints the test chose among, came at {short[0]}-{short[-1]} steps (median "
            f"{statistics.median(short):.0f}); `arms.csv` has each arm's.**")


def report(rows: list[dict[str, object]], steps: int, requested: int | None = None,
           tuned: list[dict[str, object]] | None = None) -> tuple[str, str]:
    """(README.md text, table1.csv text) of the finished arms (``requested``: arms asked for;
    ``tuned``: the same arms with the decoding tuned on their validation split)."""
    lines = ["# Table I on this machine" if MACHINE is None else "# Table I on another machine (below)", "",
             (f"Held-out test AP (Brégier, max occlusion 0.5) per parameterization and object, mean ± sample sd over the "
              f"seeds (runs); each arm `experiment=table1`, {steps} steps; the paper's Table I value in brackets. "
              "Made by `python scripts/experiments/table1/table1.py` (its docstring has the command and the budget)."
              + (f" **Arms finished: {len(rows)} of {requested}.**" if requested and len(rows) < requested else "")
              + short_of_budget(rows, steps)), ""]
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["decoding", "parameterization", "object", "runs", "ap_mean", "ap_sd", "paper", "found", "t_err_mm_p50",
                "r_err_deg_p50"])
    blocks = [(DECODINGS["configured"], "configured", rows)]
    if tuned:
        blocks.append((DECODINGS["tuned on val"], "tuned on val", tuned))
    for title, key, block in blocks:
        lines += [f"Decoding {title}:", ""]
        lines += _table(block, key, w)
        lines.append("")
    return "\n".join(lines) + "\n", buf.getvalue()


def _table(rows: list[dict[str, object]], decoding: str, w: Any) -> list[str]:
    """Markdown lines of one table (and its CSV rows through ``w``)."""
    params, objects, cells = table(rows)
    lines = ["| parameterization | " + " | ".join(objects) + " | found % (mean) | t p50 mm | r p50 ° |",
             "|" + "---|" * (len(objects) + 4)]
    for p in params:
        texts = []
        for o in objects:
            vals = cells.get((p, o))
            paper = PAPER.get(p, {}).get(o)
            texts.append(cell_text(vals) + (f" [{paper:.2f}]" if paper is not None else ""))
            if vals:
                mine = [r for r in rows if r["parameterization"] == p and r["object"] == o]
                mean, sd = mean_sd(vals)
                w.writerow([decoding, p, o, len(vals), f"{mean:.6f}", f"{sd:.6f}", "" if paper is None else paper,
                            *(("" if m is None else f"{m:.4f}") for m in
                              (_mean([r["found"] for r in mine]), _mean([r["t_err_mm_p50"] for r in mine]),
                               _mean([r["r_err_deg_p50"] for r in mine])))])  # type: ignore[misc]
        mine = [r for r in rows if r["parameterization"] == p]
        found, t50, r50 = (_mean([r[k] for r in mine]) for k in ("found", "t_err_mm_p50", "r_err_deg_p50"))  # type: ignore[misc]
        lines.append(f"| {p} | " + " | ".join(texts) + " | " + " | ".join(
            "–" if v is None else f"{v * (100 if k == 0 else 1):.1f}" for k, v in enumerate((found, t50, r50))) + " |")
    lines += ["", *checks(cells, objects)]
    return lines


def checks(cells: dict[tuple[str, str], list[float]], objects: list[str]) -> list[str]:
    """The two acceptance checks on the means over seeds: AP >= vanilla on two of three objects;
    EVE >= vanilla."""
    def mean(p: str, o: str) -> float | None:
        return mean_sd(cells[(p, o)])[0] if cells.get((p, o)) else None

    out = []
    for other, need in (("ap", 2), ("eve", len(objects))):
        pairs = [(o, mean(other, o), mean("vanilla", o)) for o in objects]
        pairs = [(o, a, b) for o, a, b in pairs if a is not None and b is not None]
        if not pairs:
            continue
        wins = [o for o, a, b in pairs if a >= b]
        need = min(need, len(pairs))
        verdict = "holds" if len(wins) >= need else "does not hold"
        out.append(f"- {other} >= vanilla on {len(wins)} of {len(pairs)} objects ({', '.join(wins) or 'none'}); "
                   f"needed {need}: {verdict}")
    return out


#: ``--machine``: where the collected arms ran, when not on this machine
MACHINE: str | None = None


def machine() -> str:
    """The CPU the arms ran on, and whether it computes bf16 natively (the training's precision path);
    ``--machine`` when they ran elsewhere."""
    if MACHINE:
        return MACHINE
    import platform

    from opnet.hardware import cpu_has_native_bf16

    name = platform.processor() or platform.machine()
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.is_file():
        name = next((line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines()
                     if line.startswith("model name")), name)
    return f"{name}, {'bf16' if cpu_has_native_bf16() else 'fp32'}"


def arms_csv(rows: list[dict[str, object]], tuned: list[dict[str, object]] | None) -> str:
    """One line per arm (seed), configured and tuned decoding side by side, with the machine: the
    per-seed values behind every mean ± sd, kept when a later table is made elsewhere."""
    by_run = {str(r["run"]): r for r in tuned or []}
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["parameterization", "object", "seed", "ap", "found", "t_err_mm_p50", "r_err_deg_p50", "ap_tuned",
                "found_tuned", "run", "machine", "steps", "time_limited"])
    where = machine()
    fmt = lambda v: "" if v is None else f"{float(v):.6f}"
    for r in sorted(rows, key=lambda r: (str(r["object"]), str(r["parameterization"]), str(r["seed"]))):
        t = by_run.get(str(r["run"]), {})
        w.writerow([r["parameterization"], r["object"], r["seed"], fmt(r["ap"]), fmt(r["found"]), fmt(r["t_err_mm_p50"]),
                    fmt(r["r_err_deg_p50"]), fmt(t.get("ap")), fmt(t.get("found")), r["run"], where,
                    "" if r.get("steps") is None else r["steps"], int(bool(r.get("time_limited")))])
    return buf.getvalue()


def _source_machine(folder: Path) -> str:
    readme = folder / "README.md"
    lines = readme.read_text().splitlines() if readme.is_file() else []
    found = next((line for line in lines if line.startswith("Machine:")), None)
    where = found.removeprefix("Machine:").split("(the arms'")[0].strip().rstrip(",") if found else "not recorded"
    short = re.search(r"\*\*(\d+ of \d+ arms stopped short of the \d+ steps[^*]*?)(; `arms.csv`[^*]*)?\*\*", "\n".join(lines))
    return f"{where}; **{short.group(1)}**" if short else where


def combine(folders: list[Path], rel_to: Path) -> tuple[str, str]:
    """(README.md text, table1.csv text) of one table merged from the tables in ``folders``."""
    sources, first, both = [], {}, []
    for k, folder in enumerate(folders, 1):
        rows = list(csv.DictReader((folder / "table1.csv").open()))
        sources.append((k, folder, _source_machine(folder), rows))
        for r in rows:
            key = (r["decoding"], r["parameterization"], r["object"])
            if key in first:
                both.append((first[key], (k, r)))
            else:
                first[key] = (k, r)
    order = {p: i for i, p in enumerate(PAPER_ORDER)}
    keys = sorted(first, key=lambda key: (key[0] != "tuned on val", order.get(key[1], 99), key[2]))
    objects = list(dict.fromkeys(key[2] for key in keys))
    cell = lambda r: f"{float(r['ap_mean']):.3f} ± {float(r['ap_sd']):.3f} ({r['runs']})"
    lines = ["# Table I", "",
             "Held-out test AP (Brégier, max occlusion 0.5), mean ± sample sd over seeds (runs), per parameterization "
             "and object; the paper's Table I value in brackets; the source table of each row as [k]. Merged by "
             f"`python scripts/experiments/table1/table1.py --combine {' '.join(os.path.relpath(f, REPO_ROOT) for f in folders)}` from:", ""]
    for k, folder, where, rows in sources:
        params = ", ".join(dict.fromkeys(r["parameterization"] for r in rows))
        lines.append(f"- [{k}] [`{os.path.relpath(folder, rel_to)}/`]({os.path.relpath(folder, rel_to)}/README.md): "
                     f"{params}; machine: {where}")
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["decoding", "parameterization", "object", "runs", "ap_mean", "ap_sd", "paper", "found", "t_err_mm_p50",
                "r_err_deg_p50", "source"])
    for decoding in dict.fromkeys(key[0] for key in keys):
        lines += ["", f"Decoding {DECODINGS.get(decoding, decoding)}:", "",
                  "| parameterization | " + " | ".join(objects) + " | source |", "|" + "---|" * (len(objects) + 2)]
        cells: dict[tuple[str, str], list[float]] = {}
        for p in dict.fromkeys(key[1] for key in keys if key[0] == decoding):
            texts, used = [], set()
            for o in objects:
                k_r = first.get((decoding, p, o))
                if k_r is None:
                    texts.append("–")
                    continue
                k, r = k_r
                used.add(k)
                cells[(p, o)] = [float(r["ap_mean"])]
                texts.append(cell(r) + (f" [{float(r['paper']):.2f}]" if r["paper"] else ""))
                w.writerow([r[c] for c in ("decoding", "parameterization", "object", "runs", "ap_mean", "ap_sd", "paper",
                                           "found", "t_err_mm_p50", "r_err_deg_p50")] + [k])
            lines.append(f"| {p} | " + " | ".join(texts) + " | " + ", ".join(f"[{k}]" for k in sorted(used)) + " |")
        lines += ["", *checks(cells, objects)]
    if both:
        lines += ["", "The same arms in two tables (the first is the one above):", "",
                  "| decoding | parameterization | object | first | second |", "|---|---|---|---|---|"]
        lines += [f"| {a[1]['decoding']} | {a[1]['parameterization']} | {a[1]['object']} | {cell(a[1])} [{a[0]}] | "
                  f"{cell(b[1])} [{b[0]}] |" for a, b in both]
    return "\n".join(lines) + "\n", buf.getvalue()


def _write(out: Path, files: dict[str, str]) -> None:
    out.mkdir(parents=True, exist_ok=True)
    for name, body in files.items():
        tmp = out / f".{name}.tmp"
        tmp.write_text(body)
        os.replace(tmp, out / name)


def main(argv: list[str] | None = None) -> int:
    try:
        args = parse(argv)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.combine is not None:
        text, table_csv = combine(args.combine, args.out)
        _write(args.out, {"README.md": text, "table1.csv": table_csv})
        print(text)
        return 0
    global MACHINE
    MACHINE = args.machine
    if args.tune_run is not None:  # one arm's tuning, in a process of its own (--jobs)
        tuned_decoding(args.tune_run)
        return 0
    todo = arms(args)
    if args.dry_run:
        for _, cmd in todo:
            print(" ".join(cmd[1:]))
        return 0
    failed = [] if args.collect else run_arms(todo, args.jobs, args.tune)
    wanted = {run.name for run, _ in todo}
    rows = [r for r in collect(args.runs_dir) if str(r["run"]) in wanted] if args.runs_dir.is_dir() else []
    for r in rows:
        run = args.runs_dir / str(r["run"])
        r["steps"] = steps_done(run)
        r["time_limited"] = (run / "console.log").is_file() and TIME_LIMITED in (run / "console.log").read_text()
    if not rows:
        print(f"error: {args.runs_dir}: no finished arm of this table", file=sys.stderr)
        return 2
    tuned = with_tuned(rows, args.runs_dir) if args.tune else None
    text, table_csv = report(rows, args.steps, len(todo), tuned)
    text += f"Machine: {machine()} (the arms' training path); every arm's seed in `arms.csv`.\n"
    _write(args.out, {"README.md": text, "table1.csv": table_csv, "arms.csv": arms_csv(rows, tuned)})
    print(text)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
