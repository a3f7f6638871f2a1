"""Which refinement the new-parts benchmark also scores with, chosen on generated validation piles.

    python scripts/experiments/new_parts/refine_probe.py \\
        --model itodd08=outputs/new_parts_probe/itodd08_probe48 --model tless20=outputs/new_parts/tless20_recipe60

Per ``PART=RUN``: ``--piles`` one-view piles of the part (75 drops, seed 3: neither the training seed 0,
nor the held-out seeds 1 and 2; the dense recipe's rig and bin sized to the part), every scene of them (each
drop's pile, 1 to 75 parts), scored with the run's model (the checkpoint its test scored) as decoded and with
each refinement of ``--refine`` (conf/refine/; without a time budget). Writes ``refinement_probe.csv`` and
``refinement_probe.md`` under ``--out``: AP, found share, median errors and seconds per scene. The new-parts
table then scores the held-out piles once with the refinement this page picks (``new_parts.py`` ``REFINE``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from opnet.paths import REPO_ROOT, best_checkpoint
from opnet.studies import diagnostic_shares, fmt, merge_csv, run_logged

DROPS = 75
SEED = 3
FIELDS = ("object", "run", "ckpt", "piles", "scenes", "refine", "ap", "found", "t_err_mm_p50", "r_err_deg_p50",
          "s_per_scene")


def validation_piles(part: str, piles: int, data_dir: Path) -> Path:
    """Make (or complete) ``piles`` one-view piles of seed :data:`SEED` with the dense recipe's scene."""
    from opnet.cli.evaluate import resolve_object
    from opnet.studies.scenes import dense_scene
    from opnet.synthesis import generate_dataset

    out = data_dir / f"{part}_val_p{piles}_d{DROPS}_s{SEED}"
    report = generate_dataset(resolve_object(part), out, piles, DROPS, workers=1, seed=SEED,
                              scene=dense_scene(views=1), progress=False, previews=0)
    print(f"[{part}] validation piles: {out} ({report.cycles_generated} made, {report.cycles_skipped} present)",
          flush=True)
    return out


def score(ckpt: Path, root: Path, refine: str, dest: Path) -> dict[str, Any]:
    """eval.py on every scene of ``root`` with ``refine``; its summary (kept from an earlier call while it is newer
    than the checkpoint)."""
    summary = dest / "summary.json"
    if not summary.is_file() or summary.stat().st_mtime < ckpt.stat().st_mtime:
        run_logged([sys.executable, "eval.py", f"ckpt={ckpt}", f"data.test_root={root}", "+data.test_min_objects=0",
                    f"refine={refine}", *(["refine.icp.budget_ms=null"] if refine != "none" else []),
                    f"out={dest}", "examples=0"], dest.with_suffix(".log"))
    return json.loads(summary.read_text())


def seconds_per_scene(log: Path) -> float | str:
    """The evaluation's wall time per scene, from its log (``run time ...``)."""
    import re

    text = log.read_text() if log.is_file() else ""
    m = re.search(r"run time (?:(\d+) min )?([\d.]+) s", text)
    n = re.search(r"^\w+ (\d+) scenes", text, re.MULTILINE)
    if not (m and n):
        return ""
    return (60 * int(m.group(1) or 0) + float(m.group(2))) / int(n.group(1))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", action="append", required=True, metavar="PART=RUN",
                    help="a part and a benchmark run of it (its checkpoint scored), repeatable")
    ap.add_argument("--piles", type=int, default=6)
    ap.add_argument("--refine", nargs="+", default=["none", "icp", "search_fast"])
    ap.add_argument("--data-dir", type=Path, default=REPO_ROOT / "outputs" / "data" / "dense")
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "new_parts")
    args = ap.parse_args(argv)
    rows = []
    for spec in args.model:
        part, _, run = spec.partition("=")
        run_dir = Path(run).resolve()
        ckpt = best_checkpoint(run_dir)
        if not part or ckpt is None:
            raise SystemExit(f"error: --model {spec}: expected PART=RUN with a trained run (checkpoints/)")
        root = validation_piles(part, args.piles, args.data_dir)
        for refine in args.refine:
            dest = run_dir / f"val_s{SEED}_{refine}"
            s = score(ckpt, root, refine, dest)
            d = diagnostic_shares(s)
            rows.append({"object": part, "run": run_dir.relative_to(REPO_ROOT) if run_dir.is_relative_to(REPO_ROOT)
                         else run_dir, "ckpt": ckpt.name, "piles": args.piles, "scenes": s["num_scenes"],
                         "refine": refine, "ap": s["ap"], "found": d["found"], "t_err_mm_p50": d["t_err_mm_p50"],
                         "r_err_deg_p50": d["r_err_deg_p50"], "s_per_scene": seconds_per_scene(dest.with_suffix(".log"))})
            print(f"[{part}] {refine}: AP {s['ap']:.4f}", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    all_rows = merge_csv(args.out / "refinement_probe.csv", FIELDS, rows, ("object", "run", "refine"))
    lines = [
        "# New parts: which refinement, chosen on validation piles", "",
        ("Generated validation piles of seed 3 (neither the training seed nor the held-out seeds; the dense recipe's "
        "rig and bin sized to the part), every scene of them (each drop's pile, 1 to 75 parts), scored with a "
        "benchmark run's model as decoded (*none*) and refined against the depth image without a time budget: "
        "*icp* (point-to-plane ICP), *search_fast* (ICP and the depth-agreement search: turns about the part's "
        "axis for a flat part, else its flips; the hypotheses ranked by agreement). Runs ending in `_probe48` are the "
        "quarter-budget models of [turns_probe/](turns_probe/turns.md). The new-parts table scores its held-out "
        "piles once with the refinement that wins here. *s / scene*: wall seconds per scene as the evaluation ran, "
         "beside other jobs on the 2 cores: a rough cost, not a timing. Made by"), "",
        "    python " + " ".join(["scripts/experiments/new_parts/refine_probe.py",
                                  *(a for spec in args.model for a in ("--model", spec)),
                                  *(["--piles", str(args.piles)] if args.piles != 6 else [])]), "",
        "| part | run | scenes | refinement | AP | found % | t p50 mm | r p50 ° | s / scene |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in all_rows:
        lines.append(f"| {r['object']} | {r['run']} | {r['scenes']} | {r['refine']} | {fmt(r['ap'])} | "
                     f"{fmt(r['found'], 'pct')} | {fmt(r['t_err_mm_p50'], 'f1')} | {fmt(r['r_err_deg_p50'], 'f1')} | "
                     f"{fmt(r['s_per_scene'], 'f2')} |")
    (args.out / "refinement_probe.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
