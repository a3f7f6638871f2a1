"""What the entry points print: each log line once, no library adverts, one-line user errors.

- :func:`tidy_logging`: Lightning adds its own console handler to the ``lightning`` logger *and*
  lets records propagate to the root logger that Hydra configured, so each of its lines appeared
  twice (the 14-line model summary too). Its records now go through the root logger only (console
  and the run's log file, in one format); the cloud-logging advert and known harmless warnings are
  dropped.
- :func:`guarded`: a user error (bad file, bad value, missing file) prints ``error: <message>``,
  one line naming the file or config key, and exits with status 2. ``HYDRA_FULL_ERROR=1`` shows the
  traceback instead (the same switch as for Hydra's own errors).
"""

from __future__ import annotations

import logging
import os
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

from omegaconf.errors import OmegaConfBaseException

from opnet._deps import MissingDependencyError
from opnet.fileio.atomic import DiskFullError
from opnet.metrics.report import nothing_to_find_note

#: exceptions that mean "the input (or the disk) is wrong", not "the program is wrong"
USER_ERRORS: tuple[type[BaseException], ...] = (ValueError, FileNotFoundError, NotADirectoryError,
                                                 PermissionError, OmegaConfBaseException, DiskFullError,
                                                 MissingDependencyError)
_ADVERTS = ("litlogger", "LitLogger", "Lightning Experiments platform")
_HARMLESS_WARNINGS = (
    r".*isinstance\(treespec, LeafSpec\)` is deprecated.*",
    r"Precision bf16-mixed is not supported by the model summary.*",
    r".*does not have many workers which may be a bottleneck.*",
)


class _DropAdverts(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        return not any(a in message for a in _ADVERTS)


def tidy_logging() -> None:
    """Route Lightning's records through the root logger once; drop adverts and harmless warnings.
    Call it after Lightning was imported (its import adds the handler this removes)."""
    root = logging.getLogger()
    if root.handlers:  # Hydra (or the caller) configured logging: one path for every record
        for name in ("lightning", "lightning.pytorch", "lightning.fabric"):
            lg = logging.getLogger(name)
            lg.handlers.clear()
            lg.propagate = True
    for handler in root.handlers:
        if not any(isinstance(f, _DropAdverts) for f in handler.filters):
            handler.addFilter(_DropAdverts())
    for name in ("lightning", "lightning.pytorch.utilities.rank_zero"):
        lg = logging.getLogger(name)
        if not any(isinstance(f, _DropAdverts) for f in lg.filters):
            lg.addFilter(_DropAdverts())
    logging.getLogger("OpenGL").setLevel(logging.WARNING)  # "No OpenGL_accelerate module loaded"
    for pattern in _HARMLESS_WARNINGS:
        warnings.filterwarnings("ignore", message=pattern)


def report(lines: list[str]) -> None:
    """Print ``lines`` on the console as they are, and write them into the run's log file too
    (the root logger's file handlers), so ``<run>/<task>.log`` ends with the same summary."""
    text = "\n".join(lines)
    print(text, flush=True)
    record = logging.LogRecord("opnet.summary", logging.INFO, __file__, 0, "\n" + text, None, None)
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler):
            handler.handle(record)


def format_duration(seconds: float) -> str:
    minutes, sec = divmod(int(round(seconds)), 60)
    return f"{minutes} min {sec:02d} s" if minutes else f"{seconds:.1f} s"


def result_summary(result: dict[str, Any], table: str, seconds: float, verbose: bool) -> list[str]:
    """The lines that end a test or an evaluation: AP, MAP, F1, recall, found, run time (and the
    per-scene table only when ``verbose``; it is always in ``table``'s file). A split with nothing
    to find gets a note in place of the scores (they are 1.0 by convention), one with some such
    scenes a note under them (:func:`opnet.metrics.report.nothing_to_find_note`)."""
    lines = []
    if verbose:
        lines += [(Path(table).read_text() if Path(table).is_file() else ""), ""]
    diag = result.get("diagnostics") or {}
    found = f", found {diag['matched']} of {diag['to_find']} ({diag['matched'] / max(diag['to_find'], 1):.1%})" if diag else ""
    scores = (f"  AP {result['ap']:.4f}   MAP {result['map']:.4f}   F1 {result['f1']:.4f}   "
              f"R@P50 {result['recall_at_p50']:.4f}   R@P99 {result['recall_at_p99']:.4f}")
    scenes, empty = int(result.get("num_scenes", result.get("scenes", 0))), int(result.get("scenes_nothing_to_find", 0))
    note = nothing_to_find_note(scenes, empty, int(result.get("false_positives_nothing_to_find", 0)), result["ap"])
    lines.append(f"{result.get('split', 'test')} {result.get('scenes', 0)} scenes{found}")
    if note is None:
        lines.append(scores)
    else:  # every scene empty: the note instead of the scores; some: the note under them
        lines += [f"  {note}"] if empty >= scenes else [scores, f"  {note}"]
    if diag and diag.get("matched"):
        lines.append(f"  errors of the matched: translation p50 {diag['t_err_mm_p50']:.1f} mm, "
                     f"rotation p50 {diag['r_err_deg_p50']:.1f} deg")
    lines.append(f"  run time {format_duration(seconds)}")
    return lines


def debug_enabled() -> bool:
    return os.environ.get("HYDRA_FULL_ERROR", "") not in ("", "0")


def user_error_in(e: BaseException) -> BaseException | None:
    """The user error behind ``e``: ``e`` itself, or the cause Hydra's instantiation wrapped
    (``InstantiationException`` keeps the original as ``__cause__``); None for a program error."""
    seen = 0
    while e is not None and seen < 10:  # explicit chaining only: a bug raised while handling a
        if isinstance(e, USER_ERRORS):  # user error (implicit __context__) stays a bug
            return e
        e = e.__cause__
        seen += 1
    return None


def guarded(run: Callable[[Any], Any], cfg: Any) -> Any:
    """``run(cfg)``; a user error prints one line on stderr and exits 2 (traceback with HYDRA_FULL_ERROR=1)."""
    tidy_logging()
    try:
        return run(cfg)
    except MemoryError:
        if debug_enabled():
            raise
        print("error: out of memory (an input asks for an implausibly large allocation; "
              "HYDRA_FULL_ERROR=1 shows where)", file=sys.stderr)
        sys.exit(2)
    except Exception as e:
        cause = user_error_in(e)
        if cause is None or debug_enabled():
            raise
        message = str(cause).strip().splitlines()[0] if str(cause).strip() else type(cause).__name__
        print(f"error: {message}", file=sys.stderr)
        sys.exit(2)
