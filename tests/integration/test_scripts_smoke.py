"""Every script that makes a published figure or table still starts: ``scripts/bench/`` and ``scripts/experiments/``.

A change to the package that breaks one of them fails here, not at the next full run. For every
script found (a new one is covered without a change here): ``--help`` runs and exits 0, and every
name it imports from ``opnet`` (at its top or inside a function, which ``--help`` never reaches)
exists. The scripts with a cheap mode also run for real in it (:data:`RUNS`: the tiny network, one
repeat, a pile of two drops), the deployment-speed benchmark among them with its ONNX rows.

Cost: the scripts run one after another in one child process (the package imported once), about
30 s on two cores; a real experiment never runs here.
"""

from __future__ import annotations

import ast
import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from opnet.paths import REPO_ROOT

SCRIPTS = sorted(p.relative_to(REPO_ROOT).as_posix() for folder in ("scripts/bench", "scripts/experiments")
                 for p in (REPO_ROOT / folder).rglob("*.py"))  # fmt: skip

#: the real runs in each script's smallest configuration, in order ({tmp}: this test's folder)
RUNS: list[tuple[str, list[str]]] = [
    ("scripts/bench/bench_infer.py", ["--model", "tiny", "--parameterizations", "vanilla", "--batches", "1",
                                      "--repeats", "1", "--threads", "1", "--device", "cpu",
                                      "--out", "{tmp}/infer.csv"]),
    ("scripts/bench/bench_decode.py", ["--repeats", "1"]),
    ("scripts/bench/bench_evaluate.py", ["--scenes", "2", "--instances", "5", "--hypotheses", "10", "--check", "1"]),
    ("scripts/bench/model_stats.py", ["--presets", "tiny", "--grids", "16", "--no-timing"]),
    ("scripts/bench/bench_cache_fingerprint.py", ["--scenes", "10", "--drops", "2", "--repeat", "1"]),
    ("scripts/bench/bench_generate.py", ["--cycles", "1", "--drops", "2", "--workers", "1", "--resolution", "64",
                                         "--keep", "{tmp}/piles"]),
    ("scripts/bench/pile_stats.py", ["{tmp}/piles/bracket_w1"]),
    ("scripts/experiments/flat_parts/spin_ceiling.py", ["--object", "bracket", "--root", "{tmp}/piles/bracket_w1",
                                                        "--cutoffs", "45", "--draws", "2"]),
    ("scripts/experiments/flat_parts/spin_observability.py", ["--object", "bracket", "--tilts", "0", "--spins", "36",
                                                              "--out", "{tmp}/observability.md"]),
    ("scripts/experiments/table1/table1.py", ["--dry-run", "--objects", "bracket", "--seeds", "0",
                                              "--runs-dir", "{tmp}/table1_runs", "--out", "{tmp}/table1"]),
]

#: runs each job [script, argv] of the JSON list argv[1] as ``python <script> <argv>`` would (its folder
#: first on sys.path, run as __main__), one after another in this process; writes per job its exit
#: code (0 when it returns), the head and tail of its output and of any traceback to the JSON file argv[2]
_RUNNER = r"""
import contextlib, io, json, runpy, sys, traceback
from pathlib import Path
jobs_file, results_file = sys.argv[1:3]
jobs, results = json.loads(Path(jobs_file).read_text()), []
for script, argv in jobs:
    before, path = set(sys.modules), list(sys.path)
    sys.argv, sys.path[0] = [script, *argv], str(Path(script).resolve().parent)
    out, code, trace = io.StringIO(), 0, ""
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
            runpy.run_path(script, run_name="__main__")
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else (0 if e.code is None else f"exit: {e.code}")
    except BaseException:
        code, trace = "traceback", traceback.format_exc()[-3000:]
    for name in set(sys.modules) - before:  # a script's own helpers: another folder may have one of that name
        if "/scripts/" in str(getattr(sys.modules[name], "__file__", "") or ""):
            del sys.modules[name]
    sys.path[:] = path
    results.append({"script": script, "argv": argv, "code": code, "head": out.getvalue()[:300], "output": out.getvalue()[-3000:], "trace": trace})
Path(results_file).write_text(json.dumps(results))
"""


@pytest.fixture(scope="module")
def ran(tmp_path_factory: pytest.TempPathFactory) -> dict[tuple[str, str], dict]:
    """Each job's result, by (script, "help" or "run"): every script's ``--help``, then :data:`RUNS`."""
    tmp = tmp_path_factory.mktemp("scripts_smoke")
    jobs = [[s, ["--help"]] for s in SCRIPTS] + [[s, [a.format(tmp=tmp) for a in argv]] for s, argv in RUNS]
    (tmp / "jobs.json").write_text(json.dumps(jobs))
    proc = subprocess.run([sys.executable, "-c", _RUNNER, str(tmp / "jobs.json"), str(tmp / "results.json")],
                          cwd=REPO_ROOT, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, f"the runner itself failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    results = json.loads((tmp / "results.json").read_text())
    return {(r["script"], "help" if r["argv"] == ["--help"] else "run"): r for r in results}


def _said(result: dict) -> str:
    return f"{result['script']} {' '.join(result['argv'])}: exit {result['code']}\n{result['output']}\n{result['trace']}"


def test_the_scripts_are_found() -> None:
    assert "scripts/bench/bench_infer.py" in SCRIPTS and any(s.startswith("scripts/experiments/") for s in SCRIPTS)
    assert {s for s, _ in RUNS} <= set(SCRIPTS), "a real run names a script that is gone"


@pytest.mark.parametrize("script", SCRIPTS)
def test_the_script_prints_its_help(script: str, ran: dict) -> None:
    result = ran[(script, "help")]
    assert result["code"] == 0 and result["head"].startswith("usage:"), _said(result)


@pytest.mark.parametrize("script", SCRIPTS)
def test_every_name_the_script_imports_from_the_package_exists(script: str) -> None:
    missing = []
    for node in ast.walk(ast.parse((REPO_ROOT / script).read_text(), script)):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "opnet":
            module = importlib.import_module(node.module)
            for alias in node.names:
                if alias.name != "*" and not hasattr(module, alias.name):
                    try:  # a submodule imported by name
                        importlib.import_module(f"{node.module}.{alias.name}")
                    except ModuleNotFoundError:
                        missing.append(f"line {node.lineno}: from {node.module} import {alias.name}")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "opnet":
                    importlib.import_module(alias.name)
    assert not missing, f"{script} imports names the package no longer has:\n" + "\n".join(missing)


@pytest.mark.parametrize("script", [s for s, _ in RUNS], ids=[Path(s).stem for s, _ in RUNS])
def test_the_script_runs_in_its_smallest_configuration(script: str, ran: dict) -> None:
    result = ran[(script, "run")]
    assert result["code"] == 0, _said(result)


def test_the_deployment_speed_table_has_its_onnx_rows(ran: dict) -> None:
    pytest.importorskip("onnxruntime")
    result = ran[("scripts/bench/bench_infer.py", "run")]
    assert "forward ONNX Runtime fp32" in result["output"], _said(result)
