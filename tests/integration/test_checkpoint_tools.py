"""The checkpoint tools users are told to run (``opnet-tune-decoding``,
``opnet-record-trained-clip``, export.py) handle errors as the entry points do: a refused
checkpoint (not a checkpoint, a pickle holding code), a missing dataset, a folder or a read-only
folder as the target give one line ``error: <file>: <problem>`` and exit status 2, leave no
temporary file and the files there as they were (they used to give tracebacks, and a folder as
the target left the whole checkpoint behind as ``.<name>.tmp``)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import torch

from opnet.cli.build import load_checkpoint, read_checkpoint
from opnet.paths import REPO_ROOT
from opnet.run_settings import CHECKPOINT_KEY
from opnet.tools import record_trained_clip as record
from opnet.tools import tune_decoding as tune


class _Code:
    """Pickled, it would call a function on load."""

    def __reduce__(self) -> tuple[Callable[..., object], tuple[()]]:
        return os.getpid, ()


@pytest.fixture
def files(checkpoint: Path, tmp_path: Path) -> Iterator[dict[str, Path | None]]:
    """A copy of the tiny model, a file that is no checkpoint, a pickle holding code, the model with its
    dataset gone, a folder, and a read-only folder holding a checkpoint (None where chmod cannot stop
    this process: root)."""
    good = tmp_path / "model.ckpt"
    shutil.copy(checkpoint, good)
    (tmp_path / "notes.ckpt").write_text("not a checkpoint\n")
    torch.save({"state_dict": _Code()}, tmp_path / "code.ckpt")
    ckpt = read_checkpoint(checkpoint)
    del ckpt[CHECKPOINT_KEY]  # a checkpoint of before the settings entry and the recorded planes
    ckpt["hyper_parameters"]["config"].pop("trained_clip", None)  # record_trained_clip has to read the dataset
    ckpt["hyper_parameters"]["config"]["data"]["root"] = str(tmp_path / "gone")
    torch.save(ckpt, tmp_path / "no_data.ckpt")
    (tmp_path / "folder").mkdir()
    read_only = tmp_path / "read_only"
    read_only.mkdir()
    shutil.copy(checkpoint, read_only / "model.ckpt")
    read_only.chmod(0o555)
    yield {"good": good, "notes": tmp_path / "notes.ckpt", "code": tmp_path / "code.ckpt",
           "no_data": tmp_path / "no_data.ckpt", "folder": tmp_path / "folder",
           "read_only": None if os.access(read_only, os.W_OK) else read_only}
    read_only.chmod(0o755)


def _snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _one_error_line(err: str, file: Path, problem: str) -> None:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"error: {file}: "), err[-2000:]
    assert problem in lines[0] and "Traceback" not in err


CASES = {  # case -> (the file the message names, its problem)
    "not a checkpoint": ("notes", "not a PyTorch checkpoint file"),
    "code in the pickle": ("code", "refused: the checkpoint holds objects other than tensors"),
    "missing dataset": ("no_data", "not found"),
}


def _named(files: dict[str, Path], case: str, tmp_path: Path) -> Path:
    return tmp_path / "gone" if case == "missing dataset" else files[CASES[case][0]]


@pytest.mark.parametrize("case", [*CASES, "folder as target", "read-only target"])
def test_tune_decoding_errors_are_one_line_and_leave_everything_as_it_was(case: str, files: dict[str, Path],
                                                                         tmp_path: Path, capsys) -> None:
    if case == "read-only target" and files["read_only"] is None:
        pytest.skip("chmod does not stop this process (root)")
    ckpt, write, named, problem = files["good"], tmp_path / "tuned.ckpt", None, ""
    if case in CASES:
        ckpt, named, problem = files[CASES[case][0]], _named(files, case, tmp_path), CASES[case][1]
    elif case == "folder as target":
        write, named, problem = files["folder"], files["folder"], "is not a regular file"
    else:
        write = named = files["read_only"] / "model.ckpt"
        problem = "is not writable"
    before = _snapshot(tmp_path)
    status = tune.main(["--ckpt", str(ckpt), "--write", str(write), "--out", str(tmp_path / "tables"),
                        "--stride", "4", "--rounds", "1"])
    assert status == 2
    _one_error_line(capsys.readouterr().err, named, problem)
    assert _snapshot(tmp_path) == before  # no table, no copy, no temporary file, the checkpoints unchanged


@pytest.mark.parametrize("case", [*CASES, "folder as target", "read-only target"])
def test_record_trained_clip_errors_are_one_line_and_leave_everything_as_it_was(case: str, files: dict[str, Path],
                                                                               tmp_path: Path, capsys) -> None:
    if case == "read-only target" and files["read_only"] is None:
        pytest.skip("chmod does not stop this process (root)")
    if case in CASES:
        args, named, problem = [files[CASES[case][0]], "--write", tmp_path / "c.ckpt"], _named(files, case, tmp_path), \
            CASES[case][1]
    elif case == "folder as target":
        args, named, problem = [files["good"], "--write", files["folder"]], files["folder"], "is not a regular file"
    else:
        named = files["read_only"] / "model.ckpt"
        args, problem = [named, "--in-place"], "is not writable"
    before = _snapshot(tmp_path)
    assert record.main([str(a) for a in args]) == 2
    _one_error_line(capsys.readouterr().err, named, problem)
    assert _snapshot(tmp_path) == before


def test_the_tools_exit_2_as_processes(files: dict[str, Path], tmp_path: Path) -> None:
    before = _snapshot(tmp_path)
    for script, args, named in [
        ("opnet.tools.tune_decoding", ["--ckpt", files["code"]], files["code"]),
        ("opnet.tools.record_trained_clip", [files["good"], "--write", files["folder"]], files["folder"]),
    ]:
        proc = subprocess.run([sys.executable, "-m", script, *map(str, args)], capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 2, proc.stderr[-2000:]
        _one_error_line(proc.stderr, named, "")
    assert _snapshot(tmp_path) == before


def test_checkpoint_writes_that_fail_name_the_target_and_leave_no_temporary(files: dict[str, Path],
                                                                            tmp_path: Path) -> None:
    """Past the checks before the work (a folder made read-only meanwhile, a full disk): the writes
    themselves."""
    settings = {**tune.current_settings(load_checkpoint(files["good"])[0].parameterization), "min_visibility": 0.3}
    before = _snapshot(tmp_path)
    with pytest.raises(ValueError, match=rf"^{files['folder']}: is a folder; give the name of a file to write"):
        tune.write_tuned_checkpoint(files["good"], files["folder"], settings)
    with pytest.raises(ValueError, match=rf"^{files['folder']}: is a folder"):
        record.record(files["good"], files["folder"])
    if files["read_only"] is not None:
        target = files["read_only"] / "model.ckpt"
        with pytest.raises(ValueError, match=rf"^{target}: cannot be written \(Permission denied\)"):
            tune.write_tuned_checkpoint(files["good"], target, settings)
        with pytest.raises(ValueError, match=rf"^{target}: cannot be written \(Permission denied\)"):
            record.record(target, target)
    assert _snapshot(tmp_path) == before


def test_a_full_disk_while_saving_a_checkpoint_names_it_and_leaves_no_temporary(files: dict[str, Path], tmp_path: Path,
                                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    from conftest import FullDisk

    import opnet.fileio.atomic as atomic
    from opnet.fileio.atomic import DiskFullError

    settings = tune.current_settings(load_checkpoint(files["good"])[0].parameterization)
    before = _snapshot(tmp_path)
    monkeypatch.setattr(atomic.os, "fdopen", FullDisk)
    with pytest.raises(DiskFullError, match=rf"^{tmp_path / 'tuned.ckpt'}: No space left on device"):
        tune.write_tuned_checkpoint(files["good"], tmp_path / "tuned.ckpt", settings)
    assert _snapshot(tmp_path) == before


def test_export_errors_name_the_target_and_leave_no_temporary(files: dict[str, Path], tmp_path: Path) -> None:
    from opnet.cli.build import load_checkpoint
    from opnet.deploy.export import export_onnx

    system, cfg = load_checkpoint(files["good"])
    before = _snapshot(tmp_path)
    with pytest.raises(ValueError, match=rf"^{files['folder']}: is a folder; give the name of a file to write"):
        export_onnx(system, cfg, files["good"], files["folder"])
    with pytest.raises(ValueError, match=rf"^{files['notes'] / 'm.onnx'}: {files['notes']} is a file, not a folder"):
        export_onnx(system, cfg, files["good"], files["notes"] / "m.onnx")
    runs = [(files["notes"], tmp_path / "a.onnx", files["notes"], "not a PyTorch checkpoint file")]
    if files["read_only"] is not None:
        target = files["read_only"] / "m.onnx"
        with pytest.raises(ValueError, match=rf"^{target}: cannot be written \(Permission denied"):
            export_onnx(system, cfg, files["good"], target)
        runs.append((files["good"], target, target, "is not writable"))
    for ckpt, out, named, problem in runs:
        proc = subprocess.run([sys.executable, "export.py", f"ckpt={ckpt}", f"out={out}",
                               f"hydra.run.dir={tmp_path / 'hydra'}"], cwd=REPO_ROOT, capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 2, proc.stderr[-2000:]
        _one_error_line(proc.stderr, named, problem)
    shutil.rmtree(tmp_path / "hydra")  # export.py's own log
    assert _snapshot(tmp_path) == before
