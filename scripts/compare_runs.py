"""Compare the arms of a sweep in the layout of the paper's Table I.

    python scripts/compare_runs.py outputs/train/multiruns/<date_time> [--out <dir>]

Rows: parameterizations; columns: objects; cells: test AP (the Brégier mean-curve AP of each
arm's ``test/summary.json``). Writes ``comparison.md``, ``comparison.csv`` and ``comparison.png``
(a grouped bar chart) into the multirun folder (or --out), and prints the table.
"""

from __future__ import annotations

import argparse
import csv
import io
import json
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
        rows.append({"parameterization": choices.get("parameterization"), "object": choices.get("object"),
                     "ap": s["ap"], "map": s["map"], "f1": s["f1"], "run": str(run.relative_to(multirun))})
    return rows


def table(rows: list[dict[str, object]]) -> tuple[list[str], list[str], dict[tuple[str, str], float]]:
    params = sorted({str(r["parameterization"]) for r in rows}, key=lambda p: (PAPER_ORDER.index(p) if p in PAPER_ORDER else 99, p))
    objects = sorted({str(r["object"]) for r in rows})
    cells = {(str(r["parameterization"]), str(r["object"])): float(r["ap"]) for r in rows}  # type: ignore[arg-type]
    return params, objects, cells


def markdown(params: list[str], objects: list[str], cells: dict[tuple[str, str], float]) -> str:
    head = "| parameterization | " + " | ".join(objects) + " | average |"
    lines = [head, "|" + "---|" * (len(objects) + 2)]
    for p in params:
        vals = [cells.get((p, o)) for o in objects]
        done = [v for v in vals if v is not None]
        avg = f"{sum(done) / len(done):.3f}" if done else "–"
        lines.append(f"| {p} | " + " | ".join("–" if v is None else f"{v:.3f}" for v in vals) + f" | {avg} |")
    return "\n".join(lines)


def bar_chart(params: list[str], objects: list[str], cells: dict[tuple[str, str], float], path: Path) -> None:
    fig, ax = plt.subplots(figsize=(1.5 + 1.2 * len(objects) * max(1, len(params)) / 3, 3.5), dpi=120)
    width = 0.8 / max(1, len(params))
    for k, p in enumerate(params):
        xs = [i + k * width for i in range(len(objects))]
        ax.bar(xs, [cells.get((p, o), 0.0) for o in objects], width, label=p)
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
    (out / "comparison.md").write_text("Test AP (Brégier, mean curve) per parameterization and object\n\n" + md + "\n")
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["parameterization", "object", "ap", "map", "f1", "run"])
    for r in rows:
        w.writerow([r["parameterization"], r["object"], f"{r['ap']:.6f}", f"{r['map']:.6f}", f"{r['f1']:.6f}", r["run"]])
    (out / "comparison.csv").write_text(buf.getvalue())
    bar_chart(params, objects, cells, out / "comparison.png")
    print(md)
    print(f"\nwritten: {out / 'comparison.md'}, {out / 'comparison.csv'}, {out / 'comparison.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
