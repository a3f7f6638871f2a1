"""Worker pools of fresh interpreters (``spawn``: physics engines, EGL and torch's OpenMP pool do
not survive a fork). A leaf module: the generator and the scene cache both use it."""

from __future__ import annotations

import multiprocessing as mp
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

T = TypeVar("T")
R = TypeVar("R")


def spawn_imap_unordered(fn: Callable[[T], R], items: Iterable[T], workers: int,
                         initializer: Callable[..., Any] | None = None, initargs: tuple = ()) -> Iterator[R]:
    """Yield ``fn(item)`` for every item, in the order they finish, from ``workers`` spawned processes.

    When every result has been yielded the pool is closed and joined: a worker still starting up
    (another took all the items) finishes its ``initializer`` and exits by itself. Terminating it
    instead kills it mid-import, and what it had started goes on without it, e.g. the version probe
    that importing MuJoCo runs in a child process (glfw), which then prints a BrokenPipeError
    traceback into the caller's console. On an error, or when the caller stops early, the workers
    are terminated (nothing more is wanted from them).
    """
    with mp.get_context("spawn").Pool(workers, initializer=initializer, initargs=initargs) as pool:
        yield from pool.imap_unordered(fn, items, chunksize=1)
        pool.close()
        pool.join()


__all__ = ["spawn_imap_unordered"]
