"""The figures of the README and of the docs pages, rendered from the committed results files, so
that they cannot drift.

Every measured number of README.md and ``docs/*.md`` sits between ``<!-- figures:NAME -->`` and
``<!-- /figures:NAME -->`` markers and is rendered here from a file under ``results/``. Each block
below must sit in at least one of those files (it may sit in several); a marker of any other name is
an error. The relative links a block holds are written from the file it sits in (``results/...``
in the README, ``../results/...`` in a docs page):

| block | source |
|---|---|
| quickstart | ``results/quickstart/summary.json`` (``--run-quickstart`` makes it, pictures included) |
| defaults | ``results/defaults/defaults.csv`` (``--record-run <run dir> --command ... --wall-s ...``) |
| learning | ``results/learning/learning.csv`` (``scripts/bench/bench_learning.py``) |
| ab | ``results/learning/ab.csv`` (``scripts/experiments/learning/ab_learning.py --collect``) |
| speed | ``results/speed/{train,data}.csv`` (``scripts/bench/bench_train.py`` / ``bench_data.py --out``) |
| inference | ``results/speed/infer.csv`` (``scripts/bench/bench_infer.py --out``), ``inference_check.csv`` (``scripts/bench/check_inference.py``) |
| benchmarks | ``results/benchmarks.csv`` (each row names the script that printed its figure) |
| sensor | ``results/sensor/{holes,ab}.csv`` (``scripts/experiments/sensor/sensor_table.py``, ``scripts/experiments/sensor/sensor_ab.py``) |
| real_frame | ``results/real_frame/summary.json`` (``scripts/experiments/real_frame/real_frame.py``) |
| framing | ``results/framing/framing.csv`` (``scripts/experiments/framing/framing_table.py``) |
| real_ipd | ``results/real_ipd/real_ipd.csv`` (``scripts/experiments/real_ipd/real_ipd.py``) |
| real_ipd_seeds | ``results/real_ipd/seeds.csv`` (``scripts/experiments/real_ipd/real_ipd.py --seeds``) |
| cells | ``results/cells/cells.csv`` (``scripts/experiments/cells/cells.py``), ``results/real_ipd/cell.csv`` (``--stage real``) |
| verification | ``results/verification/verification.csv`` (``scripts/experiments/verification/verify_ab.py``) |
| headline | the README's one table: ``results/quickstart/summary.json``, ``dense/dense.csv``, ``real_ipd/<the cell-file model cell_headline picks>.csv``, ``new_parts/new_parts.csv``, ``table1/table1.csv`` |
| pictures | the PNGs under ``results/`` (the ceiling chart is drawn here from its CSVs) |
| pictures_data | the real frame's overlay and the sensor models' missing depth |
| pictures_method | the ceiling chart |

Usage::

    python scripts/dev/readme_figures.py            # rewrite the blocks of README.md and docs/*.md (and the ceiling chart)
    python scripts/dev/readme_figures.py --check    # exit 1, with a diff, when a page and results disagree
    python scripts/dev/readme_figures.py --run-quickstart   # run the quickstart from an empty root, record it
"""

from __future__ import annotations

import argparse
import csv
import difflib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from opnet.cli.console import format_duration
from opnet.paths import REPO_ROOT
from opnet.studies import mean_sd_text, train_command
from opnet.studies.results import DENSE_HEADLINE, cpu_model, seed_spread

RESULTS = REPO_ROOT / "results"
DOCS = REPO_ROOT / "docs"
DOCS_PREFIX = "../"  # docs/*.md sit one folder below the repository root, where results/ is
BLOCK = re.compile(r"(<!-- figures:(?P<name>[a-z0-9_]+) -->\n)(?P<body>.*?)(<!-- /figures:(?P=name) -->)", re.S)
MARKER = re.compile(r"<!-- /?figures:(?P<name>[^ ]*) -->")
QUICKSTART_COMMAND = "python train.py experiment=quickstart"


def _csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _table(header: list[str], rows: list[list[Any]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


# ---------------------------------------------------------------------------------------------- blocks


def block_quickstart(results: Path, prefix: str = "") -> str:
    q = json.loads((results / "quickstart" / "summary.json").read_text())
    return (
        f"**Quickstart** — `{q['command']}` from an empty `outputs/`: generates {q['cycles']} cycles of the "
        f"built-in stepped `{q['object']}` ({q['dataset_scenes']} scenes at {q['resolution']} × {q['resolution']}, "
        f"up to {q['drops']} parts), trains the `{q['model']}` DenseNet-BC ({q['params_m']:.2f} M parameters) with "
        f"opnet's defaults and the {q['parameterization']} parameterization for {q['epochs']} epochs, and evaluates "
        f"the best checkpoint on its held-out cycles ({q['scenes']} scenes): **test AP {q['ap']:.4f}** "
        f"(MAP {q['map']:.4f}, F1 {q['f1']:.4f}, {100 * q['found']:.1f} % of the parts found), "
        f"**{format_duration(q['wall_s'])}** end to end on {q['machine']}"
        f"{quickstart_path_note(q)}. The console ends with that summary and the "
        f"paths of the checkpoint, TensorBoard logs, AP table and example prediction PNGs "
        f"([its last lines]({prefix}results/quickstart/console_tail.txt)).\n"
        f"{quickstart_seeds_table(results)}"
    )


def quickstart_path_note(q: dict[str, Any]) -> str:
    """The headline run's machine facts that change the model: its CPU and precision path."""
    if "precision_path" not in q:
        return ""
    return f" ({q['cpu']}, {q['precision_path']})"


def quickstart_seeds_table(results: Path) -> str:
    """Mean ± sd of the quickstart's test AP over training seeds, per CPU and precision path
    (``results/quickstart/seeds.csv``, ``scripts/experiments/quickstart/quickstart_seeds.py``); empty without the file."""
    path = results / "quickstart" / "seeds.csv"
    if not path.is_file():
        return ""

    def known(x: float, show: Any) -> str:  # NaN: one run (no sd), or every run generated data (no time)
        return "—" if x != x else show(x)

    rows = [[g["cpu"], "yes" if g["native_bf16"] else "no", f"**{g['precision_path']}**", ", ".join(g["seeds"]),
             f"**{g['ap_mean']:.3f} ± {known(g['ap_sd'], '{:.3f}'.format)}**",
             f"{g['ap_min']:.3f} – {g['ap_max']:.3f}", known(g["wall_s"], format_duration)]
            for g in seed_spread(_csv(path))]  # fmt: skip
    return (
        "\nThe precision path changes the model, so the figure to expect depends on the CPU: "
        "`trainer.precision=auto` trains in bf16 mixed precision where the CPU computes bf16 natively "
        "(AVX512-BF16 or AMX), else in fp32, and the console's `precision path:` line says which one a run took. "
        "Over training seeds (`python scripts/experiments/quickstart/quickstart_seeds.py --seeds 0 1 2 --precision auto 32`; the same "
        "data, made with MuJoCo like the run above; the sd is over seeds):\n\n"
        + _table(["CPU", "native bf16", "precision path", "seeds", "test AP mean ± sd", "min – max",
                  "train + test time per run"], rows)  # fmt: skip
        + "\n"
    )


def console_precision_path(console: str) -> str:
    """The precision path a train.py run printed (``precision path: bf16 mixed (...)`` -> ``bf16 mixed``)."""
    found = re.search(r"precision path: ([^(\n]+)", console)
    if not found:
        raise RuntimeError("the quickstart's console names no precision path")
    return found.group(1).strip()


def block_defaults(results: Path, prefix: str = "") -> str:
    rows = [[f"`{r['command']}`", f"**{float(r['ap']):.3f}**", f"{float(r['map']):.3f}", f"{float(r['f1']):.3f}",
             f"{100 * float(r['found']):.1f}", r["scenes"], format_duration(float(r["wall_s"])) + (f" ({r['note']})" if r["note"] else "")]
            for r in _csv(results / "defaults" / "defaults.csv")]  # fmt: skip
    return _table(["command", "test AP", "MAP", "F1", "found %", "test scenes", "wall time"], rows) + "\n"


def block_learning(results: Path, prefix: str = "") -> str:
    rows = []
    for r in _csv(results / "learning" / "learning.csv"):
        f = {k: float(r[k]) for k in ("train_minutes", "ap", "target", "found", "position", "orientation",
                                      "confident_fp_per_scene", "t_err_mm_p50", "r_err_deg_p50")}  # fmt: skip
        rows.append([r["object"], f"{r['parameterization']}, {r['rotation']}", f"{f['train_minutes']:.1f}",
                     f"**{f['ap']:.3f}**", f"{f['target']:g}", f"{100 * f['found']:.1f}", f"{100 * f['position']:.1f}",
                     f"{100 * f['orientation']:.1f}", f"{f['confident_fp_per_scene']:.1f}", f"{f['t_err_mm_p50']:.1f}",
                     f"{f['r_err_deg_p50']:.1f}"])  # fmt: skip
    header = ["object", "parameterization, rotation", "train min", "**test AP**", "target", "found %",
              "missed: position %", "orientation %", "conf. FP / scene", "t p50 mm", "r p50 °"]
    return _table(header, rows) + "\n"


def block_ab(results: Path, prefix: str = "") -> str:
    rows = [[r["object"], r["arm"], r["change"], f"{float(r['ap']):.3f}", f"{float(r['f1']):.3f}"]
            for r in _csv(results / "learning" / "ab.csv")]
    return _table(["object", "arm", "what changes", "test AP", "F1"], rows) + "\n"


def block_table1(results: Path, prefix: str = "") -> str:
    """Table I (scripts/experiments/table1/table1.py): held-out test AP, mean ± sd over seeds, the paper's value in
    brackets; the decoding tuned per arm on its validation split where the table has it."""
    rows = _csv(results / "table1" / "table1.csv")
    decoding = "tuned on val" if any(r["decoding"] == "tuned on val" for r in rows) else "configured"
    rows = [r for r in rows if r["decoding"] == decoding]
    objects = list(dict.fromkeys(r["object"] for r in rows))
    params = list(dict.fromkeys(r["parameterization"] for r in rows))
    cell = {(r["parameterization"], r["object"]): r for r in rows}

    def text(r: dict[str, str] | None) -> str:
        if r is None:
            return "–"
        paper = f" [{float(r['paper']):.2f}]" if r["paper"] else ""
        return f"{float(r['ap_mean']):.3f} ± {float(r['ap_sd']):.3f} ({r['runs']}){paper}"

    return _table(["parameterization", *objects], [[p, *(text(cell.get((p, o))) for o in objects)] for p in params]) + "\n"


def block_speed(results: Path, prefix: str = "") -> str:
    names = {"fp32": "fp32 (before)", "cl": "fp32 + channels-last", "bf16": "bf16 autocast",
             "bf16+cl": "bf16 + channels-last (default here)"}
    train = _csv(results / "speed" / "train.csv")
    ref = float(train[0]["images_per_s"])
    left = []
    for r in train:
        ips = float(r["images_per_s"])
        name = names.get(r["arm"], r["arm"]) if r["cache"] == "true" else f"{r['arm']}, files instead of the cache"
        left.append([name, f"{ips:.1f}" + (f" ({ips / ref:.2f}×)" if r["cache"] == "true" and ips != ref else "")])
    right = [[f"{int(r['scenes'])} scenes, {r['source']}", r["images_per_s"], f"{r['peak_rss_mb']} MB"]
             for r in _csv(results / "speed" / "data.csv")]
    rows = []
    for i in range(max(len(left), len(right))):
        a = left[i] if i < len(left) else ["", ""]
        b = right[i] if i < len(right) else ["", "", ""]
        rows.append([*a, "", *b])
    return _table(["training arm", "images/s", "", "data path, one epoch", "images/s", "peak RSS"], rows) + "\n"


def block_inference(results: Path, prefix: str = "") -> str:
    rows = _csv(results / "speed" / "infer.csv")
    head = rows[0]
    lines = [f"Roofline of this run: a 2048² fp32 matrix product, timed (warm) right before every repeat of every forward, "
             f"ran at {float(head['roofline_gflops']):.1f} GFLOP/s (median; range {head['roofline_range']}), so the "
             f"paper network's {float(head['forward_gflop']):.2f} GFLOP forward has a floor of "
             f"{1000 * float(head['forward_gflop']) / float(head['roofline_gflops']):.1f} ms per image. × floor = the "
             "median over the repeats of each forward's time over the floor at the rate measured beside it; "
             "ms are the best repeat and the median; GFLOP/s of the best.", ""]
    table = [[r["batch"], r["stage"], r["ms_batch"], r["ms_image"], r.get("ms_image_median", ""), r["gflops_per_s"],
              r["x_floor"]] for r in rows if not r["stage"].endswith("/ forward")]
    lines.append(_table(["batch", "stage", "ms / batch", "ms / image", "median ms / image", "GFLOP/s", "× floor"], table))
    e2e = [r for r in rows if r["stage"].endswith("/ forward")]
    lines += ["", "End-to-end (preprocess + forward + decode + averaging) / forward, batch 1, default path: "
              + ", ".join(f"{r['stage'].split()[1]} {float(r['x_floor']):.3f}" for r in e2e) + "."]
    check = _csv(results / "speed" / "inference_check.csv")
    lines += ["", "Poses of each path against fp32 eager on the quickstart model's 150 test scenes "
              "(`scripts/bench/check_inference.py`):", ""]
    lines.append(_table(["path", "hypotheses", "paired within 0.1 mm and 0.05°", "p99 Δt mm", "p99 Δr °", "AP"],
                        [[r["path"], r["hypotheses"], r["paired within 0.1 mm and 0.05 deg"], r["p99 dt mm"],
                          r["p99 dr deg"], r["AP"]] for r in check]))
    return "\n".join(lines) + "\n"


def block_benchmarks(results: Path, prefix: str = "") -> str:
    rows = [[f"`{r['command']}`", r["what"], r["figure"], r["target"]] for r in _csv(results / "benchmarks.csv")]
    return _table(["script", "what", "figure", "target"], rows) + "\n"


def block_sensor(results: Path, prefix: str = "") -> str:
    def pct(x: str) -> str:
        return "–" if x in ("", "nan") else f"{100 * float(x):.0f} %"

    rows = []
    for r in _csv(results / "sensor" / "holes.csv"):
        run = "–" if r["run_px"] in ("", "nan") else f"{float(r['run_px']):.0f} px"
        rows.append([r["source"], r["scenes"], f"{100 * float(r['missing']):.1f} %", f"{100 * float(r['missing_lit']):.1f} %",
                     pct(r["edge_runs"]), pct(r["right_nearer"]), run, pct(r["speckle"])])
    lines = [_table(["depth", "scenes", "missing", "missing, lit columns", "holes at depth edges",
                     "of those, right side nearer", "median hole run", "speckle (holes ≤ 4 px)"], rows), ""]
    ab = _csv(results / "sensor" / "ab.csv")
    sensors = list(dict.fromkeys(r["test_sensor"] for r in ab))
    ap = {(r["train_sensor"], r["test_sensor"]): float(r["ap"]) for r in ab}
    lines += [f"A/B on the same budget ({ab[0]['object']}, quickstart recipe, seed 0; test AP on {ab[0]['scenes']} "
              f"held-out scenes of seed 1 per column, [`results/sensor/ab.csv`]({prefix}results/sensor/ab.csv)):", ""]
    lines.append(_table(["trained on ↓ / tested on →", *sensors],
                        [[f"`sensor={t}`", *(f"{ap[(t, s)]:.4f}" for s in sensors)] for t in sensors]))
    return "\n".join(lines) + "\n"


def block_real_frame(results: Path, prefix: str = "") -> str:
    s = json.loads((results / "real_frame" / "summary.json").read_text())
    cam = s["camera"]
    return (f"camera from its `camera_params.txt` (fx {cam['fx']:g}, principal point ({cam['cx']:g}, {cam['cy']:g}), "
            f"{cam['width']} × {cam['height']}); **{s['hypotheses']} hypotheses, {s['above_min_score']} with a score "
            f"above {s['min_score']:g}** (top scores {', '.join(f'{x:.2f}' for x in s['top_scores'][:s['above_min_score']])}; "
            f"depths {', '.join(f'{x:.2f}' for x in s['depths_above_m'])} m).\n")


def block_dense(results: Path, prefix: str = "") -> str:
    """The dense-pile recipe within 60 minutes per object (the ``DENSE_HEADLINE`` rows)."""

    rows = []
    for r in _csv(results / "dense" / "dense.csv"):
        if r["config"] != DENSE_HEADLINE:
            continue
        tuned = re.search(r"test AP (\d\.\d+)", r.get("tuned") or "")
        rows.append([r["object"].replace("_", " "),
                     f"{float(r['gen_minutes']):.1f} + {float(r['train_minutes']):.1f} = {float(r['total_minutes']):.1f}",
                     f"**{float(r['ap']):.3f}**" + (f" ({float(tuned.group(1)):.3f})" if tuned else ""),
                     f"{100 * float(r['found']):.1f}", r.get("extra_tests") or "–"])
    return _table(["object", "generation + training min", "**held-out AP** (decoding tuned on validation)",
                   "found %", "other generators' piles (AP)"], rows) + "\n"


def block_new_parts(results: Path, prefix: str = "") -> str:
    """The new-parts benchmark: held-out AP per part against its target (results/new_parts/new_parts.csv)."""
    from opnet.studies.results import decoding_cell, fill_cell, other_engine_cell, refined_cell, symmetry_cell

    rows = [[r["object"], symmetry_cell(r), f"{float(r['d_mm']):.0f}", fill_cell(r),
             f"{float(r['gen_minutes']):.1f} + {float(r['train_minutes']):.1f}", decoding_cell(r),
             other_engine_cell(r), refined_cell(r), r["reason"]]
            for r in _csv(results / "new_parts" / "new_parts.csv")]
    return _table(["part", "symmetry (opnet-object)", "D mm", "bin fill", "generation + training min",
                   "**held-out AP** (the other decoding)", "other engine's piles (AP)",
                   "refined against the depth: held-out (other engine)", "target AP >= 0.6"], rows) + "\n"


def block_framing(results: Path, prefix: str = "") -> str:
    rows = [[f"`{r['fit']}`", f"{100 * float(r['input_share']):.0f} %", f"{100 * float(r['image_share']):.0f} %",
             f"{float(r['image_px_per_input_px']):.2f}", f"**{float(r['ap']):.4f}**"]
            for r in _csv(results / "framing" / "framing.csv")]
    return _table(["data.fit", "input showing image", "image reaching the input", "image px per input px",
                   "test AP"], rows) + "\n"


def block_real_ipd(results: Path, prefix: str = "") -> str:
    """The real Photoneo frames of IPD object 18 with their ground truth (scripts/experiments/real_ipd/real_ipd.py)."""
    pct = lambda v: f"{100 * float(v):.1f}"  # noqa: E731
    rows = [[r["visibility"], r["refine"], r["required"], f"**{float(r['ap']):.3f}**", pct(r["found"]),
             pct(r["no_hypothesis"]), pct(r["position"]), pct(r["orientation"]), f"{float(r['confident_fp_per_frame']):.1f}",
             "–" if r["t_err_mm_p50"] in ("", "nan") else f"{float(r['t_err_mm_p50']):.1f} / {float(r['r_err_deg_p50']):.1f}",
             f"{float(r['ms_per_frame']):.0f}" if r["ms_per_frame"] else "–"]
            for r in _csv(results / "real_ipd" / "real_ipd.csv")]
    return _table(["visibility", "refine", "required", "**AP**", "found %", "no hypothesis %", "position %",
                   "orientation %", "confident FP / frame", "t mm / r ° p50", "refine ms / frame"], rows) + "\n"


def block_real_ipd_seeds(results: Path, prefix: str = "") -> str:
    """The real-frame recipe over training seeds: AP per refinement, then mean ± sd (real_ipd.py --seeds)."""
    runs = _csv(results / "real_ipd" / "seeds.csv")
    keys = ["generated_ap", "real_ap", "real_ap_icp", "real_ap_search"]
    rows = [[r["seed"], r["parameterization"], *(f"{float(r[k]):.3f}" for k in keys), f"{float(r['found_search']):.1f}"]
            for r in runs]

    def spread(key: str, digits: int) -> str:
        return mean_sd_text([float(r[key]) for r in runs], digits)

    rows.append([f"mean ± sd ({len(runs)})", "", *(f"**{spread(k, 3)}**" if k == "real_ap_search" else spread(k, 3)
                                                  for k in keys), spread("found_search", 1)])
    return _table(["training seed", "parameterization", "generated piles AP", "real AP", "real AP, ICP",
                   "**real AP, search**", "found %, search"], rows) + "\n"


def block_cells(results: Path, prefix: str = "") -> str:
    """A cell whose bin moves: generated piles where the bin stood in training and where it did not
    (scripts/experiments/cells/cells.py), and the real frames scored by the recipe (results/real_ipd/cell.csv; its earlier
    scorings with the search, before its speed settings changed and before the refinement was made faster,
    cell_first_scoring.csv and cell_second_scoring.csv) and by the one command's model (cell_one_command.csv; the one it replaced, cell_one_command_grid16.csv)."""
    real = results / "real_ipd" / "cell.csv"
    # the one command's model on the same frames, and the one it replaced
    one_command = [results / "real_ipd" / f"cell_one_command{s}.csv" for s in ("_grid16", "")]
    cell_files = [results / "real_ipd" / f"{arm}.csv" for arm in CELL_FILE_ARMS]  # set up from opnet-cell's files
    earlier = [{**r, "refine": f"{r['refine']} ({label})"}
               for name, label in (("first", "first scoring, earlier speed settings"), ("second", "second scoring"))
               for path in [results / "real_ipd" / f"cell_{name}_scoring.csv"]
               for r in (_csv(path) if path.is_file() else []) if r["refine"] != "none"]
    rows = [[r["policy"], r["model"], r["placement"], r["refine"], r["scenes"], f"**{float(r['ap']):.3f}**",
             f"{100 * float(r['found']):.1f}", f"{100 * float(r['found_of_all']):.1f}" if r.get("found_of_all") else "–",
             f"{float(r['ms_per_frame']):.0f}" if r["ms_per_frame"] else "–"]
            for r in [*_csv(results / "cells" / "cells.csv"), *earlier, *(_csv(real) if real.is_file() else []),
                      *(r for path in one_command if path.is_file() for r in _csv(path)), *(r for path in cell_files if path.is_file() for r in _csv(path))]]
    return _table(["input (data.roi)", "model", "basket", "refine", "frames", "**AP**", "found %",
                   "found % of the frame's parts", "refine ms / frame"], rows) + "\n"


def block_verification(results: Path, prefix: str = "") -> str:
    """Decoded, ICP and the depth-agreement search on held-out generated piles (scripts/experiments/verification/verify_ab.py)."""
    rows = [[r["object"].replace("_", " "), r["decoding"], r["refine"], r["scenes"], f"**{float(r['ap']):.3f}**",
             f"{100 * float(r['found']):.1f}", f"{float(r['icp_ms_per_image']):.0f}" if r.get("icp_ms_per_image") else "–"]
            for r in _csv(results / "verification" / "verification.csv")]
    return _table(["part", "decoding", "refine", "frames", "**AP**", "found %", "refine ms / frame"], rows) + "\n"


#: the refinement the cell's model records (a flat part's recipe), the one its headline figure is scored with
CELL_REFINE = "search_flat"
#: the cell's models set up from opnet-cell's files (scripts/experiments/cells/cells.py --stage cell --cell-file N)
CELL_FILE_ARMS = ("cell_ipd", "cell_ipd_area")


def cell_headline(results: Path) -> str:
    """The one of CELL_FILE_ARMS in the headline, by the rule fixed before the real frames were scored: the higher
    AP on its worse generated held-out placement with CELL_REFINE (results/cells/README.md: the bin where it stood
    in training, or moved; the study's piles)."""
    rows = [r for r in _csv(results / "cells" / "cells.csv") if r["refine"] == CELL_REFINE and ", piles " not in r["model"]]
    worst = {arm: min((float(r["ap"]) for r in rows if r["model"].startswith(f"{arm} (")), default=-1.0)
             for arm in CELL_FILE_ARMS}  # fmt: skip
    return max(worst, key=lambda arm: worst[arm])


def block_headline(results: Path, prefix: str = "") -> str:
    """The README's one headline table: a row per user's path (the quickstart, dense piles, the cell, new parts,
    Table I), its figure drawn from the same results files as the full tables of docs/results.md."""
    q = json.loads((results / "quickstart" / "summary.json").read_text())
    quickstart = (f"test AP **{q['ap']:.3f}** on {q['scenes']} held-out scenes, {format_duration(q['wall_s'])} "
                  f"end to end on a 2-core CPU")
    dense = [r for r in _csv(results / "dense" / "dense.csv") if r["config"] == DENSE_HEADLINE]
    dense_text = (", ".join(f"{r['object'].replace('_', ' ')} **{float(r['ap']):.3f}**" for r in dense)
                  + f" held-out AP on 70–75-part piles, ≤ {max(float(r['total_minutes']) for r in dense):.0f} min "
                  "generation + training per part")
    # the cell set up by opnet-cell from the frames' depth (no ground truth), scored with its recorded refinement
    cell = next(r for r in _csv(results / "real_ipd" / f"{cell_headline(results)}.csv") if r["refine"] == CELL_REFINE)
    cell_text = (f"AP **{float(cell['ap']):.3f}** on {cell['scenes']} real Photoneo frames of flat plates, the cell set "
                 f"up by `opnet-cell` from their depth (`{CELL_REFINE}`, the refinement the model records)")
    parts = _csv(results / "new_parts" / "new_parts.csv")
    targets = "/".join(sorted({f"{float(r['target']):g}" for r in parts}))
    parts_text = (f"{sum(r['met'] == '1' for r in parts)} of {len(parts)} parts nobody here tuned for meet AP ≥ {targets} ("
                  + ", ".join(f"{r['object']} {float(r['ap']):.3f}" for r in parts) + ")")
    table1 = [r for r in _csv(results / "table1" / "table1.csv") if r["decoding"] == "tuned on val"]
    objects = list(dict.fromkeys(r["object"] for r in table1))
    best = {o: max((r for r in table1 if r["object"] == o), key=lambda r: float(r["ap_mean"])) for o in objects}
    winners = sorted({r["parameterization"] for r in best.values()})
    aps = [float(r["ap_mean"]) for r in best.values()]
    table1_text = (f"best per object: {', '.join(f'`{w}`' for w in winners)} on all {len(objects)} objects, held-out AP "
                   f"**{min(aps):.3f}–{max(aps):.3f}** (mean over {'/'.join(sorted({r['runs'] for r in best.values()}))} seeds) "
                   "at a small CPU budget")
    rows = [["quickstart", f"`{q['command']}`", quickstart, f"[results]({prefix}docs/results.md#quickstart)"],
            ["dense bulk piles", "`python train.py experiment=dense object=<o> scene.camera_file=<camera>`", dense_text,
             f"[results/dense]({prefix}results/dense/README.md)"],
            ["your cell, real frames", "`python train.py experiment=cell cell=<N> object=<o>`", cell_text,
             f"[results/cells]({prefix}results/cells/README.md)"],
            ["new parts", "`opnet-object <mesh>`, then the dense recipe", parts_text,
             f"[results/new_parts]({prefix}results/new_parts/README.md)"],
            ["Table I, the six parameterizations", "`python scripts/experiments/table1/table1.py`", table1_text,
             f"[results/table1]({prefix}results/table1/README.md)"]]  # fmt: skip
    return _table(["result", "command", "figure", "results page"], rows) + "\n"


PICTURES = [
    ("quickstart/overlay.png", "Quickstart: the densest held-out scene, each estimated part's model drawn on the depth image"),
    ("quickstart/pr_curve.png", "Quickstart: the test split's precision-recall curve (Brégier protocol)"),
    ("learning/curves.png", "Learning benchmark: held-out AP against training minutes, four objects"),
    ("ceiling/ceiling.png", "Parameterization ceiling: the AP of a perfect network per parameterization and object"),
    ("real_frame/overlay.png", "The real Siléane structured-light frame: the bunny model's detections above 0.5 drawn on it"),
    ("sensor/holes.png", "Missing depth (red): the real frame, then generated scenes with sensor=ideal, structured_light, tof"),
]


def _pictures(results: Path, prefix: str, pictures: list[tuple[str, str]]) -> str:
    """The pictures two a row, with their captions; ``src`` written from the page's folder."""
    cells = []
    for rel, caption in pictures:
        if not (results / rel).is_file():
            raise FileNotFoundError(f"{results / rel}: picture missing (python scripts/dev/readme_figures.py [--run-quickstart])")
        cells.append(f'<img src="{prefix}results/{rel}" width="420" alt="{caption}"><br><sub>{caption}</sub>')
    rows = ["<tr>" + "".join(f"<td>{c}</td>" for c in cells[i : i + 2]) + "</tr>" for i in range(0, len(cells), 2)]
    return "<table>" + "\n".join(rows) + "</table>\n"


def block_pictures(results: Path, prefix: str = "") -> str:
    return _pictures(results, prefix, PICTURES)


def block_pictures_data(results: Path, prefix: str = "") -> str:
    """docs/data.md: the real frame and the sensor models' missing depth."""
    return _pictures(results, prefix, [p for p in PICTURES if p[0].startswith(("real_frame/", "sensor/"))])


def block_pictures_method(results: Path, prefix: str = "") -> str:
    """docs/method.md: the parameterization ceiling."""
    return _pictures(results, prefix, [p for p in PICTURES if p[0].startswith("ceiling/")])


BLOCKS = {"quickstart": block_quickstart, "defaults": block_defaults, "learning": block_learning, "ab": block_ab,
          "speed": block_speed, "benchmarks": block_benchmarks, "pictures": block_pictures,
          "inference": block_inference, "sensor": block_sensor, "framing": block_framing,
          "real_frame": block_real_frame, "pictures_data": block_pictures_data,
          "pictures_method": block_pictures_method, "table1": block_table1, "dense": block_dense,
          "new_parts": block_new_parts,
          "real_ipd": block_real_ipd, "real_ipd_seeds": block_real_ipd_seeds, "cells": block_cells,
          "verification": block_verification, "headline": block_headline}


def docs_pages(docs: Path = DOCS) -> dict[Path, str]:
    """The docs pages (``docs/*.md``) and their texts."""
    return {path: path.read_text() for path in sorted(docs.glob("*.md"))}


def blocks_of(text: str, name: str = "text") -> list[str]:
    """The names of the figures blocks ``text`` holds; ValueError naming ``name`` when a marker
    names no known block or has no pair."""
    markers = [m.group("name") for m in MARKER.finditer(text)]
    unknown = sorted(set(markers) - set(BLOCKS))
    blocks = [m.group("name") for m in BLOCK.finditer(text)]
    if unknown or len(markers) != 2 * len(blocks):
        raise ValueError(f"{name}: figures blocks: unknown {unknown}, markers without their pair: "
                         f"{sorted(set(markers) - set(blocks))}")
    return blocks


def check_blocks(texts: dict[str, str]) -> None:
    """Every marker of ``texts`` (file name -> text) is a known, closed block, and every known block
    sits in at least one of them; ValueError otherwise."""
    found = {block for name, text in texts.items() for block in blocks_of(text, name)}
    missing = sorted(set(BLOCKS) - found)
    if missing:
        raise ValueError(f"figures blocks: missing {missing} (each must sit in README.md or a docs page)")


def render_text(text: str, results: Path = RESULTS, prefix: str = "") -> str:
    """``text`` with the figures blocks it holds rendered from ``results``, their relative links
    starting with ``prefix`` (the way from the file's folder to the repository root)."""
    return BLOCK.sub(lambda m: m.group(1) + BLOCKS[m.group("name")](results, prefix) + m.group(4), text)


def render(readme: str, results: Path = RESULTS, pages: dict[Path, str] | None = None) -> str:
    """The README with its figures blocks rendered from ``results``. Unknown or missing blocks are
    errors: each known block must sit in the README or in one of the docs ``pages`` (path -> text;
    by default those under docs/)."""
    pages = docs_pages() if pages is None else pages
    check_blocks({"README.md": readme, **{str(path): text for path, text in pages.items()}})
    return render_text(readme, results)


def render_page(page: str, results: Path = RESULTS) -> str:
    """A docs page (``docs/*.md``) with its figures blocks rendered, links written from docs/."""
    blocks_of(page, "docs page")
    return render_text(page, results, DOCS_PREFIX)


# ------------------------------------------------------------------------------------------ pictures


def draw_ceiling_chart(results: Path) -> Path:
    """Grouped bars of the ceiling AP (full view) per parameterization and object."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4), sharey=True)
    for ax, view in zip(axes, ("full_view", "close_view")):
        rows = _csv(results / "ceiling" / view / "ceiling.csv")
        params = list(dict.fromkeys(r["parameterization"] for r in rows))
        order = ["vanilla", "eve", "ap", "z", "mp", "si"]
        params = [p for p in order if p in params] + [p for p in params if p not in order]
        objects = list(dict.fromkeys(r["object"] for r in rows))
        ap = {(r["parameterization"], r["object"]): float(r["ap"]) for r in rows}
        width = 0.8 / len(objects)
        for j, obj in enumerate(objects):
            xs = [i + (j - (len(objects) - 1) / 2) * width for i in range(len(params))]
            ax.bar(xs, [ap.get((p, obj), 0.0) for p in params], width, label=obj)
        ax.set_xticks(range(len(params)), params)
        ax.set_ylim(0.9, 1.005)
        ax.set_title(view.replace("_", " "))
        ax.grid(axis="y", alpha=0.3)
    axes[0].set_ylabel("AP of a perfect network")
    axes[1].legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    out = results / "ceiling" / "ceiling.png"
    fig.savefig(out, dpi=110, metadata={"Software": None})
    plt.close(fig)
    return out


# ------------------------------------------------------------------------------------------ recording


def record_run(run_dir: Path, command: str, wall_s: float, note: str, into: Path) -> None:
    """Append a train run's test summary as a row of ``into`` (results/defaults/defaults.csv)."""
    from opnet.fileio.atomic import append_csv_rows

    d = json.loads((run_dir / "test" / "summary.json").read_text())
    g = d["diagnostics"]
    append_csv_rows(into, ["command", "object", "scenes", "ap", "map", "f1", "found", "wall_s", "note"],
                    [[command, d["object"], d["scenes"], f"{d['ap']:.4f}", f"{d['map']:.4f}", f"{d['f1']:.4f}",
                      f"{g['matched'] / max(g['to_find'], 1):.4f}", round(wall_s), note]])  # fmt: skip


def run_quickstart(results: Path, keep: Path | None) -> dict[str, Any]:
    """Run the README's quickstart in an empty root, as a new user would, and record its figures,
    its console's last lines, a prediction overlay of the densest test scene and the PR curve."""
    import yaml

    root = Path(keep) if keep else Path(tempfile.mkdtemp(prefix="opnet_quickstart_"))
    root.mkdir(parents=True, exist_ok=True)
    run_dir = root / "run"
    env = {**os.environ, "OPNET_ROOT": str(root), "PYOPENGL_PLATFORM": "egl"}
    start = time.monotonic()
    proc = subprocess.run(train_command(["experiment=quickstart"], run_dir), cwd=REPO_ROOT, env=env, capture_output=True,
                          text=True)
    wall = time.monotonic() - start
    if proc.returncode:
        raise RuntimeError(f"the quickstart failed (exit {proc.returncode}):\n{proc.stderr[-3000:]}")
    out = results / "quickstart"
    out.mkdir(parents=True, exist_ok=True)
    lines = [line for line in proc.stdout.splitlines() if line.strip()]
    tail = lines[-10:]
    (out / "console_tail.txt").write_text("\n".join(line.replace(str(root), "<root>") for line in tail) + "\n")
    summary = json.loads((run_dir / "test" / "summary.json").read_text())
    cfg = yaml.safe_load((run_dir / ".hydra" / "config.yaml").read_text())
    gen = cfg["data"]["generate"]
    ckpt = sorted((run_dir / "checkpoints").glob("epoch*.ckpt"))[-1]
    import torch

    params = sum(v.numel() for k, v in torch.load(ckpt, map_location="cpu", weights_only=True)["state_dict"].items()
                 if k.startswith("backbone.") and "running_" not in k and "num_batches" not in k)
    data_root = Path(cfg["data"]["root"].replace("${paths.root_dir}", str(root)))
    data_root = next((root / "outputs" / "data").iterdir()) if not data_root.is_dir() else data_root
    diag = summary["diagnostics"]
    q = {
        "command": QUICKSTART_COMMAND, "ap": summary["ap"], "map": summary["map"], "f1": summary["f1"],
        "recall_at_p50": summary["recall_at_p50"], "found": diag["matched"] / max(diag["to_find"], 1),
        "scenes": summary["scenes"], "wall_s": round(wall, 1), "object": cfg["object"]["name"],
        "cycles": gen["cycles"], "drops": gen["drops"], "resolution": (cfg.get("scene") or gen["scene"])["resolution"],
        "dataset_scenes": len(list((data_root / "p_depth").rglob("*.png"))), "model": "small",
        "params_m": params / 1e6, "parameterization": "vanilla", "epochs": cfg["trainer"]["max_epochs"],
        "machine": f"this {os.cpu_count()}-core CPU machine", "date": time.strftime("%Y-%m-%d"),
        "cpu": cpu_model(), "precision_path": console_precision_path(proc.stdout + proc.stderr),
        "checkpoint": ckpt.name,
    }  # fmt: skip
    (out / "summary.json").write_text(json.dumps(q, indent=1) + "\n")
    # the densest test scene (most parts; the first such), predicted with predict.py as a user would
    names = sorted(summary["per_scene"])
    densest = max(names, key=lambda n: (int(n.rsplit("_", 1)[1]), -names.index(n)))
    cycle, drop = densest.rsplit("_", 1)
    png = data_root / "p_depth" / cycle / f"{drop}_depth_uint16.png"
    pred = root / "predict"
    subprocess.run([sys.executable, str(REPO_ROOT / "predict.py"), f"ckpt={ckpt}", f"input={png}", f"out={pred}",
                    "overwrite=true", f"hydra.run.dir={root / 'predict_run'}"], cwd=REPO_ROOT, env=env, check=True,
                   capture_output=True)  # fmt: skip
    shutil.copyfile(pred / f"{png.stem}.png", out / "overlay.png")
    subprocess.run(["opnet-evaluate", "--gt", "test/gt", "--results", "test/results", "--object", q["object"],
                    "--plot", str((out / "pr_curve.png").resolve())], cwd=run_dir, check=True, capture_output=True)
    if not keep:
        shutil.rmtree(root, ignore_errors=True)
    return q


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--check", action="store_true", help="only compare; exit 1 when a page differs")
    parser.add_argument("--readme", type=Path, default=REPO_ROOT / "README.md")
    parser.add_argument("--docs", type=Path, default=DOCS, help="the folder of the docs pages (*.md)")
    parser.add_argument("--results", type=Path, default=RESULTS)
    parser.add_argument("--run-quickstart", action="store_true", help="run the quickstart and record its figures first")
    parser.add_argument("--keep", type=Path, help="with --run-quickstart: run in this folder and keep it")
    parser.add_argument("--record-run", type=Path, metavar="RUN_DIR", help="append a train run to results/defaults/defaults.csv")
    parser.add_argument("--command", help="with --record-run: the command that made the run")
    parser.add_argument("--wall-s", type=float, help="with --record-run: its wall time in seconds")
    parser.add_argument("--note", default="", help="with --record-run: a remark for the table")
    args = parser.parse_args(argv)
    if args.record_run:
        if not args.command or args.wall_s is None:
            parser.error("--record-run needs --command and --wall-s")
        record_run(args.record_run, args.command, args.wall_s, args.note, args.results / "defaults" / "defaults.csv")
    if args.run_quickstart:
        q = run_quickstart(args.results, args.keep)
        print(f"quickstart: test AP {q['ap']:.4f}, {format_duration(q['wall_s'])}")
    readme = args.readme.read_text()
    pages = docs_pages(args.docs)
    if not args.check:
        draw_ceiling_chart(args.results)
    files = {args.readme: (readme, render(readme, args.results, pages))}
    files.update({path: (page, render_page(page, args.results)) for path, page in pages.items()})
    drifted = [path for path, (text, rendered) in files.items() if rendered != text]
    if args.check:
        for path in drifted:
            text, rendered = files[path]
            sys.stdout.writelines(difflib.unified_diff(text.splitlines(True), rendered.splitlines(True),
                                                       str(path), "rendered from results/"))  # fmt: skip
        if drifted:
            print(f"\nfigures of {', '.join(map(str, drifted))} differ from results/: run python scripts/dev/readme_figures.py",
                  file=sys.stderr)
            return 1
        print(f"figures of README.md and {len(pages)} docs pages match results/")
        return 0
    for path, (text, rendered) in files.items():
        if rendered != text:
            path.write_text(rendered)
            print(f"{path}: figures updated")
        else:
            print(f"{path}: figures already up to date")
    return 0


if __name__ == "__main__":
    sys.exit(main())
