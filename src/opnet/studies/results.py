"""What a script that makes a committed table and the one that renders it into the docs
(``scripts/dev/readme_figures.py``) must agree on: the machine a row was measured on, the spread of
the quickstart over seeds, the dense benchmark's headline configuration, the new-parts table's cells."""

from __future__ import annotations

import platform
import re
import statistics
from pathlib import Path
from typing import Any

from opnet.studies import fmt, mean_sd

#: the configuration of the dense benchmark's headline table (the 60-minute recipe of ``experiment=dense``)
DENSE_HEADLINE = "recipe60"


class ProbePage:
    """A probe script's Markdown page: its title and command, then every line printed as it comes
    (:meth:`emit`) and written at once at the end (:meth:`write`)."""

    def __init__(self, title: str, command: str) -> None:
        self.lines = [f"# {title}", "", f"`{command}`", ""]

    @classmethod
    def of_script(cls, doc: str, script: str | Path, argv: list[str] | None) -> ProbePage:
        """The page of the script ``script`` (its path) whose module docstring is ``doc`` (the first line: the
        title), run with ``argv`` (None: the command line's)."""
        import sys

        from opnet.paths import REPO_ROOT

        args = sys.argv[1:] if argv is None else argv
        return cls(doc.splitlines()[0], " ".join(["python", str(Path(script).resolve().relative_to(REPO_ROOT)),
                                                  *args]))

    @classmethod
    def checkpoint_probe(cls, ap: Any, doc: str, script: str | Path, argv: list[str] | None) -> tuple[Any, ...]:
        """A probe of a checkpoint's decoded outputs: ``ap`` (an argparse parser with the probe's own options)
        takes ``ckpt``, ``--splits`` (default val and test) and ``--out``; the command line parsed, each split
        recorded and decoded as the checkpoint records (:func:`opnet.cli.decoding_search.decoded_as_recorded`).
        Returns ``(args, page, recorded, settings, decoded, obj)``, ``obj`` the checkpoint's part."""
        from opnet.cli.decoding_search import decoded_as_recorded

        ap.add_argument("ckpt", type=Path)
        ap.add_argument("--splits", nargs="+", default=["val", "test"])
        ap.add_argument("--out", type=Path, help="also write the tables to this Markdown file")
        args = ap.parse_args(argv)
        page = cls.of_script(doc, script, argv)
        recorded, settings, decoded = decoded_as_recorded(args.ckpt, args.splits)
        return args, page, recorded, settings, decoded, next(iter(recorded.values())).parameterization.obj

    def emit(self, text: str = "") -> None:
        print(text, flush=True)
        self.lines.extend(text.split("\n"))

    def write(self, out: Path | None) -> None:
        """The page, atomically, to ``out`` (None: nowhere)."""
        if out is not None:
            from opnet.fileio.atomic import write_text_atomic

            write_text_atomic(out, "\n".join(self.lines) + "\n")


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), or the platform's processor string."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def seed_spread(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One entry per (CPU, native bf16, precision path) of the quickstart's seed rows, sorted: its
    seeds, the test AP's mean, sample sd (NaN for one run), min and max, and the mean wall time of the
    runs that did not generate data (NaN when all did)."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((str(r["cpu"]), str(r["native_bf16"]), str(r["precision_path"])), []).append(r)
    out = []
    for (cpu, native, precision), rs in sorted(groups.items()):
        aps = [float(r["ap"]) for r in rs]
        walls = [float(r["wall_s"]) for r in rs if str(r["with_generation"]) != "True"]
        mean, sd = mean_sd(aps, single=float("nan"))
        out.append({"cpu": cpu, "native_bf16": native == "True", "precision_path": precision,
                    "seeds": [str(r["seed"]) for r in rs], "ap_mean": mean, "ap_sd": sd, "ap_min": min(aps),
                    "ap_max": max(aps), "wall_s": statistics.fmean(walls) if walls else float("nan")})  # fmt: skip
    return out


__all__ = ["DENSE_HEADLINE", "cpu_model", "seed_spread"]


def symmetry_cell(row: dict[str, Any]) -> str:
    """A new part's group as ``opnet-object`` finds it and, where it names one, its near-symmetry's turn and
    deviation (``near_symmetry``), e.g. ``none (near: 180° about [+0.00, +0.00, +1.00], 2.92 mm)``."""
    m = re.match(r"([\d.]+) deg about (\[[^\]]*\]) \(model frame\), ([\d.]+) mm", row.get("near_symmetry") or "")
    return f"{row['symmetry']} (near: {float(m.group(1)):.0f}° about {m.group(2)}, {m.group(3)} mm)" if m else row["symmetry"]


def fill_cell(row: dict[str, Any]) -> str:
    """The recipe's bin fill for a new part, and in brackets its training piles' where those were made with another
    bin (``fill_made``)."""
    if row.get("fill") in ("", None):
        return "–"
    made = f" ({fmt(row['fill_made'], 'f2')} as made)" if row.get("fill_made") not in ("", None) else ""
    return f"{fmt(row['fill'], 'f2')}{made}"


def refined_cell(row: dict[str, Any]) -> str:
    """A new part's held-out AP with its hypotheses refined, and in brackets on the other engine's piles
    (``0.412 (0.388)``); ``–`` where the model was not scored so."""
    if row.get("ap_refined") in ("", None):
        return "–"
    other = row.get("ap_pybullet_refined")
    return fmt(row["ap_refined"]) + ("" if other in ("", None) else f" ({fmt(other)})")


def decoding_cell(row: dict[str, Any]) -> str:
    """A new part's held-out AP in bold, and in brackets the other decoding scored: the one its recipe was
    configured with where the recipe tuned its own after training (``ap_configured``), else the one tuned on
    validation after the recipe (``ap_tuned``)."""
    for key, what in (("ap_configured", "configured"), ("ap_tuned", "tuned")):
        if row.get(key) not in ("", None):
            return f"**{fmt(row['ap'])}** ({fmt(row[key])} {what})"
    return f"**{fmt(row['ap'])}**"


def other_engine_cell(row: dict[str, Any]) -> str:
    """A new part's AP on the other engine's piles, or why there is none: ``not made``, ``not run``."""
    if row.get("ap_pybullet") not in ("", None):
        return fmt(row["ap_pybullet"])
    return (row.get("pybullet_note") or "not run").split(":")[0]
