"""What the benchmark, study and maintenance scripts of ``scripts/`` and the tools of
:mod:`opnet.tools` share: run a command of the framework (train.py above all) with its console in a
log file, read a run's test summary, mean ± sample sd, the checkpoint a run's test scored, tables
kept across invocations. Sweeps in the layout of the paper's Table I: :mod:`opnet.studies.sweeps`;
training runs of a fixed budget: :mod:`opnet.studies.training`; scene presets, a depth image and a
network output for the benchmarks: :mod:`opnet.studies.scenes`; what a table's maker and its
renderer agree on: :mod:`opnet.studies.results`; the refinement studies' options and score:
:mod:`opnet.studies.refinement`."""

from __future__ import annotations

import csv
import io
import json
import math
import shlex
import statistics
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from opnet.paths import REPO_ROOT, best_checkpoint


def run_logged(cmd: list[str], log: Path, cwd: Path = REPO_ROOT, env: dict[str, str] | None = None) -> None:
    """Run ``cmd`` (a command of the framework: ``[python, script, overrides...]``) in ``cwd`` with its
    console in ``log``, echoing it without the interpreter; a failure exits naming the log."""
    log.parent.mkdir(parents=True, exist_ok=True)
    print(f"$ {' '.join(cmd[1:])}", flush=True)
    with log.open("w") as f:
        code = subprocess.run(cmd, cwd=cwd, env=env, stdout=f, stderr=subprocess.STDOUT, check=False).returncode
    if code:
        raise SystemExit(f"error: exit {code}; see {log}")


def compose_entry(name: str, overrides: list[str]) -> Any:
    """The config of the entry point ``<name>.py`` (``conf/<name>.yaml``) composed with ``overrides``, as it
    composes it."""
    from hydra import compose, initialize_config_dir

    from opnet.paths import config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        return compose(name, overrides=overrides)


def compose_train(overrides: list[str]) -> Any:
    """train.py's config (``conf/train.yaml``) composed with ``overrides``, as train.py composes it."""
    return compose_entry("train", overrides)


def train_command(overrides: list[str], run_dir: str | Path) -> list[str]:
    """``python train.py <overrides> hydra.run.dir=<run_dir>`` as an argv, to run in the repository root."""
    return [sys.executable, "train.py", *overrides, f"hydra.run.dir={run_dir}"]


def run_train(overrides: list[str], run_dir: Path, log: Path | None = None, env: dict[str, str] | None = None) -> None:
    """train.py with ``overrides`` into ``run_dir``, its console in ``log`` (default
    ``<run_dir>/train_stdout.log``); a failure exits naming the log (:func:`run_logged`)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    run_logged(train_command(overrides, run_dir), log or run_dir / "train_stdout.log", env=env)


def read_summary(run: str | Path, folder: str = "test") -> dict[str, Any] | None:
    """``<run>/<folder>/summary.json`` (what train.py's test or eval.py wrote), or None if it is missing."""
    path = Path(run) / folder / "summary.json"
    return json.loads(path.read_text()) if path.is_file() else None


def mean_sd(values: Iterable[float], single: float = 0.0) -> tuple[float, float]:
    """Mean and sample standard deviation; the sd of one value is ``single``."""
    values = [float(v) for v in values]
    return statistics.fmean(values), statistics.stdev(values) if len(values) > 1 else single


def mean_sd_text(values: Iterable[float], digits: int = 3) -> str:
    """``mean ± sd`` of ``values`` with ``digits`` decimals (the sd of one value is 0)."""
    mean, sd = mean_sd(values)
    return f"{mean:.{digits}f} ± {sd:.{digits}f}"


def diagnostic_shares(summary: dict[str, Any]) -> dict[str, float]:
    """A test summary's diagnostics as the tables give them: shares of the parts to find (found, no
    hypothesis, position, orientation, conflict), per-scene counts and the median errors."""
    d = summary["diagnostics"]
    n, scenes = max(d["to_find"], 1), max(summary["num_scenes"], 1)
    return {
        "found": d["matched"] / n, "no_hypothesis": d["no_hypothesis"] / n, "position": d["position"] / n,
        "orientation": d["orientation"] / n, "conflict": d["conflict"] / n,
        "confident_fp_per_scene": d["confident_false_positives"] / scenes,
        "duplicates_per_scene": d["duplicates"] / scenes,
        "t_err_mm_p50": d["t_err_mm_p50"], "r_err_deg_p50": d["r_err_deg_p50"],
    }  # fmt: skip


def merge_csv(path: Path, fields: tuple[str, ...], new: list[dict[str, Any]], key: tuple[str, ...]) -> list[dict[str, Any]]:
    """Rows of ``path`` whose key is not among the new rows', then the new rows; written back atomically
    (a table cut short by a kill would lose earlier rows)."""
    from opnet.fileio.atomic import write_text_atomic

    old = list(csv.DictReader(path.open())) if path.is_file() else []
    keys = {tuple(str(r[k]) for k in key) for r in new}
    rows = [r for r in old if tuple(str(r[k]) for k in key) not in keys] + new
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields, extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, buf.getvalue())
    return rows


def write_table_page(out: Path, title: str, lines: list[str]) -> None:
    """A script's printed ``lines`` (a Markdown table and its caption) under ``title`` and the command that printed
    them (``python <script> <arguments>`` as invoked), written atomically as the page ``out``."""
    from opnet.fileio.atomic import write_text_atomic

    command = shlex.join(["python", Path(sys.argv[0]).as_posix(), *sys.argv[1:]])
    write_text_atomic(out, "\n".join([f"# {title}", "", f"`{command}`", "", *lines, ""]))


def fmt(value: Any, kind: str = "f3") -> str:
    """A table cell: ``f<digits>`` decimals, ``pct`` a share in percent (one decimal), ``int``; ``–``
    for NaN, the text itself for what is not a number."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        return str(value)
    if math.isnan(v):  # NaN: nothing to report (e.g. no matched pair)
        return "–"
    if kind == "int":
        return f"{int(v)}"
    return f"{100 * v:.1f}" if kind == "pct" else f"{v:.{kind[1]}f}"


__all__ = ["best_checkpoint", "diagnostic_shares", "fmt", "mean_sd", "mean_sd_text", "merge_csv", "read_summary",
           "run_logged", "run_train", "train_command", "write_table_page"]
