"""What the study and benchmark scripts of ``scripts/`` share: run a command of the framework with its
console in a log file."""

from __future__ import annotations

import subprocess
from pathlib import Path

from opnet.paths import REPO_ROOT


def run_logged(cmd: list[str], log: Path, cwd: Path = REPO_ROOT) -> None:
    """Run ``cmd`` (a command of the framework: ``[python, script, overrides...]``) in ``cwd`` with its
    console in ``log``, echoing it without the interpreter; a failure exits naming the log."""
    log.parent.mkdir(parents=True, exist_ok=True)
    print(f"$ {' '.join(cmd[1:])}", flush=True)
    with log.open("w") as f:
        code = subprocess.run(cmd, cwd=cwd, stdout=f, stderr=subprocess.STDOUT, check=False).returncode
    if code:
        raise SystemExit(f"error: exit {code}; see {log}")


__all__ = ["run_logged"]
