"""The dense-pile A/B tables of the learning changes, read back from the runs of
``scripts/bench_dense.py`` (``outputs/dense/<object>_<config>/``): per arm and seed the held-out test
AP (72 scenes of 70-75 parts, piles of seed 1), the AP on the piles of the other generators scored
with ``--extra-test`` (``eval_<name>/``), the share of the parts to find that were found or missed
on position / orientation, and the median errors; per arm the mean (± sample sd over seeds).

    python scripts/dense_ab.py                   # prints the tables, writes results/dense/ab_learning.md

Every arm of a table trained on the same training piles with the same step budget and held-out
scenes (the commands are in ``results/dense/README.md``, one per configuration); arms differ only in
what the "change" column says. A missing run is a row of dashes, never a number made up.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "scripts"))

from bench_learning import diagnostic_shares  # noqa: E402

#: the other generators' piles, in the order of the columns
OTHERS = ("sileane", "pybullet")

#: (title, object, note, [(arm, change, [config per seed])])
TABLES: tuple[tuple[str, str, str, list[tuple[str, str, list[str]]]], ...] = (
    ("Bunny: parameterization, weight averaging, position loss", "bunny",
     "6600 training scenes (11 piles x 8 views of 75 parts, seed 0), 3000 steps of batch 16, small preset.",
     [("vanilla", "the paper's OP-Net output (`experiment=dense` before this change)", ["ab3k_base", "ab3k_base_s1"]),
      ("EVE", "`parameterization=eve`", ["ab3k_eve", "ab3k_eve_s1"]),
      ("vanilla + EMA", "`callbacks.weight_ema.decay=0.999`", ["ab3k_ema"]),
      ("EVE + EMA", "`parameterization=eve callbacks.weight_ema.decay=0.999`", ["ab3k_eve_ema"]),
      ("EVE, metric position 0.1", "`loss.position=metric loss.lambda_pos=0.1`", ["ab3k_eve_metric"]),
      ("EVE, metric position 0.3", "`loss.position=metric loss.lambda_pos=0.3`", ["ab3k_eve_metric03"]),
      ("EVE, depth weight 10", "`loss.lambda_z=10`", ["ab3k_eve_z10"]),
      ("EVE, depth weight 100", "`loss.lambda_z=100`", ["ab3k_eve_z100"])]),
    ("Ring screw: the same arms", "ring_screw",
     "6600 training scenes (11 piles x 8 views of 75 parts, seed 0), 3000 steps of batch 16, small preset.",
     [("vanilla", "the paper's OP-Net output", ["ab3k_base"]),
      ("EVE", "`parameterization=eve`", ["ab3k_eve", "ab3k_eve_s1"]),
      ("EVE, metric position 0.1", "`loss.position=metric loss.lambda_pos=0.1`", ["ab3k_eve_metric", "ab3k_eve_metric_s1"]),
      ("EVE, metric position 0.3", "`loss.position=metric loss.lambda_pos=0.3`", ["ab3k_eve_metric03"]),
      ("EVE, depth weight 10", "`loss.lambda_z=10`", ["ab3k_eve_z10"]),
      ("EVE, depth weight 100", "`loss.lambda_z=100`", ["ab3k_eve_z100"])]),
    ("Bunny: data scaling at a fixed budget (EVE, 3000 steps)", "bunny",
     "`data.train_groups=N` keeps the first N training piles; 23 piles come from `--gen-cycles 192`. "
     "*v*: validated 10 times evenly spaced (`--validations 10`, the last at the final step) instead of at "
     "epoch ends, which for a budget ending mid-epoch left the last steps out of the model choice.",
     [("1200 scenes (2 piles)", "`data.train_groups=2`", ["scale3k_eve_p2"]),
      ("3000 scenes (5 piles)", "`data.train_groups=5`", ["scale3k_eve_p5"]),
      ("6600 scenes (11 piles)", "all of `--gen-cycles 96`", ["ab3k_eve"]),
      ("6600 scenes (11 piles), v", "`--validations 10`", ["scale3k_eve_p11v"]),
      ("13200 scenes (23 piles)", "`--gen-cycles 192`", ["scale3k_eve_p23"]),
      ("13200 scenes (23 piles), v", "`--gen-cycles 192 --validations 10`", ["scale3k_eve_p23v"])]),
)


def read_run(run: Path) -> dict[str, Any] | None:
    """Test AP, the other generators' APs and the diagnostics of one run, or None if it is missing."""
    path = run / "test" / "summary.json"
    if not path.is_file():
        return None
    s = json.loads(path.read_text())
    row = {"ap": s["ap"], **diagnostic_shares(s)}
    for name in OTHERS:
        other = run / f"eval_{name}" / "summary.json"
        row[name] = json.loads(other.read_text())["ap"] if other.is_file() else None
    return row


def cell(values: list[float | None], digits: int = 3) -> str:
    """``a / b (mean ± sd)`` over seeds, ``a`` for one seed, ``—`` where nothing was measured."""
    vals = [v for v in values if v is not None]
    if not vals:
        return "—"
    each = " / ".join(f"{v:.{digits}f}" for v in vals)
    if len(vals) == 1:
        return each
    return f"{each} ({statistics.mean(vals):.{digits}f} ± {statistics.stdev(vals):.{digits}f})"


def mean_cell(values: list[float | None], digits: int = 1) -> str:
    vals = [v for v in values if v is not None]
    return f"{statistics.mean(vals):.{digits}f}" if vals else "—"


def render(runs_dir: Path) -> str:
    lines = ["# Dense-pile A/B: learning changes at a fixed budget", "",
             "Generated by `python scripts/dense_ab.py` from the runs of `scripts/bench_dense.py` (one command per "
             "configuration in [README.md](README.md)). Held-out **test AP**: the 72 scenes of 70-75 parts of 12 "
             "piles of seed 1 (Brégier AP, max occlusion 0.5); *Siléane*: the 11 official Siléane bunny ground-truth "
             "piles re-rendered with the fitted camera (`scripts/sileane_rerender.py --fitted`); *pybullet*: 72 scenes "
             "of 12 piles of seed 2 made with the other physics engine (`scene.physics=pybullet`). Several seeds: "
             "each seed's value, then mean ± sample sd. found / position / orientation: % of the parts to find; "
             "t / r p50: median errors of the matched parts; FP: confident false positives per scene. "
             "Measured on a 2-core AMD EPYC with native bf16 (bf16 mixed precision), 2026-11-25/26.", ""]
    for title, obj, note, arms in TABLES:
        lines += [f"## {title}", "", note, "",
                  "| arm | change | seeds | **test AP** | Siléane AP | pybullet AP | found % | position % | "
                  "orientation % | t p50 mm | r p50 ° | FP |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for arm, change, configs in arms:
            rows = [r for r in (read_run(runs_dir / f"{obj}_{c}") for c in configs) if r is not None]
            if not rows:
                lines.append(f"| {arm} | {change} | 0 | — | — | — | — | — | — | — | — | — |")
                continue
            col = lambda k: [r[k] for r in rows]  # noqa: E731
            pct = lambda k: [100 * r[k] for r in rows]  # noqa: E731
            lines.append(f"| {arm} | {change} | {len(rows)} | **{cell(col('ap'))}** | {cell(col('sileane'))} | "
                         f"{cell(col('pybullet'))} | {mean_cell(pct('found'))} | {mean_cell(pct('position'))} | "
                         f"{mean_cell(pct('orientation'))} | {mean_cell(col('t_err_mm_p50'))} | "
                         f"{mean_cell(col('r_err_deg_p50'))} | {mean_cell(col('confident_fp_per_scene'))} |")
        lines.append("")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs-dir", type=Path, default=REPO / "outputs" / "dense")
    ap.add_argument("--out", type=Path, default=REPO / "results" / "dense" / "ab_learning.md")
    args = ap.parse_args(argv)
    if not args.runs_dir.is_dir():
        print(f"error: {args.runs_dir}: no such folder of bench_dense.py runs", file=sys.stderr)
        return 2
    text = render(args.runs_dir)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
