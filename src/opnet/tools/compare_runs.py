"""Compare the arms of a sweep in the layout of the paper's Table I.

    opnet-compare-runs outputs/train/multiruns/<date_time> [--out <dir>]

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
import sys
from pathlib import Path

from opnet.arguments import ArgumentParser, fail
from opnet.cli.tools import require_folder
from opnet.studies import mean_sd
from opnet.studies.sweeps import collect, markdown, table


def bar_chart(params: list[str], objects: list[str], cells: dict[tuple[str, str], list[float]], path: Path) -> None:
    """A grouped bar chart of the cells (the sd as error bars) at ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

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
    ap = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("multirun", type=Path, help="a Hydra multirun folder (one sub-folder per arm)")
    ap.add_argument("--out", type=Path, default=None, help="where to write comparison.* (default: the multirun folder)")
    args = ap.parse_args(argv)
    if not args.multirun.is_dir():
        return fail(f"{args.multirun}: not a folder")
    out = args.out or args.multirun
    try:
        require_folder(out, "--out")
    except ValueError as e:
        return fail(str(e))
    rows = collect(args.multirun)
    if not rows:
        return fail(f"{args.multirun}: no finished arm (no */.hydra/hydra.yaml with test/summary.json)")
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
