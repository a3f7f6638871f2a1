"""The depth-agreement search, step by step, on the real IPD frames (issue 26).

    python scripts/search_ab.py outputs/real_ipd/run_D outputs/real_ipd/run_D_s1 outputs/real_ipd/run_D_s2 \\
        [--generated results/real_ipd/search_ab_generated/ab.csv] [--out results/real_ipd/search_ab.md]

Each run folder of ``scripts/real_ipd.py`` (one training seed each) is scored on the three real frames
(official ``visib_fract``, its region of interest and clip planes) by ``eval.py`` with each arm's
overrides, from the network alone to ``refine=search +decoding.averaging=false`` (the recipe): what
each step of the search is worth, mean ± sd over the runs. ``--generated`` adds the table that
``scripts/icp_ab.py --search`` wrote for held-out generated piles (the same refinements on 240
scenes of another generation seed). Writes ``--out`` and prints it; ``--report`` re-makes it from the
evaluations already made (``<run>/search_ab/<arm>/``).
"""

from __future__ import annotations

import argparse
import csv
import importlib.util
import json
import os
import statistics
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("real_ipd", REPO / "scripts" / "real_ipd.py")
real_ipd = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(real_ipd)

#: (name, what it changes, eval.py overrides); each arm adds to the one before unless it says otherwise
ARMS = [
    ("none", "the network's hypotheses as decoded (DBSCAN averaging as trained)", []),
    ("icp", "+ ICP (refine=icp: 0.1-diameter reach, 20 degree guard, 100 ms per frame)", ["refine=icp"]),
    ("search_v0", "ICP as refine=icp, then the search; ranked by agreement, no duplicate removal",
     ["refine=search", "refine.icp.max_distance=0.1", "refine.icp.max_rotation_deg=20", "refine.search.suppress=0"]),
    ("suppress", "+ duplicates within one delta dropped (search.suppress=1)",
     ["refine=search", "refine.icp.max_distance=0.1", "refine.icp.max_rotation_deg=20"]),
    ("no_averaging", "+ the search from every decoded hypothesis (decoding.averaging=false)",
     ["refine=search", "refine.icp.max_distance=0.1", "refine.icp.max_rotation_deg=20", "+decoding.averaging=false"]),
    ("recipe", "+ ICP reach 0.2 diameters, 45 degree guard (conf/refine/search.yaml as it stands)",
     ["refine=search", "+decoding.averaging=false"]),
]  # fmt: skip


def score(run: Path, overrides: list[str], out: Path) -> dict:
    """A run's best checkpoint on the real frames with one arm's eval.py overrides."""
    return real_ipd.evaluate(real_ipd.best_checkpoint(run), real_ipd.FRAMES / "test", out, real_ipd.ROI, real_ipd.CLIP,
                             overrides, examples=0)  # fmt: skip


def generated_table(path: Path) -> list[str]:
    rows = list(csv.DictReader(path.open()))
    lines = ["| decoding | refine | scenes | AP | found % | t p50 mm | r p50 ° | ms / image |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ms = f"{float(r['icp_ms_per_image']):.0f}" if r.get("icp_ms_per_image") else "–"
        lines.append(f"| {r['decoding']} | {r['refine']} | {r['scenes']} | {float(r['ap']):.3f} | "
                     f"{100 * float(r['found']):.1f} | {float(r['t_mm_p50']):.1f} | {float(r['r_deg_p50']):.1f} | {ms} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="+", type=Path)
    ap.add_argument("--generated", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=REPO / "results" / "real_ipd" / "search_ab.md")
    ap.add_argument("--report", action="store_true", help="re-make the page from the evaluations already made")
    args = ap.parse_args(argv)
    for run in args.runs:
        if not (run / "checkpoints").is_dir():
            print(f"error: {run}: not a run folder of scripts/real_ipd.py (no checkpoints/)", file=sys.stderr)
            return 2
    if args.generated is not None and not args.generated.is_file():
        print(f"error: --generated {args.generated}: no such file (scripts/icp_ab.py --search writes it)", file=sys.stderr)
        return 2
    runs = [r.resolve() for r in args.runs]
    seeds = [real_ipd.run_info(r)[0] for r in runs]
    lines = ["# The depth-agreement search on the real IPD frames, step by step", "",
             f"Made by `python scripts/search_ab.py {' '.join(os.path.relpath(r, REPO) for r in runs)}"
             + (f" --generated {os.path.relpath(args.generated, REPO)}" if args.generated else "") + "`. "
             "Each arm adds to the one before (unless it says otherwise); every run is one training seed of "
             "`scripts/real_ipd.py` (the same generated data), scored on the three real frames with the official "
             "`visib_fract` (AP: Brégier, max occlusion 0.5; found: plates matched of the 15 to find).", "",
             "| arm | what changes | eval.py overrides | " + " | ".join(f"AP seed {s}" for s in seeds)
             + " | **AP mean ± sd** | found % mean |", "|" + "---|" * (5 + len(runs))]
    for name, change, overrides in ARMS:
        aps, found = [], []
        for run in runs:
            folder = run / "search_ab" / name
            if args.report and not (folder / "summary.json").is_file():
                print(f"error: --report: {folder} holds no evaluation; run without --report first", file=sys.stderr)
                return 2
            summary = json.loads((folder / "summary.json").read_text()) if args.report else score(run, overrides, folder)
            aps.append(summary["ap"])
            found.append(100 * summary["diagnostics"]["matched"] / max(summary["diagnostics"]["to_find"], 1))
            print(f"{run.name} {name}: AP {aps[-1]:.3f}", flush=True)
        sd = statistics.stdev(aps) if len(aps) > 1 else 0.0
        lines.append(f"| {name} | {change} | `{' '.join(overrides) or '(none)'}` | " + " | ".join(f"{a:.3f}" for a in aps)
                     + f" | **{statistics.mean(aps):.3f} ± {sd:.3f}** | {statistics.mean(found):.1f} |")
    if args.generated is not None:
        command = args.generated.parent / "command.txt"
        made_by = f"`{command.read_text().strip()}`" if command.is_file() else "`scripts/icp_ab.py --search`"
        lines += ["", "On held-out generated piles (another generation seed, refined at the dataset's own resolution; "
                  f"`{os.path.relpath(args.generated, REPO)}`, written by {made_by}); the milliseconds were measured "
                  "on 2 cores while other evaluations shared them:", "", *generated_table(args.generated)]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(args.out.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
