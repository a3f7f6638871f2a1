"""The arms of a Hydra multirun in the layout of the paper's Table I: one row per finished arm, one
cell per parameterization and object, seeds as mean ± sample sd."""

from __future__ import annotations

import sys
from pathlib import Path

import yaml

from opnet.studies import mean_sd, read_summary

PAPER_ORDER = ["vanilla", "eve", "ap", "z", "mp", "si"]


def collect(multirun: Path) -> list[dict[str, object]]:
    """One row per finished arm: parameterization, object, seed, ap, map, f1, share found, median
    errors, run folder (relative to ``multirun``); an arm without ``test/summary.json`` is named and skipped."""
    rows = []
    for hydra_yaml in sorted(multirun.rglob(".hydra/hydra.yaml")):
        run = hydra_yaml.parent.parent
        choices = yaml.safe_load(hydra_yaml.read_text())["hydra"]["runtime"]["choices"]
        s = read_summary(run)
        if s is None:
            print(f"warning: {run.name}: no test/summary.json (unfinished arm?), skipped", file=sys.stderr)
            continue
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


def cell_text(values: list[float] | None) -> str:
    """``0.812`` for one run, ``0.812 ± 0.031 (3)`` over seeds, ``–`` for none."""
    if not values:
        return "–"
    if len(values) == 1:
        return f"{values[0]:.3f}"
    mean, sd = mean_sd(values)
    return f"{mean:.3f} ± {sd:.3f} ({len(values)})"


def markdown(params: list[str], objects: list[str], cells: dict[tuple[str, str], list[float]]) -> str:
    """The table: a row per parameterization, a column per object and their average."""
    head = "| parameterization | " + " | ".join(objects) + " | average |"
    lines = [head, "|" + "---|" * (len(objects) + 2)]
    for p in params:
        vals = [cells.get((p, o)) for o in objects]
        done = [mean_sd(v)[0] for v in vals if v]
        avg = f"{sum(done) / len(done):.3f}" if done else "–"
        lines.append(f"| {p} | " + " | ".join(cell_text(v) for v in vals) + f" | {avg} |")
    return "\n".join(lines)


__all__ = ["PAPER_ORDER", "cell_text", "collect", "markdown", "table"]
