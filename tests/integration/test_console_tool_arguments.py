"""The console tools' arguments go through one validation path (:mod:`opnet.arguments`,
:mod:`opnet.cli.tools`): a bad option, a missing input, an output that cannot be written or would replace a
file without --force is one line ``error: ...`` naming it, exit status 2, nothing written. A variant string
takes only the settings its parameterization documents: ``_target_`` (which instantiated any callable) and
interpolations are refused. Each case failed before its fix (a traceback, a silent run, a replaced file)."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
import torch

from opnet.tools import compare_runs, diagnose_sources, oracle, record_trained_clip, tune_decoding


def _status(main: Callable[[list[str]], object], argv: list[str]) -> int:
    try:
        return int(main(argv) or 0)
    except SystemExit as e:  # argparse's exit
        return int(e.code or 0)


def _snapshot(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _refused(capsys: pytest.CaptureFixture[str], *named: str) -> str:
    captured = capsys.readouterr()
    lines = [line for line in captured.err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), captured.err[-2000:]
    assert "Traceback" not in captured.err and all(n in lines[0] for n in named), lines[0]
    return lines[0]


@pytest.mark.parametrize(("variant", "named"), [
    ("vanilla:_target_=builtins.dict", "_target_"),
    ("vanilla:_convert_=all", "_convert_"),
    ("vanilla:bogus_key=1", "bogus_key"),
    ("vanilla:threshold=7", "threshold=7"),
    ("vanilla:grid=${oc.env:HOME}", "grid"),
    ("ap:points={_target_: os.system}", "points"),
    ("vanilla:threshold", "threshold"),
    ("nosuch", "nosuch"),
])  # fmt: skip
def test_oracle_variants_take_only_documented_settings(tiny_dataset: Path, tmp_path: Path, capsys, variant: str,
                                                       named: str) -> None:  # fmt: skip
    out = tmp_path / "ceiling"
    assert _status(oracle.main, ["--data", str(tiny_dataset), "--out", str(out), "--variant", variant]) == 2
    _refused(capsys, "--variant", named)
    assert not out.exists()


@pytest.mark.parametrize(("args", "named"), [
    (["--max-scenes", "0"], "--max-scenes"),
    (["--max-scenes", "-1"], "--max-scenes"),
    (["--min-objects", "-2"], "--min-objects"),
    (["--data", "<gone>"], "gone"),
    (["--out", "<file>"], "a_file"),
])  # fmt: skip
def test_oracle_arguments_are_checked_before_the_work(tiny_dataset: Path, tmp_path: Path, capsys, args: list[str],
                                                      named: str) -> None:  # fmt: skip
    (tmp_path / "a_file").write_text("kept\n")
    given = {"--data": str(tiny_dataset), "--out": str(tmp_path / "ceiling"), "--max-scenes": "2"}
    for key, value in zip(args[::2], args[1::2], strict=True):
        given[key] = value.replace("<gone>", str(tmp_path / "gone")).replace("<file>", str(tmp_path / "a_file"))
    before = _snapshot(tmp_path)
    assert _status(oracle.main, [x for kv in given.items() for x in kv]) == 2
    _refused(capsys, named)
    assert _snapshot(tmp_path) == before and not (tmp_path / "ceiling").exists()


def test_oracle_runs_with_a_documented_setting(tiny_dataset: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "ceiling"
    assert _status(oracle.main, ["--data", str(tiny_dataset), "--out", str(out), "--max-scenes", "2",
                                 "--variant", "vanilla:threshold=0.2"]) == 0
    assert (out / "ceiling.csv").is_file() and "vanilla:threshold=0.2" in (out / "ceiling.md").read_text()


class _Code:
    def __reduce__(self) -> tuple[Callable[..., object], tuple[()]]:
        import os

        return os.getpid, ()


def test_diagnose_sources_refuses_a_pickle_and_an_out_onto_a_file(checkpoint: Path, tmp_path: Path, capsys) -> None:
    code = tmp_path / "code.ckpt"
    torch.save({"state_dict": _Code()}, code)
    (tmp_path / "a_file").write_text("kept\n")
    before = _snapshot(tmp_path)
    assert _status(diagnose_sources.main, ["--ckpt", str(code), "--out", str(tmp_path / "diag")]) == 2
    _refused(capsys, str(code), "refused")
    assert _status(diagnose_sources.main, ["--ckpt", str(checkpoint), "--out", str(tmp_path / "a_file")]) == 2
    _refused(capsys, str(tmp_path / "a_file"), "not a folder")
    assert _status(diagnose_sources.main, ["--ckpt", str(tmp_path / "gone.ckpt")]) == 2
    _refused(capsys, "gone.ckpt")
    assert _snapshot(tmp_path) == before


@pytest.mark.parametrize("rounds", ["0", "-3", "x"])
def test_tune_decoding_refuses_rounds_that_tune_nothing(checkpoint: Path, tmp_path: Path, capsys, rounds: str) -> None:
    """``--rounds 0`` tuned nothing, printed "best: AP 1.0000", wrote the sweep and exited 0."""
    assert _status(tune_decoding.main, ["--ckpt", str(checkpoint), "--rounds", rounds,
                                        "--out", str(tmp_path / "tune")]) == 2
    _refused(capsys, "--rounds")
    assert not (tmp_path / "tune").exists()


def test_record_trained_clip_keeps_an_existing_file_without_force(checkpoint: Path, tmp_path: Path, capsys) -> None:
    target = tmp_path / "kept.ckpt"
    target.write_text("someone's file\n")
    assert _status(record_trained_clip.main, [str(checkpoint), "--write", str(target)]) == 2
    _refused(capsys, str(target), "--force")
    assert target.read_text() == "someone's file\n"
    assert _status(tune_decoding.main, ["--ckpt", str(checkpoint), "--write", str(target), "--rounds", "1",
                                        "--out", str(tmp_path / "tune")]) == 2
    _refused(capsys, str(target), "--force")
    assert target.read_text() == "someone's file\n" and not (tmp_path / "tune").exists()
    copy = tmp_path / "copy.ckpt"
    shutil.copy(checkpoint, copy)
    assert _status(record_trained_clip.main, [str(checkpoint), "--write", str(target), "--force"]) == 0
    assert target.read_bytes()[:2] == b"PK"


def test_compare_runs_refuses_an_out_onto_a_file(tmp_path: Path, capsys) -> None:
    arm = tmp_path / "multirun" / "0"
    (arm / ".hydra").mkdir(parents=True)
    (tmp_path / "a_file").write_text("kept\n")
    assert _status(compare_runs.main, [str(tmp_path / "multirun"), "--out", str(tmp_path / "a_file")]) == 2
    _refused(capsys, str(tmp_path / "a_file"))
    assert (tmp_path / "a_file").read_text() == "kept\n"


@pytest.mark.parametrize("main", [oracle.main, diagnose_sources.main, tune_decoding.main, record_trained_clip.main,
                                  compare_runs.main])
def test_a_usage_error_is_one_line(main: Callable[[list[str]], object], capsys) -> None:
    assert _status(main, ["--no-such-option"]) == 2
    _refused(capsys)
