"""The product speaks of itself only: no tracked file of the code, configs, docs, tests, scripts,
results or models cites a number of a tracker the user has no access to ("issue" followed by a
number). Each sentence says what it means instead."""

from __future__ import annotations

import re
import shutil
import subprocess

import pytest

from opnet.paths import REPO_ROOT

CHECKED = ["src", "conf", "docs", "tests", "scripts", "results", "models", "README.md"]

# Built from pieces so that this file does not match its own pattern.
_WORD = "iss" + "ue"
TRACKER_REF = re.compile(r"\b" + _WORD + r"s?\s*#?\s*[0-9]", re.IGNORECASE)


def _tracked_files() -> list[str]:
    if shutil.which("git") is None or not (REPO_ROOT / ".git").exists():
        pytest.skip("not a git checkout: the tracked files cannot be listed")
    out = subprocess.run(["git", "ls-files", "-z", "--", *CHECKED], cwd=REPO_ROOT, check=True,
                         capture_output=True).stdout
    return [name for name in out.decode().split("\0") if name and ".egg-info/" not in name]


def test_no_tracker_numbers_in_tracked_files() -> None:
    hits = []
    for name in _tracked_files():
        path = REPO_ROOT / name
        if not path.is_file():
            continue  # deleted in the working tree, not yet committed
        data = path.read_bytes()
        if b"\0" in data[:8192]:
            continue  # binary (pictures, arrays)
        text = data.decode("utf-8", errors="replace")
        for lineno, line in enumerate(text.splitlines(), 1):
            if TRACKER_REF.search(line):
                hits.append(f"{name}:{lineno}: {line.strip()[:120]}")
    assert not hits, "tracker numbers in the product (say what is meant instead):\n" + "\n".join(hits)
