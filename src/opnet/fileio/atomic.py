"""Atomic file writes: a reader never sees a half-written dataset file.

The data goes to a temporary file in the destination folder (same file system), which then
replaces the destination with ``os.replace`` (atomic on POSIX and Windows). No fsync: this guards
against concurrent readers and crashed writers, not against power loss. The file gets the mode a
plain ``open(path, "w")`` would give it (0666 less the umask), not ``mkstemp``'s private 0600, so
that a shared dataset or results folder stays readable by colleagues.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

from opnet.fileio.files import file_kind

#: errno values of a write that failed for want of space: a full disk or an exhausted quota
DISK_FULL_ERRNOS = (errno.ENOSPC, errno.EDQUOT)


class DiskFullError(OSError):
    """A write failed for want of space; ``filename`` is the file (or folder) being written.

    One line naming it, for the entry points (an ``OSError``, so that it is not mistaken for bad
    input by the per-image loops, which go on with the next image)."""

    def __str__(self) -> str:
        return f"{self.filename}: {self.strerror} (disk full); free some space or choose another output folder"


@contextlib.contextmanager
def disk_full_named(path: str | Path) -> Iterator[None]:
    """Turn an ``OSError`` of a full disk (ENOSPC, EDQUOT) raised in the block into a
    :class:`DiskFullError` naming ``path``; other errors pass unchanged."""
    try:
        yield
    except DiskFullError:
        raise
    except OSError as e:
        if e.errno not in DISK_FULL_ERRNOS:
            raise
        raise DiskFullError(e.errno, os.strerror(e.errno), str(path)) from None


def _umask() -> int:
    """The process's umask, read without changing it where the system tells it (Linux)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)  # elsewhere: set and restore at once
    os.umask(mask)
    return mask


@contextlib.contextmanager
def write_errors_named(path: str | Path) -> Iterator[None]:
    """Name ``path``, the one file a tool writes, in an ``OSError`` raised in the block, in one line
    for the entry points: a full disk as a :class:`DiskFullError`, any other (a read-only folder or
    file system, a folder at ``path``, a file where its folder should be) as a ``ValueError``
    ``<path>: ...``, not naming the temporary file beside it (deleted by then). The per-image loops
    do without it: to them an ``OSError`` is no bad input."""
    try:
        with disk_full_named(path):
            yield
    except DiskFullError:
        raise
    except OSError as e:
        path = Path(path)
        if path.is_dir():
            raise ValueError(f"{path}: is a folder; give the name of a file to write") from e
        above = next((p for p in path.parents if p.exists()), None)
        if above is not None and not above.is_dir():
            raise ValueError(f"{path}: {above} is a file, not a folder") from e
        raise ValueError(f"{path}: cannot be written ({e.strerror or type(e).__name__})") from e


def temporary_beside(path: str | Path) -> tuple[int, Path]:
    """A new, empty temporary file in ``path``'s folder (made if absent; the same file system, so that
    ``os.replace`` onto ``path`` is atomic), unique to this writer, with the mode a plain ``open``
    would give it: its open descriptor and its path."""
    path = Path(path)
    with disk_full_named(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        if hasattr(os, "fchmod"):
            os.fchmod(fd, 0o666 & ~_umask())
    except BaseException:
        os.close(fd)
        Path(tmp).unlink(missing_ok=True)
        raise
    return fd, Path(tmp)


def remove_stale_temporaries(targets: Iterable[str | Path]) -> int:
    """Delete the temporary files (:func:`temporary_beside`: ``.<name>.<random>.tmp``) that a writer
    killed in the middle of writing one of ``targets`` left beside it; returns how many. Only for a
    caller that holds the folder for itself (its lock): a live writer's temporary file looks the same.
    Each folder is listed once, however many targets it holds."""
    names: dict[Path, set[str]] = {}
    for target in map(Path, targets):
        names.setdefault(target.parent, set()).add(target.name)
    removed = 0
    for folder, wanted in names.items():
        if not folder.is_dir():
            continue
        for tmp in folder.glob(".*.tmp"):
            if tmp.name[1:-len(".tmp")].rpartition(".")[0] in wanted and tmp.is_file():
                tmp.unlink(missing_ok=True)
                removed += 1
    return removed


def _require_replaceable(path: Path) -> None:
    """Refuse a FIFO, socket or device at ``path``: ``os.replace`` would put the written file in its
    place (as root, ``/dev/null`` became a regular file). A folder there fails in ``os.replace`` itself.

    Raises:
        ValueError: naming ``path`` and what it is.
    """
    try:
        mode = os.stat(path).st_mode
    except OSError:  # absent (or its folder is): the write itself says what is wrong
        return
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise ValueError(f"{path}: not a regular file ({file_kind(mode)}); writing a file there would replace it, "
                         "give the name of a file to write")


def write_bytes_atomic(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically, creating the parent folders.

    Args:
        path: destination file; replaced if it exists.
        data: the complete file content.
    """
    path = Path(path)
    _require_replaceable(path)
    fd, tmp = temporary_beside(path)
    try:
        with disk_full_named(path):
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def write_text_atomic(path: str | Path, text: str) -> None:
    """Write UTF-8 ``text`` to ``path`` atomically (``\\n`` line endings on every platform)."""
    write_bytes_atomic(path, text.encode("utf-8"))


def write_text_if_changed(path: str | Path, text: str) -> bool:
    """Write ``text`` atomically unless ``path`` already holds exactly it; returns whether it wrote.

    A complete dataset or cache on read-only storage is then used without a single write.
    """
    path = Path(path)
    try:
        if path.is_file() and path.read_bytes() == text.encode("utf-8"):
            return False
    except OSError:
        pass
    write_text_atomic(path, text)
    return True


def append_csv_rows(path: str | Path, header: list[str], rows: list[list[Any]]) -> None:
    """Append ``rows`` to the CSV ``path`` (created with ``header``), rewriting it atomically.

    Raises:
        ValueError: the file exists with another header (the message names the file and both).
    """
    import csv
    import io

    path = Path(path)
    text = path.read_text() if path.is_file() else ""
    if text:
        first = next(csv.reader(io.StringIO(text)))
        if first != header:
            raise ValueError(f"{path}: header {first} differs from {header}; write to another file")
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    if not text:
        writer.writerow(header)
    writer.writerows(rows)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, text + buf.getvalue())
