"""Compare the arms of a sweep in the layout of the paper's Table I.

    python scripts/compare_runs.py outputs/train/multiruns/<date_time> [--out <dir>]

Rows: parameterizations; columns: objects; cells: test AP (the Brégier mean-curve AP of each
arm's ``test/summary.json``). Arms that differ only in their seed (``python train.py -m ...
seed=0,1,2``) are one cell: the mean ± sample sd of their test AP over the seeds, with their
number. Writes ``comparison.md``, ``comparison.csv`` (one row per arm, with its seed, share of
parts found and median errors) and ``comparison.png`` (a grouped bar chart, the sd as error bars)
into the multirun folder (or --out), and prints the table.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import statistics
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import yaml  # noqa: E402

PAPER_ORDER = ["vanilla", "eve", "ap", "z", "mp", "si"]


def collect(multirun: Path) -> list[dict[str, object]]:
    """One row per finished arm: parameterization, object, ap, map, f1, run dir."""
    rows = []
    for hydra_yaml in sorted(multirun.rglob(".hydra/hydra.yaml")):
        run = hydra_yaml.parent.parent
        choices = yaml.safe_load(hydra_yaml.read_text())["hydra"]["runtime"]["choices"]
        summary = run / "test" / "summary.json"
        if not summary.is_file():
            print(f"warning: {run.name}: no test/summary.json (unfinished arm?), skipped", file=sys.stderr)
            continue
        s = json.loads(summary.read_text())
        config = run / ".hydra" / "config.yaml"
        seed = (yaml.safe_load(config.read_text()) or {}).get("seed") if config.is_file() else None
        diag = s.get("diagnostics") or {}
        found = diag["matched"] / diag["to_find"] if diag.get("to_find") else None
        rows.append({"parameterization": choices.get("parameterization"), "object": choices.get("object"), "seed": seed,
                     "ap": s["ap"], "map": s["map"], "f1": s["f1"], "found": found,
                     "t_err_mm_p50": diag.get("t_err_mm_p50"), "r_err_deg_p50": diag.get("r_err_deg_p50"),
                     "run": str(run.relative_to(multirun))})
    return rows


def table(rows: list[dict[str, object]]) -> tuple[list[str], list[str], dict[tuple[str, str], list[float]]]:
    """(parameterizations in the paper's order, objects, the test APs of each cell: one per seed)."""
    params = sorted({str(r["parameterization"]) for r in rows}, key=lambda p: (PAPER_ORDER.index(p) if p in PAPER_ORDER else 99, p))
    objects = sorted({str(r["object"]) for r in rows})
    cells: dict[tuple[str, str], list[float]] = {}
    for r in rows:
        cells.setdefault((str(r["parameterization"]), str(r["object"])), []).append(float(r["ap"]))  # type: ignore[arg-type]
    return params, objects, cells


def mean_sd(values: list[float]) -> tuple[float, float]:
    """Mean and sample standard deviation (0 for one value)."""
    return statistics.fmean(values), statistics.stdev(values) if len(values) > 1 else 0.0


def cell_text(values: list[float] | None) -> str:
    """``0.812`` for one run, ``0.812 ± 0.031 (3)`` over seeds, ``–`` for none."""
    if not values:
        return "–"
    if len(values) == 1:
        return f"{values[0]:.3f}"
    mean, sd = mean_sd(values)
    return f"{mean:.3f} ± {sd:.3f} ({len(values)})"


def markdown(params: list[str], objects: list[str], cells: dict[tuple[str, str], list[float]]) -> str:
    head = "| parameterization | " + " | ".join(objects) + " | average |"
    lines = [head, "|" + "---|" * (len(objects) + 2)]
    for p in params:
        vals = [cells.get((p, o)) for o in objects]
        done = [mean_sd(v)[0] for v in vals if v]
        avg = f"{sum(done) / len(done):.3f}" if done else "–"
        lines.append(f"| {p} | " + " | ".join(cell_text(v) for v in vals) + f" | {avg} |")
    return "\n".join(lines)


def bar_chart(params: list[str], objects: list[str], cells: dict[tuple[str, str], list[float]], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(1.5 + 1.2 * len(objects) * max(1, len(params)) / 3, 3.5), dpi=120)
    width = 0.8 / max(1, len(params))
    for k, p in enumerate(params):
        xs = [i + k * width for i in range(len(objects))]
        stats = [mean_sd(cells[(p, o)]) if cells.get((p, o)) else (0.0, 0.0) for o in objects]
        ax.bar(xs, [m for m, _ in stats], width, yerr=[sd for _, sd in stats], capsize=2, label=p)
    ax.set_xticks([i + 0.4 - width / 2 for i in range(len(objects))], objects)
    ax.set_ylabel("test AP (Brégier)")
    ax.set_ylim(0, 1)
    ax.legend(fontsize=8, ncols=min(len(params), 6))
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("multirun", type=Path, help="a Hydra multirun folder (one sub-folder per arm)")
    ap.add_argument("--out", type=Path, default=None, help="where to write comparison.* (default: the multirun folder)")
    args = ap.parse_args(argv)
    if not args.multirun.is_dir():
        print(f"error: {args.multirun}: not a folder", file=sys.stderr)
        return 2
    rows = collect(args.multirun)
    if not rows:
        print(f"error: {args.multirun}: no finished arm (no */.hydra/hydra.yaml with test/summary.json)", file=sys.stderr)
        return 2
    out = args.out or args.multirun
    out.mkdir(parents=True, exist_ok=True)
    params, objects, cells = table(rows)
    md = markdown(params, objects, cells)
    (out / "comparison.md").write_text("Test AP (Brégier, mean curve) per parameterization and object; over seeds: "
                                       "mean ± sample sd (runs)\n\n" + md + "\n")
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["parameterization", "object", "ap", "map", "f1", "seed", "found", "t_err_mm_p50", "r_err_deg_p50", "run"])

    def num(value: object) -> str:
        return "" if value is None else f"{float(value):.6f}"  # type: ignore[arg-type]

    for r in rows:
        w.writerow([r["parameterization"], r["object"], num(r["ap"]), num(r["map"]), num(r["f1"]),
                    "" if r["seed"] is None else r["seed"], num(r["found"]), num(r["t_err_mm_p50"]),
                    num(r["r_err_deg_p50"]), r["run"]])
    (out / "comparison.csv").write_text(buf.getvalue())
    bar_chart(params, objects, cells, out / "comparison.png")
    print(md)
    print(f"\nwritten: {out / 'comparison.md'}, {out / 'comparison.csv'}, {out / 'comparison.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
