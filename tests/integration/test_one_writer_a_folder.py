"""One writer a folder: generate.py into the ``out=`` of a running generation, train.py into the
run directory of a running training and eval.py into the ``out=`` of a running evaluation stop at
once with one line naming the folder and the process that writes it, exit 2 and write nothing (they
used to claim the same work, or overwrite each other's checkpoints and results, and both exit 0).
The lock is predict.py's (:func:`opnet.datasets.outputs.folder_lock`); a crashed run's lock blocks
nobody."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from opnet.datasets.outputs import LOCK_NAME
from opnet.paths import REPO_ROOT

#: a run holding the output lock on argv[1], its process id recorded in the lock file as opnet's runs do
_HOLDER = """
import os, sys
from pathlib import Path
from opnet.datasets.outputs import LOCK_NAME, folder_lock
with folder_lock(sys.argv[1]):
    (Path(sys.argv[1]) / LOCK_NAME).write_text(f"{os.getpid()}\\n")
    print("held", flush=True)
    sys.stdin.read()
"""


@contextlib.contextmanager
def _held(folder: Path, code: str = _HOLDER) -> Iterator[subprocess.Popen]:
    """Another process holding the output lock on ``folder`` while the block runs."""
    holder = subprocess.Popen([sys.executable, "-c", code, str(folder)], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        yield holder
    finally:
        holder.kill()
        holder.wait()


def _tree(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` (hidden ones too) with its bytes."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _refused(args: list[str], folder: Path, holder: subprocess.Popen, option: str) -> None:
    """Run ``args``: exit 2 at once, one line naming ``folder`` and the holder's pid, nothing written."""
    before = _tree(folder)
    proc = subprocess.run([sys.executable, *args], cwd=REPO_ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr[-2000:]
    said = (f"error: {folder}: another run (pid {holder.pid}) is writing into this folder; wait for it to finish, "
            f"or choose another {option}")
    assert proc.stderr.strip().splitlines() == [said]
    assert "Traceback" not in proc.stdout
    assert _tree(folder) == before  # only the holder's lock file: nothing written


def test_a_second_generate_into_the_out_of_a_running_one_stops_at_once(tmp_path: Path) -> None:
    out = tmp_path / "data"
    with _held(out) as holder:
        _refused(["generate.py", "object=zbracket", "cycles=1", "drops=1", "scene.resolution=64", "previews=0",
                  "progress=false", f"out={out}", f"hydra.run.dir={tmp_path / 'h'}"], out, holder, "out=")
    assert sorted(p.name for p in out.iterdir()) == [LOCK_NAME]  # the killed holder's file: no dataset


def test_a_second_train_into_the_run_directory_of_a_running_one_stops_at_once(tiny_dataset: Path,
                                                                               tmp_path: Path) -> None:
    run = tmp_path / "run"
    args = ["train.py", "model=tiny", "object=zbracket", f"data.root={tiny_dataset}", "data.generate=null",
            "data.batch_size=4", "trainer.max_epochs=1", "+trainer.limit_train_batches=2",
            "+trainer.limit_val_batches=1", "trainer.enable_progress_bar=false", "test=false",
            "trainer.precision=32", f"hydra.run.dir={run}"]
    with _held(run) as holder:
        _refused(args, run, holder, "hydra.run.dir=")  # no .hydra/, no train.log, no checkpoints
    # the holder was killed: its lock file stays, its lock does not; the run takes it and leaves none behind
    proc = subprocess.run([sys.executable, *args], cwd=REPO_ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert (run / "checkpoints" / "last.ckpt").is_file() and (run / ".hydra" / "config.yaml").is_file()
    assert not (run / LOCK_NAME).exists()


def test_a_second_eval_into_the_out_of_a_running_one_stops_at_once(checkpoint: Path, tmp_path: Path) -> None:
    out = tmp_path / "eval"
    with _held(out) as holder:
        _refused(["eval.py", f"ckpt={checkpoint}", f"out={out}", "examples=0", f"hydra.run.dir={tmp_path / 'h'}"],
                 out, holder, "out=")


def test_the_lock_names_its_holder_and_a_crashed_holder_blocks_nobody(tmp_path: Path) -> None:
    from opnet.cli.locks import writer_lock
    from opnet.datasets.outputs import holder_pid

    folder = tmp_path / "out"
    code = ("import sys\nfrom opnet.cli.locks import writer_lock\nwith writer_lock(sys.argv[1], 'out='):\n"
            "    print('held', flush=True)\n    sys.stdin.read()\n")
    with _held(folder, code) as holder:
        assert holder_pid(folder) == holder.pid
        with pytest.raises(ValueError) as refused:
            with writer_lock(folder, "out="):
                pass
        assert str(refused.value) == (f"{folder}: another run (pid {holder.pid}) is writing into this folder; wait "
                                      "for it to finish, or choose another out=")
        os.kill(holder.pid, signal.SIGKILL)  # a crash: no clean-up
        holder.wait()
    assert (folder / LOCK_NAME).read_text().strip() == str(holder.pid)  # its file stays, naming a dead process
    assert holder_pid(folder) is None
    with writer_lock(folder, "out="):
        assert holder_pid(folder) == os.getpid()
    assert not (folder / LOCK_NAME).exists()


def test_a_folder_the_lock_made_is_removed_when_the_run_leaves_it_empty(tmp_path: Path) -> None:
    from opnet.cli.locks import writer_lock

    with pytest.raises(ValueError, match="refused checkpoint"):
        with writer_lock(tmp_path / "a" / "out", "out="):
            raise ValueError("refused checkpoint")
    assert not (tmp_path / "a" / "out").exists()
    with writer_lock(tmp_path / "b", "out="):
        (tmp_path / "b" / "x.json").write_text("{}")
    assert [p.name for p in (tmp_path / "b").iterdir()] == ["x.json"]
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match=rf"^{tmp_path / 'file'}: exists and is not a folder; choose another out="):
        with writer_lock(tmp_path / "file", "out="):
            pass


def test_a_folder_this_process_cannot_write_is_used_unlocked(tmp_path: Path) -> None:
    """A complete dataset on read-only storage is read without a single write: no lock file either."""
    from opnet.cli.locks import writer_lock

    folder = tmp_path / "read_only"
    folder.mkdir()
    (folder / "parameter.json").write_text("{}")
    folder.chmod(0o555)
    try:
        if os.access(folder, os.W_OK):
            pytest.skip("chmod does not stop this process (root)")
        with writer_lock(folder, "out="):
            assert [p.name for p in folder.iterdir()] == ["parameter.json"]
        assert [p.name for p in folder.iterdir()] == ["parameter.json"]
    finally:
        folder.chmod(0o755)
