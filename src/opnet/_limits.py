"""Caps on counts of threads and processes taken from the user (config keys, command lines)."""

from __future__ import annotations

import os

from opnet._repr import short_repr

#: more threads or worker processes than this per core only thrash (and thousands hang the process
#: creating them: ``--threads 20000``)
MAX_THREADS_PER_CORE = 4


def check_threads(threads: object, key: str = "threads") -> int:
    """A count of threads or worker processes in 1 .. :data:`MAX_THREADS_PER_CORE` x the cores
    (20,000 threads hung the host); ``ValueError`` naming ``key`` otherwise."""
    cores = os.cpu_count() or 1
    limit = MAX_THREADS_PER_CORE * cores
    if isinstance(threads, bool) or not isinstance(threads, int) or not 1 <= threads <= limit:
        raise ValueError(f"{key}={short_repr(threads)}: expected a whole number in 1..{limit} "
                         f"({MAX_THREADS_PER_CORE} per core on this machine's {cores})")
    return threads
