"""A ``kill -9`` in the middle of writing a file, then the same command again: generation and prediction.

The killed process is the real command (``generate.py`` / ``predict.py`` with its arguments) whose
atomic writer (:mod:`opnet.fileio.atomic`) is cut in the middle of one chosen write: half the file's
bytes reach the disk, then the process kills itself with SIGKILL, before the file could be closed or
moved into place. Then: the half-written file is nowhere a reader looks (only its temporary file
holds it), the same command completes, and every file is byte-identical to an uninterrupted run's,
with nothing of the killed run left behind.
"""

from __future__ import annotations

import hashlib
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from opnet.cli import generate as generate_cli
from opnet.cli import predict as predict_cli
from opnet.cli.console import guarded
from opnet.datasets.outputs import LOCK_NAME
from opnet.paths import REPO_ROOT
from conftest import compose_cfg

#: runs ``python <argv[3:]>`` with the atomic writer's ``argv[1]``-th write (counted from 1) cut in the
#: middle by a SIGKILL; torch on ``argv[2]`` threads (0: torch not set up), as the test's own process
_CHILD = r"""
import os, runpy, signal, sys
from opnet.fileio import atomic

kill_at, threads, calls = int(sys.argv[1]), int(sys.argv[2]), 0


class Cut:
    def __init__(self, f):
        self.f = f

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()

    def write(self, data):
        self.f.write(data[: len(data) // 2])
        self.f.flush()
        os.kill(os.getpid(), signal.SIGKILL)


class Os:  # the os module as the atomic writer sees it: the kill_at-th file it opens is cut
    def __getattr__(self, name):
        return getattr(os, name)

    def fdopen(self, fd, *args, **kwargs):
        global calls
        calls += 1
        f = os.fdopen(fd, *args, **kwargs)
        return Cut(f) if calls == kill_at else f


if threads:
    import torch
    torch.set_num_threads(threads)
atomic.os = Os()
sys.argv = sys.argv[3:]
runpy.run_path(sys.argv[0], run_name="__main__")
"""


def _killed_in_a_write(script: str, overrides: list[str], kill_at: int, hydra_dir: Path, threads: int = 0) -> None:
    """Run ``script`` with ``overrides``, killed by SIGKILL in the middle of its ``kill_at``-th file write."""
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(kill_at), str(threads), str(REPO_ROOT / script),
                           *overrides, f"hydra.run.dir={hydra_dir}"],
                          cwd=REPO_ROOT, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == -signal.SIGKILL, f"not killed in a write (exit {proc.returncode}):\n{proc.stderr[-3000:]}"


def _tree(root: Path) -> dict[str, str]:
    """sha256 of every file under ``root`` (hidden and temporary files included), by relative path."""
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}  # fmt: skip


def _half_written(root: Path) -> Path:
    """The one file the killed write was making, by its temporary file: it holds part of the bytes,
    and the file itself was never put in place."""
    temporaries = [p for p in root.rglob(".*.tmp") if p.is_file()]
    assert len(temporaries) == 1, f"expected the killed write's temporary file, found {temporaries}"
    tmp = temporaries[0]
    target = tmp.with_name(tmp.name[1:-len(".tmp")].rpartition(".")[0])
    assert tmp.stat().st_size > 0, "the write was cut before any byte"
    assert not target.exists(), f"{target}: half-written file put in place"
    return target


def test_generation_killed_in_a_write_completes_to_the_same_bytes(tmp_path: Path) -> None:
    overrides = ["object=zbracket", "scene.resolution=64", "cycles=2", "drops=2", "seed=3", "workers=1", "previews=1",
                 "progress=false"]  # fmt: skip
    killed, straight = tmp_path / "killed", tmp_path / "straight"
    # 4 files at the root, then per cycle its preview and 3 scenes x 3 files: the 20th is in the second cycle
    _killed_in_a_write("generate.py", [*overrides, f"out={killed}"], 20, tmp_path / "hydra")
    target = _half_written(killed)
    assert "cycle_0001" in target.as_posix(), target

    resumed = generate_cli.run(compose_cfg("generate", [*overrides, f"out={killed}"]))
    assert (resumed.cycles_skipped, resumed.cycles_generated) == (1, 1)
    generate_cli.run(compose_cfg("generate", [*overrides, f"out={straight}"]))
    reference = _tree(straight)
    assert target.relative_to(killed).as_posix() in reference
    assert _tree(killed) == reference


@pytest.fixture(scope="module")
def depth_folder(tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two depth images of :func:`tiny_dataset` with its camera file."""
    folder = tmp_path_factory.mktemp("depth_in")
    shutil.copy(tiny_dataset / "parameter.json", folder)
    for n in (0, 1):
        (folder / "cycle_0000").mkdir(exist_ok=True)
        shutil.copy(tiny_dataset / "p_depth" / "cycle_0000" / f"00{n}_depth_uint16.png", folder / "cycle_0000")
    return folder


@pytest.fixture(scope="module")
def predicted(checkpoint: Path, depth_folder: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The files of an uninterrupted prediction of :func:`depth_folder`."""
    out = tmp_path_factory.mktemp("predicted") / "out"
    assert guarded(predict_cli.run, compose_cfg("predict", [f"ckpt={checkpoint}", f"input={depth_folder}",
                                                            f"out={out}"])) == 0  # fmt: skip
    return _tree(out)


@pytest.mark.parametrize("kill_at, image", [(1, "000"), (5, "001")], ids=["first write", "second image"])
def test_prediction_killed_in_a_write_completes_to_the_same_bytes(kill_at: int, image: str, checkpoint: Path,
                                                                   depth_folder: Path, predicted: dict[str, str],
                                                                   tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture) -> None:  # fmt: skip
    killed = tmp_path / "killed"
    overrides = [f"ckpt={checkpoint}", f"input={depth_folder}"]
    _killed_in_a_write("predict.py", [*overrides, f"out={killed}"], kill_at, tmp_path / "hydra",
                       torch.get_num_threads())  # fmt: skip
    target = _half_written(killed)
    assert f"cycle_0000/{image}_depth_uint16" in target.as_posix(), target

    assert target.relative_to(killed).as_posix() in predicted
    again = compose_cfg("predict", [*overrides, f"out={killed}"])
    if image != "000":  # the first image's files are complete: the same command keeps them, naming one
        before = {k: v for k, v in _tree(killed).items() if k != LOCK_NAME}  # the killed run's, taken and left
        capsys.readouterr()
        with pytest.raises(SystemExit) as refused:
            guarded(predict_cli.run, again)
        err = capsys.readouterr().err
        assert refused.value.code == 2 and err.count("\n") == 1 and "predictions exist already" in err, err
        assert _tree(killed) == before
        again = compose_cfg("predict", [*overrides, f"out={killed}", "overwrite=true"])
    assert guarded(predict_cli.run, again) == 0
    assert _tree(killed) == predicted
