"""The depth-agreement search, step by step, on the real IPD frames.

    python scripts/experiments/real_ipd/search_ab.py outputs/real_ipd/run_D outputs/real_ipd/run_D_s1 outputs/real_ipd/run_D_s2 \\
        [--generated results/real_ipd/search_ab_generated/ab.csv] [--out results/real_ipd/search_ab.md]

Each run folder of ``scripts/experiments/real_ipd/real_ipd.py`` (one training seed each) is scored on the three real frames
(official ``visib_fract``, its region of interest and clip planes) by ``eval.py`` with each arm's
overrides, from the network alone to ``refine=search +decoding.averaging=false`` (the recipe): what
each step of the search is worth, mean ± sd over the runs. ``--generated`` adds the table that
``scripts/experiments/verification/icp_ab.py --search`` wrote for held-out generated piles (the same refinements on 240
scenes of another generation seed). ``VARIANTS`` (the recipe with one change each, measured and not
adopted) follow the arms; ``--generated-run RUN`` also scores the recipe and its variants on RUN's own
held-out generated piles (made once, reused). Writes ``--out`` and prints it; ``--report`` re-makes it
from the evaluations already made (``<run>/search_ab/<arm>/``).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import statistics
import sys
from pathlib import Path

from opnet.paths import REPO_ROOT, best_checkpoint
from opnet.studies import mean_sd_text, run_logged
from opnet.studies.ipd import CLIP, FRAMES, ROI, evaluate, run_info

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

#: variants of the recipe, each the recipe with one change (measured, not part of it)
VARIANTS = [
    ("start_0.05", "the recipe, searching from hypotheses down to presence 0.05 (decoding.threshold; as trained 0.1)",
     [*ARMS[-1][2], "+decoding.threshold=0.05"]),
    ("start_0.02", "the recipe, searching from hypotheses down to presence 0.02",
     [*ARMS[-1][2], "+decoding.threshold=0.02"]),
]  # fmt: skip


def score(run: Path, overrides: list[str], out: Path) -> dict:
    """A run's best checkpoint on the real frames with one arm's eval.py overrides."""
    return evaluate(best_checkpoint(run), FRAMES / "test", out, ROI, CLIP,
                             overrides, examples=0)  # fmt: skip


def generated_split(run: Path, arms: list[tuple[str, str, list[str]]]) -> list[str]:
    """The recipe and its variants on ``run``'s own held-out generated piles (its test split at the
    dataset's resolution): a table. Each evaluation (``<run>/search_ab/generated_<arm>/``) is made
    once and reused (a few minutes each); delete its folder to make it again."""
    lines = ["| arm | eval.py overrides | scenes | AP | found % | hypotheses searched from |", "|---|---|---|---|---|---|"]
    for name, _, overrides in arms:
        out = run / "search_ab" / f"generated_{name}"
        if not (out / "summary.json").is_file():
            run_logged([sys.executable, "eval.py", f"ckpt={best_checkpoint(run)}", "+data.cache=false",
                        f"out={out}", "examples=0", *overrides], out.with_suffix(".log"))  # fmt: skip
        summary = json.loads((out / "summary.json").read_text())
        d = summary["diagnostics"]
        lines.append(f"| {name} | `{' '.join(overrides)}` | {summary['scenes']} | {summary['ap']:.3f} | "
                     f"{100 * d['matched'] / max(d['to_find'], 1):.1f} | {sum(summary['icp']['statuses'].values())} |")
        print(f"{run.name} generated {name}: AP {summary['ap']:.3f}", flush=True)
    return lines


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
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "real_ipd" / "search_ab.md")
    ap.add_argument("--report", action="store_true", help="re-make the page from the evaluations already made")
    ap.add_argument("--generated-run", type=Path, default=None,
                    help="also score the recipe and its variants on this run's held-out generated piles")
    args = ap.parse_args(argv)
    for run in args.runs:
        if not (run / "checkpoints").is_dir():
            print(f"error: {run}: not a run folder of scripts/experiments/real_ipd/real_ipd.py (no checkpoints/)", file=sys.stderr)
            return 2
    if args.generated_run is not None and not (args.generated_run / "checkpoints").is_dir():
        print(f"error: --generated-run {args.generated_run}: not a run folder of scripts/experiments/real_ipd/real_ipd.py", file=sys.stderr)
        return 2
    if args.generated is not None and not args.generated.is_file():
        print(f"error: --generated {args.generated}: no such file (scripts/experiments/verification/icp_ab.py --search writes it)", file=sys.stderr)
        return 2
    runs = [r.resolve() for r in args.runs]
    seeds = [run_info(r)[0] for r in runs]
    lines = ["# The depth-agreement search on the real IPD frames, step by step", "",
             f"Made by `python scripts/experiments/real_ipd/search_ab.py {' '.join(os.path.relpath(r, REPO_ROOT) for r in runs)}"
             + (f" --generated {os.path.relpath(args.generated, REPO_ROOT)}" if args.generated else "")
             + (f" --generated-run {os.path.relpath(args.generated_run.resolve(), REPO_ROOT)}" if args.generated_run else "")
             + "`. "
             "Each arm adds to the one before (unless it says otherwise); every run is one training seed of "
             "`scripts/experiments/real_ipd/real_ipd.py` (the same generated data), scored on the three real frames with the official "
             "`visib_fract` (AP: Brégier, max occlusion 0.5; found: plates matched of the 15 to find).", "",
             "| arm | what changes | eval.py overrides | " + " | ".join(f"AP seed {s}" for s in seeds)
             + " | **AP mean ± sd** | found % mean |", "|" + "---|" * (5 + len(runs))]
    for name, change, overrides in ARMS + VARIANTS:
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
        label = f"variant {name}" if (name, change, overrides) in VARIANTS else name
        lines.append(f"| {label} | {change} | `{' '.join(overrides) or '(none)'}` | " + " | ".join(f"{a:.3f}" for a in aps)
                     + f" | **{mean_sd_text(aps)}** | {statistics.mean(found):.1f} |")
    lines += ["", "The variants are measured, not adopted: the recipe changes only where held-out generated piles "
              "support it (`--generated-run`), since the three frames above are the test."]
    if args.generated_run is not None:
        run = args.generated_run.resolve()
        lines += ["", f"The recipe and its variants on the held-out generated piles of `{os.path.relpath(run, REPO_ROOT)}` "
                  "(its test split: another generation seed, at the dataset's own resolution):", "",
                  *generated_split(run, ARMS[-1:] + VARIANTS)]
    if args.generated is not None:
        command = args.generated.parent / "command.txt"
        made_by = f"`{command.read_text().strip()}`" if command.is_file() else "`scripts/experiments/verification/icp_ab.py --search`"
        lines += ["", "On held-out generated piles (another generation seed, refined at the dataset's own resolution; "
                  f"`{os.path.relpath(args.generated, REPO_ROOT)}`, written by {made_by}); the milliseconds were measured "
                  "on 2 cores while other evaluations shared them:", "", *generated_table(args.generated)]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")
    print(args.out.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
