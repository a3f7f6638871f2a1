"""One writer a folder: a second run into the output folder of a running one stops at once.

:func:`writer_lock` holds :func:`opnet.datasets.outputs.folder_lock` (the lock predict.py takes on
its ``out=``) and records this process's id in the lock file, so that the run it refuses names the
holder: ``<folder>: another run (pid 1234) is writing into this folder; ...``. The kernel drops
the lock when its holder dies, so a crashed run's lock file blocks nobody, and the id it still
holds is named only while that process lives. generate.py locks its ``out=``, eval.py its ``out=``
and train.py its run directory (:class:`RunDirLock`, a Hydra callback: the lock is taken before
Hydra writes the run's ``.hydra/`` config and log into the directory).
"""

from __future__ import annotations

import atexit
import contextlib
import errno
import logging
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from opnet.datasets.outputs import folder_lock

log = logging.getLogger(__name__)

#: errno values of a folder this process may not write into: nothing of its run can be written there
_READ_ONLY = (errno.EACCES, errno.EPERM, errno.EROFS)


@contextlib.contextmanager
def writer_lock(folder: str | Path, option: str) -> Iterator[None]:
    """Hold the output lock on ``folder`` (made if absent) while the block runs, its lock file naming
    this process; a folder made here and left empty (a run that failed before writing) is removed.

    A folder this process may not write into is not locked: the run cannot write there either, and
    its first write says so.

    Args:
        folder: the output folder.
        option: how the user names it (``out=``, ``hydra.run.dir=``), for the messages.
    Raises:
        ValueError: ``folder`` is a file or cannot be made, or another run holds its lock: one line
            naming the folder and that run's process id (where the lock file records a live one).
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{folder}: exists and is not a folder; choose another {option}")
    made = not folder.exists()
    held = contextlib.ExitStack()
    try:
        held.enter_context(folder_lock(folder, option))
    except OSError as e:
        if e.errno not in _READ_ONLY:
            raise
        log.debug("%s: not writable (%s): not locked", folder, e.strerror)
    try:
        with held:
            yield
    finally:
        if made:
            with contextlib.suppress(OSError):  # only while empty
                folder.rmdir()


def _launched_worker() -> bool:
    """This process is a worker that Lightning's process launcher started for distributed training (it
    re-runs train.py with LOCAL_RANK / NODE_RANK set, into the same run directory)."""
    return any(os.environ.get(key, "0") not in ("", "0") for key in ("LOCAL_RANK", "NODE_RANK"))


class RunDirLock(Callback):
    """Hydra callback of train.py (``hydra.callbacks`` in conf/train.yaml): holds :func:`writer_lock`
    on the run directory (``hydra.run.dir``) from before Hydra writes anything into it until the run
    ends. A second run into the directory of a running one prints one line naming the directory and
    the holder, and exits with status 2 having written nothing.
    """

    def __init__(self) -> None:
        self._held: contextlib.ExitStack | None = None

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        if _launched_worker():  # a DDP worker Lightning started: its launcher, rank 0, holds the lock
            return
        held = contextlib.ExitStack()
        try:
            held.enter_context(writer_lock(str(config.hydra.run.dir), "hydra.run.dir="))
        except ValueError as e:  # Hydra turns a callback's exception into a warning and runs on
            print(f"error: {e}", file=sys.stderr, flush=True)
            sys.exit(2)
        self._held = held
        atexit.register(self.release)  # a run ended by a user error (sys.exit) never reaches on_run_end

    def on_run_end(self, config: DictConfig, **kwargs: Any) -> None:
        self.release()

    def release(self) -> None:
        """Drop the lock (once)."""
        held, self._held = self._held, None
        if held is not None:
            atexit.unregister(self.release)
            held.close()
