"""opnet._pool: a worker still starting when the work is done is let finish, not killed.

The initializer is ``runpy.run_path`` (a library function, so a spawned worker can unpickle it) of
a script written here: the first worker to start returns at once, every later one sleeps, then leaves a marker.
The fast worker takes both items, so the items are done while the slow one is still starting;
terminating it then (what the pool's ``with`` block does) leaves no marker.
"""

from __future__ import annotations

import operator
import runpy
import time
from pathlib import Path

from opnet._pool import spawn_imap_unordered

_SLOW_START = """
import os, time
from pathlib import Path
here = Path({here!r})
try:
    os.mkdir(here / "first")  # atomic: exactly one worker wins
except FileExistsError:
    time.sleep({sleep})
    (here / f"started_{{os.getpid()}}").touch()
"""


def _slow_second_worker(tmp_path: Path, sleep: float) -> Path:
    script = tmp_path / "init.py"
    script.write_text(_SLOW_START.format(here=str(tmp_path), sleep=sleep))
    return script


def test_a_worker_still_starting_finishes_its_start_and_exits(tmp_path: Path) -> None:
    script = _slow_second_worker(tmp_path, 1.5)
    results = sorted(spawn_imap_unordered(operator.neg, [1, 2], 2, runpy.run_path, (str(script),)))
    assert results == [-2, -1]
    assert (tmp_path / "first").is_dir()
    assert len(list(tmp_path.glob("started_*"))) == 1  # the slow worker's start was not cut short


def test_stopping_early_terminates_the_workers(tmp_path: Path) -> None:
    script = _slow_second_worker(tmp_path, 30)
    start = time.perf_counter()
    results = spawn_imap_unordered(operator.neg, range(4), 2, runpy.run_path, (str(script),))
    assert next(results) in (0, -1, -2, -3)
    results.close()  # the caller stops: the sleeping worker is not waited for
    assert time.perf_counter() - start < 20 and not list(tmp_path.glob("started_*"))
