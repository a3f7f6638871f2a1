"""Atomic writes: complete files only, with the permissions of an ordinary write."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from opnet.fileio.atomic import write_bytes_atomic, write_text_atomic


@pytest.mark.skipif(not hasattr(os, "fchmod"), reason="POSIX file modes")
@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_atomic_files_get_the_mode_of_an_ordinary_write(tmp_path: Path, umask: int) -> None:
    old = os.umask(umask)
    try:
        write_text_atomic(tmp_path / "a" / "gt.json", "{}\n")
        with open(tmp_path / "plain.txt", "w") as f:
            f.write("x")
    finally:
        os.umask(old)
    mode = stat.S_IMODE((tmp_path / "a" / "gt.json").stat().st_mode)
    assert mode == stat.S_IMODE((tmp_path / "plain.txt").stat().st_mode) == 0o666 & ~umask


def test_atomic_write_replaces_and_leaves_no_temporary_file(tmp_path: Path) -> None:
    target = tmp_path / "x.bin"
    write_bytes_atomic(target, b"old")
    write_bytes_atomic(target, b"new content")
    assert target.read_bytes() == b"new content"
    assert [p.name for p in tmp_path.iterdir()] == ["x.bin"]


def test_an_atomic_write_never_replaces_a_fifo_or_a_device(tmp_path: Path) -> None:
    """os.replace puts the written file in the place of whatever is at the path: as root, a tool told to
    write /dev/null turned the device into a regular file. Refused, naming it, the path left as it was."""
    fifo = tmp_path / "pipe.yaml"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match=rf"^{fifo}: not a regular file \(a FIFO\); writing a file there would replace it"):
        write_text_atomic(fifo, "x")
    assert stat.S_ISFIFO(os.stat(fifo).st_mode) and sorted(p.name for p in tmp_path.iterdir()) == ["pipe.yaml"]
    null = tmp_path / "null"  # a null device of its own (where this user may make one): never /dev/null itself
    try:
        os.mknod(null, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except OSError:
        return
    with pytest.raises(ValueError, match=rf"^{null}: not a regular file \(a device\)"):
        write_bytes_atomic(null, b"x")
    assert stat.S_ISCHR(os.stat(null).st_mode)
