"""Output folders: a lock between processes that a killed holder does not leave behind, and a
folder replaced as a whole or not at all."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from opnet.datasets.outputs import LOCK_NAME, folder_lock, folder_replaced


def test_lock_held_by_another_process_and_released_when_it_is_killed(tmp_path: Path) -> None:
    holder = subprocess.Popen(
        [sys.executable, "-c", "import sys, time\nfrom opnet.datasets.outputs import folder_lock\n"
         f"with folder_lock({str(tmp_path)!r}):\n    print('held', flush=True)\n    time.sleep(60)"],
        stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(ValueError, match=rf"^{tmp_path}: another run \(pid {holder.pid}\) is writing into this folder; "
                           "wait for it to finish, or choose another output folder$"):
            with folder_lock(tmp_path):
                pass
    finally:
        holder.kill()
        holder.wait()
    assert (tmp_path / LOCK_NAME).exists()  # killed: the file stays, the lock does not
    with folder_lock(tmp_path):
        pass
    assert not (tmp_path / LOCK_NAME).exists()


def test_failed_replacement_leaves_the_folder_as_it_was(tmp_path: Path) -> None:
    target = tmp_path / "out"
    target.mkdir()
    (target / "keep.txt").write_text("old")
    with pytest.raises(ValueError, match=f"^{target}: exists and is not empty; pass --overwrite"):
        with folder_replaced(target, overwrite=False):
            pass
    with pytest.raises(OSError):
        with folder_replaced(target, overwrite=True) as tmp:
            (tmp / "half.txt").write_text("new")
            raise OSError(28, "No space left on device")
    assert [p.name for p in tmp_path.iterdir()] == ["out"] and [p.name for p in target.iterdir()] == ["keep.txt"]
    with folder_replaced(target, overwrite=True) as tmp:
        (tmp / "new.txt").write_text("new")
    assert [p.name for p in tmp_path.iterdir()] == ["out"] and [p.name for p in target.iterdir()] == ["new.txt"]
