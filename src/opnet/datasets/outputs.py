"""Outputs that cannot lose data: an output that is an input is refused, a folder is replaced as a
whole or not at all, and a run holds a lock on the folder it writes into.

- :func:`is_within`, :func:`require_output_folder`: "``out=`` is an input" (links and ``..``
  resolved), refused.
- :func:`folder_replaced`: a writer fills a temporary folder beside the target, which then takes the
  target's place; a non-empty target is refused unless the caller says to replace it. Readers see
  the old folder or the new one, never a mix (between the two renames the path is briefly absent).
- :func:`folder_lock`: ``flock`` on ``<folder>/.opnet-writing.lock`` for the duration of a run; a
  second run into the same folder stops at once with an error naming it. The kernel drops the lock
  when a run dies, so a killed run leaves no stale lock behind.

No PyTorch: the torch-free ONNX runner uses it.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from opnet.fileio.atomic import DiskFullError, _umask

log = logging.getLogger(__name__)

LOCK_NAME = ".opnet-writing.lock"


def is_within(path: str | Path, folder: str | Path) -> bool:
    """Whether ``path`` is ``folder`` or lies inside it, after resolving links and ``..``."""
    p, f = Path(path).resolve(), Path(folder).resolve()
    return p == f or f in p.parents


def require_output_folder(out: str | Path, inputs: Iterable[Path], option: str) -> None:
    """Refuse an output folder that is one of the ``inputs`` (files) or lies inside one, or that
    exists as a file; ``option`` is how the user names it (``out=``, ``--out``)."""
    out = Path(out)
    for path in inputs:
        if is_within(out, path):
            raise ValueError(f"{out}: the output folder would be the input {path}; choose another {option}")
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: exists and is not a folder; choose another {option}")


@contextlib.contextmanager
def folder_replaced(path: str | Path, overwrite: bool, option: str = "--overwrite") -> Iterator[Path]:
    """A fresh temporary folder beside ``path`` to write into; when the block ends without an
    error it replaces ``path`` (created if absent), else it is deleted and ``path`` is untouched.

    Args:
        path: the folder to write.
        overwrite: replace a non-empty ``path``; refused otherwise.
        option: how the user says ``overwrite`` (named in the error).
    Raises:
        ValueError: ``path`` is a file, or a non-empty folder without ``overwrite``.
    """
    path = Path(path)
    if path.exists():
        if not path.is_dir():
            raise ValueError(f"{path}: exists and is not a folder; choose another output folder")
        if not overwrite and any(path.iterdir()):
            raise ValueError(f"{path}: exists and is not empty; pass {option} to replace it, or choose another folder")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    try:
        yield tmp
        os.chmod(tmp, 0o777 & ~_umask())  # an ordinary folder's mode, not mkdtemp's private 0700
        _swap_in(tmp, path, overwrite, option)
    except DiskFullError as e:  # named as the file in the target, not in the deleted temporary folder
        name = str(e.filename)
        if not name.startswith(str(tmp)):
            raise
        raise DiskFullError(e.errno, e.strerror, str(path) + name[len(str(tmp)):]) from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _swap_in(new: Path, path: Path, overwrite: bool, option: str) -> None:
    """Put folder ``new`` at ``path``; with ``overwrite``, a previous ``path`` is moved aside first,
    then deleted. Without it, ``path`` must still be absent or empty: a rename onto a folder that
    another run filled meanwhile fails (atomically), and that run's files stay."""
    if not overwrite or not path.exists():
        try:
            os.rename(new, path)
        except OSError as e:
            if e.errno not in (errno.ENOTEMPTY, errno.EEXIST):
                raise
            raise ValueError(f"{path}: another run filled this folder while this one was writing; its files were "
                             f"kept and this run's discarded; pass {option} to replace them") from None
        return
    old = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".old", dir=path.parent))
    os.rename(path, old)  # onto the empty folder just made: atomic
    try:
        os.rename(new, path)
    except OSError:
        os.rename(old, path)
        raise
    shutil.rmtree(old, ignore_errors=True)


def _try_lock(fd: int) -> bool:
    """Take an exclusive lock on the open file ``fd`` without waiting; False if another holds it."""
    try:
        import fcntl
    except ImportError:  # Windows
        import msvcrt

        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
            return True
        except OSError:
            return False
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return True
    except BlockingIOError:
        return False


def holder_pid(folder: str | Path) -> int | None:
    """The process id recorded in ``folder``'s lock file while that process lives; None where the
    file names none (a run of an older version, Windows, where the held file cannot be read) or a
    process that has ended."""
    if os.name == "nt":  # os.kill would end the process, not test it
        return None
    try:
        pid = int((Path(folder) / LOCK_NAME).read_text().strip())
    except (OSError, ValueError):
        return None
    if pid <= 0:
        return None
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return None
    except PermissionError:  # alive, another user's
        pass
    return pid


def _busy(folder: Path, option: str) -> ValueError:
    pid = holder_pid(folder)
    if pid is None:
        return ValueError(f"{folder}: another run is writing into this folder (it holds {LOCK_NAME}); wait for it "
                          f"to finish, or choose another {option}")
    return ValueError(f"{folder}: another run (pid {pid}) is writing into this folder; wait for it to finish, "
                      f"or choose another {option}")


def _acquire(folder: Path, option: str) -> int | None:
    """The descriptor of the held lock file, or None where the file system has no locks."""
    path = folder / LOCK_NAME
    for _ in range(100):
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        try:
            locked = _try_lock(fd)
        except OSError as e:
            os.close(fd)
            if e.errno in (errno.ENOLCK, errno.EOPNOTSUPP, errno.ENOTSUP):
                log.warning("%s: the file system has no locks; concurrent runs into it are not detected", folder)
                return None
            raise
        if not locked:
            os.close(fd)
            raise _busy(folder, option)
        try:  # the holder before us may have deleted the file while we opened it: lock the current one
            if os.path.samestat(os.fstat(fd), os.stat(path)):
                return fd
        except FileNotFoundError:
            pass
        os.close(fd)
    raise _busy(folder, option)


@contextlib.contextmanager
def folder_lock(folder: str | Path, option: str = "output folder") -> Iterator[None]:
    """Hold an exclusive lock on ``folder`` (created if needed) while the block runs; the lock file
    records this process's id, so that a refused run can name the holder.

    Args:
        option: how the user names the folder (``out=``, ``--out``), for the message.
    Raises:
        ValueError: another process (or another run in this one) holds it; one line naming the
            folder and, where the lock file records a live one, the holder's process id.
    """
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # a file at the path or above it
        raise ValueError(f"{folder}: cannot be made an output folder ({e.strerror})") from None
    fd = _acquire(folder, option)
    if fd is not None:
        with contextlib.suppress(OSError):  # the id only names the holder; the lock is the kernel's
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode())
    try:
        yield
    finally:
        if fd is not None:
            with contextlib.suppress(OSError):  # deleted while held: a later run makes a new one
                (folder / LOCK_NAME).unlink()
            os.close(fd)
