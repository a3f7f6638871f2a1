"""What the console tools (``opnet-tune-decoding``, ``opnet-record-trained-clip``, ``opnet-oracle``,
``opnet-diagnose-sources``, ``opnet-compare-runs``, ``opnet-object``) and export.py share with the entry
points: a user error is one line ``error: <file>: <problem>`` and exit status 2, a target that cannot be
written (or an existing file without ``--force``) is refused before the work, and a checkpoint is written
atomically (a failure leaves the target as it was and no temporary file). Their options are parsed by
:mod:`opnet.arguments`.
"""

from __future__ import annotations

import io
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any

from opnet.cli.console import guarded
from opnet.fileio.atomic import write_bytes_atomic, write_errors_named


def tool_main(body: Callable[[], int]) -> int:
    """``body()``'s exit status, with the entry points' handling of a user error
    (:func:`opnet.cli.console.guarded`): a refused checkpoint, a missing dataset, a target that cannot
    be written print ``error: <message>`` on one line and give 2 (``HYDRA_FULL_ERROR=1``: the traceback)."""
    try:
        return guarded(lambda _: body(), None)
    except SystemExit as e:  # guarded's exit of a user error, as the status a script's main returns
        if e.code != 2:
            raise
        return 2


def require_writable(path: str | Path, option: str, replace: bool = True) -> Path:
    """``path`` if a file can be written there (checked before a long run that would fail only at
    its end): not a folder or another non-file, in a folder (or below the nearest existing one) that
    this process may write into; with ``replace`` False, no file yet.

    Args:
        option: how the user names ``path`` (``--write``, ``out=``), for the message.
        replace: an existing file may be replaced (``--force``, ``--in-place``).
    Raises:
        ValueError: naming ``path``: what is in the way.
    """
    path = Path(path)
    if path.exists() and not path.is_file():
        raise ValueError(f"{path}: exists and is not a regular file; {option} takes the name of a file to write")
    if path.exists() and not replace:
        raise ValueError(f"{path}: exists; give --force to replace it, or another {option}")
    _require_folder_above(path, option)
    return path


def require_folder(path: str | Path, option: str) -> Path:
    """``path`` if it is a folder this process may write into, or one it may make (checked before the work).

    Raises:
        ValueError: naming ``path``: a file there (or above it), or a folder that is not writable.
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{path}: exists and is not a folder; {option} takes a folder to write into")
    if path.is_dir():
        if not os.access(path, os.W_OK):
            raise ValueError(f"{path}: the folder is not writable; choose another {option}")
        return path
    _require_folder_above(path, option)
    return path


def _require_folder_above(path: Path, option: str) -> None:
    folder = next(p for p in path.parents if p.exists())  # "." or the root at the latest
    if not folder.is_dir():
        raise ValueError(f"{path}: {folder} is a file, not a folder; choose another {option}")
    if not os.access(folder, os.W_OK):
        raise ValueError(f"{path}: the folder {folder} is not writable; choose another {option}")


def save_checkpoint(ckpt: dict[str, Any], dest: str | Path) -> None:
    """Write the checkpoint ``ckpt`` (``torch.save``) to ``dest`` atomically; a failure (a read-only
    folder, a full disk, a folder at ``dest``) leaves ``dest`` as it was and no temporary file.

    Raises:
        ValueError, DiskFullError: one line naming ``dest``.
    """
    import torch

    buffer = io.BytesIO()
    torch.save(ckpt, buffer)
    with write_errors_named(dest):
        write_bytes_atomic(dest, buffer.getvalue())
