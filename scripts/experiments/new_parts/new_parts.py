"""The new-parts benchmark: parts nobody here tuned for, from their CAD files through ``opnet-object``
and the dense recipe, untouched, at the dense benchmark's per-part budget (results/new_parts/README.md).

    python scripts/experiments/new_parts/new_parts.py --run                   # every part not in the table yet
    python scripts/experiments/new_parts/new_parts.py --run --objects tless20 # one part (again)
    python scripts/experiments/new_parts/new_parts.py --refine                # score the models here refined
    python scripts/experiments/new_parts/new_parts.py                         # the table of what is there

Per part:

1. ``opnet-object <mesh> --name <part>`` writes the part's object config to a scratch folder; its symmetry
   must be the one of ``conf/object/<part>.yaml`` (which ``opnet-object`` wrote), else the part stops here:
   the benchmark runs on what the command finds, nothing set by hand.
2. ``scripts/bench/bench_dense.py`` at one budget for every part (:data:`BUDGET`): the dense benchmark's
   192 cycles generated (24 piles x 8 views, 75 drops, seed 0; the recipe's rig sized to the part) and 10,680
   training steps of batch 16 (:data:`STEPS`: what 41 minutes gave on the first part's machine; half the steps
   of the dense benchmark's ``recipe60`` rows, which a faster machine gave), 20 validations, the decoding tuned
   on validation; held out: 12 piles of seed 1 (their scenes of at least 70 parts) and 12 piles of seed 2
   simulated by the other physics engine (pybullet).

Writes ``bench/dense.csv`` and ``bench/README.md`` (the benchmark's own table) under ``--out``, then
``new_parts.csv`` (a row per part: ``object``, ``ap``, ...) and ``README.md``: the held-out AP against the target
(:data:`TARGET`), and for a part below it the measured reason: where its misses went.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import yaml

from opnet.paths import REPO_ROOT, shared_dir
from opnet.studies import fmt, merge_csv
from opnet.studies.results import decoding_cell, fill_cell, other_engine_cell, refined_cell, symmetry_cell

#: part -> its mesh under the shared data folder (conf/object/<part>.yaml names the same file)
PARTS = {
    "pepper": "SileanePepper.stl",
    "tless20": "TLess20.stl",
    "itodd08": "ITODD08.stl",
    "itodd13": "ITODD13.stl",
    "itodd27": "ITODD27.stl",
}
CONFIG = "recipe60"
#: one budget for every part, whatever the machine: the dense benchmark's 192 cycles and a fixed step count, the
#: steps that 41 minutes of training gave on the 2-core machine the first part ran on (its calibration; trained to
#: 10,680, 20 validations x 534)
STEPS = 10696
PYBULLET_PILES = 12  # the other engine's held-out piles
BUDGET = ["--config", CONFIG, "--gen-cycles", "192", "--views", "8", "--steps", str(STEPS), "--validations", "20",
          "--tune", "--pybullet-piles", str(PYBULLET_PILES)]
DROPS = 75  # bench_dense.py's parts per pile
#: the refinement the model is also scored with (conf/refine/): ICP and the depth-agreement search, chosen on
#: generated validation piles of another seed (refinement_probe.md), scored on the held-out piles once
REFINE = "search_fast"
#: the CSV field of each refined score -> the run's folder it is read from
REFINED = {"ap_refined": "test_refined", "ap_pybullet_refined": "eval_pybullet_refined"}
TARGET = 0.6
FIELDS = ("object", "symmetry", "near_symmetry", "d_mm", "camera_m", "fill", "fill_made", "ap", "ap_tuned", "ap_configured", "ap_pybullet",
          "ap_refined", "ap_pybullet_refined", "pybullet_note", "found", "position", "orientation", "no_hypothesis", "confident_fp_per_scene", "t_err_mm_p50", "r_err_deg_p50", "steps",
          "gen_minutes", "train_minutes", "train_scenes", "test_scenes", "turned_over", "turn_mode", "found_end_on",
          "found_side_on", "side_on", "target", "met", "reason")
#: the fields of :func:`opnet.metrics.breakdown.view_shares`
VIEWS = ("found_end_on", "found_side_on", "side_on")
TITLE = "New parts: the dense recipe on parts nobody tuned for"


def symmetry_text(sym: dict[str, Any]) -> str:
    """The group as the object config states it, e.g. ``cyclic 2``, ``revolution``, ``none``."""
    kind = sym.get("kind", "none")
    order = f" {sym['order']}" if sym.get("order") else ""
    flip = " with a flip" if sym.get("rotoreflection") or sym.get("flip") else ""
    return f"{kind}{order}{flip}"


def check_object(part: str) -> str:
    """Run ``opnet-object`` on the part's mesh (with ``--declare-near`` where the committed config was written
    with it: a near-revolution declared); its symmetry must be the committed config's. Returns it."""
    text = (REPO_ROOT / "conf" / "object" / f"{part}.yaml").read_text()
    committed = yaml.safe_load(text)
    declare = ["--declare-near"] if "declared with --declare-near" in text else []
    mesh = shared_dir() / "data" / "meshes" / "new_parts" / PARTS[part]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / f"{part}.yaml"
        subprocess.run([sys.executable, "-m", "opnet.cli.object", str(mesh), "--name", part, "--out", str(out), *declare],
                       check=True, cwd=REPO_ROOT, stdout=subprocess.DEVNULL)
        found = yaml.safe_load(out.read_text())
    if found["symmetry"] != committed["symmetry"]:
        raise SystemExit(f"error: opnet-object {' '.join(declare)} finds {found['symmetry']} for {mesh}, "
                         f"conf/object/{part}.yaml says {committed['symmetry']}: write it again with opnet-object")
    print(f"[{part}] opnet-object{' --declare-near' if declare else ''}: {symmetry_text(found['symmetry'])}, as "
          f"conf/object/{part}.yaml", flush=True)
    return symmetry_text(found["symmetry"])


def part_geometry(part: str, run: str) -> dict[str, Any]:
    """D, the recipe's camera height and its bin's fill for the part (its rig sized to it), from the mesh;
    ``fill_made``: the fill of the piles the benchmark's ``run`` trained on (NaN where they are absent);
    ``near_symmetry``: the one ``opnet-object`` names (empty if none)."""
    from opnet.cli.evaluate import resolve_object
    from opnet.cli.object import inspect_part, near_symmetries
    from opnet.studies.scenes import dense_scene, recorded_bin
    from opnet.synthesis.layout import bin_fill, make_rig

    obj = resolve_object(part)
    rig = make_rig(obj, DROPS, 8, dense_scene())
    root = train_root(run)
    report = inspect_part(shared_dir() / "data" / "meshes" / "new_parts" / PARTS[part])[3]
    return {"d_mm": 1e3 * obj.diameter, "camera_m": float(rig.params.location[2]),
            "fill": bin_fill(obj, DROPS, rig.bin), "fill_made": recorded_bin(root, obj)["fill"] if root else math.nan,
            "near_symmetry": near_symmetries(report)}


def train_root(run: str) -> Path | None:
    """The training piles of a benchmark run, as its recorded Hydra overrides name them (``data.root``)."""
    overrides = REPO_ROOT / run / ".hydra" / "overrides.yaml"
    if not run or not overrides.is_file():
        return None
    roots = [o.split("=", 1)[1] for o in yaml.safe_load(overrides.read_text()) or [] if o.startswith("data.root=")]
    return Path(roots[0]) if roots else None


def _number(pattern: str, text: str) -> float | str:
    m = re.search(pattern, text or "")
    return float(m.group(1)) if m else ""


def other_engine_note(bench_row: dict[str, Any]) -> str:
    """Why a part has no AP on the other engine's piles: ``not made: <the generator's message>`` (a pile pybullet
    could not make), ``not run`` (the run was started without them), or empty (it has one)."""
    extra = bench_row.get("extra_tests") or ""
    made = re.search(r"pybullet not made: ([^;]*)", extra)
    if made:
        return f"not made: {made.group(1).strip()}"
    return "" if re.search(r"pybullet [\d.]+", extra) else "not run"


def reason(row: dict[str, Any]) -> str:
    """Met, or where the misses went (shares of the parts to find), measured on the held-out piles."""
    if float(row["ap"]) >= TARGET:
        return "met"
    misses = {"position": row["position"], "orientation": row["orientation"], "no hypothesis": row["no_hypothesis"]}
    worst = max(misses, key=lambda k: float(misses[k] or 0))
    shares = ", ".join(f"{k} {fmt(v, 'pct')} %" for k, v in misses.items())
    turns = ""
    if worst == "orientation" and row.get("turned_over") not in ("", None):
        turns = (f"; of the orientation misses {fmt(row['turned_over'], 'pct')} % turned over (> 150°), the largest "
                 f"cluster: {row['turn_mode'] or 'none'}")
    views = ""
    if row.get("side_on") not in ("", None) and row.get("found_side_on") not in ("", None):
        views = (f"; {fmt(row['side_on'], 'pct')} % lie with their main axis across the line of sight (side-on), of "
                 f"which {fmt(row['found_side_on'], 'pct')} % found (end-on: {fmt(row['found_end_on'], 'pct')} %)")
    return (f"found {fmt(row['found'], 'pct')} % of the parts to find; missed on {worst} most ({shares}){turns}; "
            f"{fmt(row['confident_fp_per_scene'], 'f1')} confident false positives per scene{views}")


def orientation_turns(run: str) -> dict[str, Any]:
    """``turned_over`` and ``turn_mode`` (the largest cluster of turns, as text) of the orientation misses on
    the run's held-out piles (its test ``summary.json``); empty where the run or the figures are absent."""
    from opnet.metrics.breakdown import view_shares
    from opnet.metrics.diagnostics import TurnMode
    from opnet.studies import read_summary

    summary = read_summary(REPO_ROOT / run) if run else None
    if not summary or "orientation_misses" not in summary:
        return {}
    misses = summary["orientation_misses"]
    return {"turned_over": misses["turned_over"], "turn_mode": TurnMode(**misses["modes"][0]).text() if misses["modes"] else "",
            **view_shares(summary.get("breakdown", {}))}


def refine_run(part: str, run_dir: Path) -> None:
    """Score the run's model (the checkpoint its test scored) with :data:`REFINE` on its held-out piles and,
    where they were made, the other engine's: ``test_refined/`` and ``eval_pybullet_refined/`` in the run."""
    from opnet.paths import best_checkpoint
    from opnet.studies import run_logged

    ckpt, root = best_checkpoint(run_dir), train_root(str(run_dir))
    if ckpt is None or root is None:
        raise SystemExit(f"error: {run_dir}: no trained benchmark run of {part} to refine")
    other = root.parent / f"{part}_pybullet_p{PYBULLET_PILES}_d{DROPS}_s2"  # bench_dense.py's name for them
    for dest, test_root in zip(REFINED.values(), (None, other), strict=True):
        if test_root is not None and not (run_dir / "eval_pybullet" / "summary.json").is_file():
            continue  # the other engine's piles were not made
        run_logged([sys.executable, str(REPO_ROOT / "eval.py"), f"ckpt={ckpt}", f"out={run_dir / dest}",
                    f"refine={REFINE}", "examples=0", *([f"data.test_root={test_root}"] if test_root else [])],
                   run_dir / f"{dest}.log")
        print(f"[{part}] {dest} ({REFINE}): AP {json.loads((run_dir / dest / 'summary.json').read_text())['ap']:.4f}",
              flush=True)


def refined(run: str) -> dict[str, Any]:
    """``ap_refined`` and ``ap_pybullet_refined`` of a run scored by :func:`refine_run` (empty where not)."""
    out = {}
    for key, dest in REFINED.items():
        summary = REPO_ROOT / run / dest / "summary.json" if run else None
        if summary is not None and summary.is_file():
            out[key] = json.loads(summary.read_text())["ap"]
    return out


def table_rows(bench_csv: Path, previous: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    rows = []
    for b in csv.DictReader(bench_csv.open()) if bench_csv.is_file() else []:
        if b["object"] not in PARTS or b["config"] != CONFIG:
            continue
        part = b["object"]
        row = {k: b.get(k, "") for k in FIELDS}
        old = previous.get(part, {})
        try:
            row |= part_geometry(part, b.get("run", ""))
        except (FileNotFoundError, ValueError):  # the shared meshes absent: what the table had
            row |= {k: old.get(k, "") for k in ("d_mm", "camera_m", "fill", "fill_made", "near_symmetry")}
        row |= orientation_turns(b.get("run", "")) or {k: old.get(k, "") for k in ("turned_over", "turn_mode", *VIEWS)}
        row |= {k: old.get(k, "") for k in REFINED} | refined(b.get("run", ""))
        if row["fill_made"] in ("", None) or math.isnan(float(row["fill_made"])):  # the piles not here: the table's
            row["fill_made"] = old.get("fill_made", "")
        elif abs(float(row["fill_made"]) - float(row["fill"])) <= 0.005:  # the bin the recipe gives it now: no note
            row["fill_made"] = ""
        conf = yaml.safe_load((REPO_ROOT / "conf" / "object" / f"{part}.yaml").read_text())
        row |= {"symmetry": symmetry_text(conf.get("symmetry") or {}),
                "ap_tuned": _number(r"test AP ([\d.]+)", b.get("tuned", "")),
                "ap_configured": _number(r"configured decoding: AP ([\d.]+)", b.get("tuned", "")),
                "ap_pybullet": _number(r"pybullet ([\d.]+)", b.get("extra_tests", "")), "target": TARGET,
                "pybullet_note": other_engine_note(b)}
        row["met"] = int(float(row["ap"]) >= TARGET)
        row["reason"] = reason(row)
        rows.append(row)
    return sorted(rows, key=lambda r: list(PARTS).index(r["object"]))


def write_readme(out: Path, rows: list[dict[str, Any]]) -> None:
    done = {r["object"] for r in rows}
    intro = (
        "Five parts nobody here chose a setting for (two of the paper's Table I objects, the Siléane pepper and "
        "T-LESS 20, and three industrial parts of MVTec ITODD), from their CAD files: `opnet-object` writes each "
        "object config (units, symmetry, main axis), then the dense recipe (`experiment=dense`, its rig sized to "
        "the part) runs untouched at one budget per part on a 2-core CPU.\n\nThe budget: 192 cycles (24 piles "
        "x 8 views, 75 drops) generated, 10,680 training steps of batch 16 (41 minutes on the 2-core machine the "
        "first part ran on; half the steps of the dense benchmark's bunny and ring screw rows), the decoding tuned "
        "on validation: by the recipe itself after training (`tune_decoding`: every 8th validation scene), the "
        "held-out AP in brackets that of the decoding as configured (*configured*); a row made before the recipe "
        "tuned (and pooled four turns) has the decoding it had then, in brackets the decoding tuned on validation "
        "after it (*tuned*)."
        "\n\nA part that CoACD cuts into more than 20 convex pieces is merged toward 20 while that adds "
        "at most 1 % of its volume (the recipe's `scene.max_convex_pieces`, `scene.convex_merge_budget`; T-LESS 20: "
        "39 pieces to 20, ITODD 08: 42 to 36, ITODD 13: 45 to 40), as a physics step costs about the pieces in contact "
        "([where a pile's time goes](generation_profile.md)).\n\nHeld out: "
        "scenes of at least 70 parts of 12 piles of another seed (**AP**), and of 12 piles simulated by the other "
        "physics engine (pybullet; *not made*: a pile pybullet could not make, the message below the table; "
        "*not run*: the part ran without them).\n\nThe recipe's walls are 1.5 D high whatever the part's bulk, and "
        "[compact parts pile above them](piles.md): the *fill* (the 75 parts' convex hulls over the volume inside "
        "the walls) is 0.30 for the pepper, whose piles stay under its walls, and 0.68 for ITODD 27, whose piles "
        "stand 1.4 wall heights high in MuJoCo. pybullet's piles stand higher still and leave parts resting on the "
        "rim, and a pile whose drops keep leaving the bin is refused: in their bins as first sized, pybullet could not "
        "pile T-LESS 20 (fill 0.82), and neither engine ITODD 08 (1.06). So the recipe caps the fill at 0.7 "
        "(`scene.bin_max_fill`, a fill at which pybullet made every pile): the floor widens until the hulls fill at "
        "most that share, the walls and so the pile's height stay sized to the part; parts that fill less (pepper, "
        "ITODD 13, ITODD 27, every built-in part) keep their piles, and every row here was made with the cap "
        "(*fill*: the recipe's; in brackets, that of a part's training piles where they were made otherwise).\n\n"
        "*near*: the near-symmetry `opnet-object` names, a turn it rejects that still moves 98 % of the surface by "
        "less than δ (its deviation; [what to do with one](../../docs/data.md#your-own-part)): a depth image may "
        "hardly tell the part from itself turned so, and the metric counts such a pose as wrong.\n\nAt a quarter of this "
        "budget ([turns_probe/turns.md](turns_probe/turns.md)), ITODD 27's orientation misses are not its near-symmetry "
        "and ITODD 08's are not its front/back flip (1 % and 0 % turned over): both parts are spun about their main "
        "axis, ITODD 27 by 16-54° and ITODD 08 by about 21° (its spokes' angle). So the recipe now turns every part "
        "of a training pile's views after the first about its own axis by a fresh spin where the part's hull lets it "
        "(`scene.view_spin: auto`, [fresh spins per view](../../docs/data.md#fresh-spins-per-view)): of these five "
        "parts ITODD 08 and ITODD 27, whose rows are made so (their training piles: the same physics, `_view_spin-true`); "
        "the other three parts' piles are unchanged (pepper's spins are free, the other hulls are no bodies of "
        "revolution). Before it, at the same budget and seed: ITODD 08 0.408, ITODD 27 0.601 "
        "([the flat-parts study](../flat_parts/README.md) has both at several seeds).\n\n"
        f"*refined ({REFINE})*: the same model, its hypotheses refined against the depth image without a time "
        "budget (ICP and the depth-agreement search: a flat part's turns about its axis, any other part's flips), the "
        "refinement that did best on generated validation piles of another seed for the two parts below target (ICP "
        "alone did best on T-LESS 20's: 0.933 against 0.909, 0.913 as decoded; [refinement_probe.md]"
        "(refinement_probe.md)), scored on the held-out piles once; *–*: the part's model was not at hand when the "
        "column was added (`--refine` scores the models there are)."
        "\n\nAP: Brégier, max occlusion 0.5. "
        f"**Target: held-out AP >= {TARGET} per part**; below it, the measured reason (where the misses went: "
        "shares of the parts to find). For scale: the bunny, the part the recipe was chosen on, scores 0.83 at "
        "twice these steps ([the dense benchmark](../dense/README.md)).\n\n*gen + train min*: wall minutes, longer where "
        "other jobs shared the machine (pepper's generation: 33 minutes, about half of them beside other generation "
        "and decomposition jobs; ITODD 13's: 41.5 minutes, made over three resumed runs, most of them beside another part's generation; ITODD 08's and T-LESS "
        "20's training: 25 and 23 minutes, beside short evaluations of other models; the bunny's 192 cycles took 14 "
        "alone). The steps are the budget, not the minutes: ITODD 08, ITODD 13 and T-LESS 20 ran on a 2-core AMD "
        "EPYC, which trains the same 10,696 steps in 19-25 minutes; the other parts on a 2-core Intel Xeon (40-44). "
        "Nor is a part's row one number for all machines: the two CPUs' physics differ in the last bits, so the same "
        "command makes other piles and another model on each, and ITODD 08's run on the Intel Xeon scored 0.176 "
        "(pybullet 0.185) where the recipe of then on the AMD EPYC scored 0.255. Made by")
    lines = [
        f"# {TITLE}", "", intro, "",
        "    python scripts/experiments/new_parts/new_parts.py --run", "",
        ("([the script](../../scripts/experiments/new_parts/new_parts.py); the benchmark's own table with the "
         "learning curves and commands: [bench/README.md](bench/README.md); every number in "
         "[new_parts.csv](new_parts.csv))."), "",
        ("| part | symmetry (opnet-object) | D mm | camera m | fill | **held-out AP** (the other decoding) | other engine "
         f"(pybullet) | refined ({REFINE}): held-out (pybullet) | found % | t p50 mm | r p50 ° | steps | gen + train min | target | "
         "reason |"),
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['object']} | {symmetry_cell(r)} | {fmt(r['d_mm'], 'f0')} | {fmt(r['camera_m'], 'f2')} | "
            f"{fill_cell(r)} | {decoding_cell(r)} | {other_engine_cell(r)} | {refined_cell(r)} | "
            f"{fmt(r['found'], 'pct')} | "
            f"{fmt(r['t_err_mm_p50'], 'f1')} | {fmt(r['r_err_deg_p50'], 'f1')} | {r['steps']} | "
            f"{fmt(r['gen_minutes'], 'f0')} + {fmt(r['train_minutes'], 'f0')} | {TARGET} | {r['reason']} |")
    lines += [f"\n*Other engine* for {r['object']}: {r['pybullet_note']}." for r in rows
              if (r.get("pybullet_note") or "").startswith("not made")]
    missing = [p for p in PARTS if p not in done]
    if missing:
        lines += ["", f"Not run yet: {', '.join(missing)} (`--run --objects {' '.join(missing)}`)."]
    (out / "README.md").write_text("\n".join(lines) + "\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--run", action="store_true", help="run the benchmark for the parts first")
    ap.add_argument("--objects", nargs="+", choices=list(PARTS), default=None,
                    help="the parts to run (default: those not in the table yet)")
    ap.add_argument("--refine", action="store_true",
                    help=f"score the parts' trained models (those run here) with refine={REFINE} (--run does too)")
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "new_parts")
    args = ap.parse_args(argv)
    bench = args.out / "bench"
    if args.run:
        have = {r["object"] for r in csv.DictReader((bench / "dense.csv").open())
                if r["config"] == CONFIG} if (bench / "dense.csv").is_file() else set()
        for part in args.objects or [p for p in PARTS if p not in have]:
            check_object(part)
            subprocess.run([sys.executable, str(REPO_ROOT / "scripts" / "bench" / "bench_dense.py"), "--objects", part,
                            *BUDGET, "--out", str(bench), "--runs-dir", str(REPO_ROOT / "outputs" / "new_parts"),
                            "--title", f"{TITLE}: the benchmark's table"], check=True, cwd=REPO_ROOT)
            refine_run(part, REPO_ROOT / "outputs" / "new_parts" / f"{part}_{CONFIG}")
    elif args.refine:
        for part in args.objects or list(PARTS):
            run_dir = REPO_ROOT / "outputs" / "new_parts" / f"{part}_{CONFIG}"
            if (run_dir / "checkpoints").is_dir():
                refine_run(part, run_dir)
            else:
                print(f"[{part}] no run in {run_dir}: not refined", flush=True)
    csv_path = args.out / "new_parts.csv"
    previous = {r["object"]: r for r in csv.DictReader(csv_path.open())} if csv_path.is_file() else {}
    rows = table_rows(bench / "dense.csv", previous)
    merge_csv(csv_path, FIELDS, rows, ("object",))
    write_readme(args.out, rows)
    print((args.out / "README.md").read_text())
    print(json.dumps({r["object"]: round(float(r["ap"]), 3) for r in rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
