"""Training on a complete synthetic dataset needs neither pybullet nor pyrender (a training box
without them uses data generated elsewhere); making cycles without them is a one-line error.

Each run blocks both packages (``sys.modules[name] = None`` makes ``import name`` fail) before
train.py starts, as on a Python version without pybullet wheels.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from opnet.paths import REPO_ROOT

TINY = ["experiment=quickstart", "data.generate.cycles=4", "data.generate.drops=2", "data.generate.workers=1",
        "data.generate.scene.resolution=128", "model=tiny", "trainer.max_epochs=1", "+trainer.limit_train_batches=2",
        "+trainer.limit_val_batches=1", "trainer.enable_progress_bar=false", "example_predictions=0"]  # fmt: skip

BLOCKED_RUN = """
import runpy, sys
for name in ("pybullet", "pyrender"):
    sys.modules[name] = None
sys.argv = ["train.py", *sys.argv[1:]]
try:
    runpy.run_path("train.py", run_name="__main__")
finally:
    loaded = [m for m in ("pybullet", "pyrender", "OpenGL") if sys.modules.get(m) is not None]
    print("generator modules loaded:", loaded or "none")
"""


def _train(ws: Path, overrides: list[str], blocked: bool) -> subprocess.CompletedProcess:
    env = {**os.environ, "OPNET_ROOT": str(ws), "PYOPENGL_PLATFORM": "egl"}
    head = [sys.executable, "-c", BLOCKED_RUN] if blocked else [sys.executable, "train.py"]
    return subprocess.run([*head, *TINY, f"data.root={ws / 'data'}", *overrides], cwd=REPO_ROOT, env=env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip


@pytest.mark.slow
def test_a_complete_dataset_trains_without_pybullet_and_pyrender(tmp_path: Path) -> None:
    made = _train(tmp_path, [f"hydra.run.dir={tmp_path / 'run_made'}"], blocked=False)
    assert made.returncode == 0, made.stderr[-2000:]

    used = _train(tmp_path, [f"hydra.run.dir={tmp_path / 'run_used'}"], blocked=True)
    assert used.returncode == 0, used.stderr[-2000:]
    assert "generator modules loaded: none" in used.stdout
    assert (tmp_path / "run_used" / "test" / "summary.json").is_file()

    # one more cycle to make: the generator is needed, and its absence is one line naming it and the folder
    more = _train(tmp_path, ["data.generate.cycles=5", f"hydra.run.dir={tmp_path / 'run_more'}"], blocked=True)
    assert more.returncode != 0
    assert "Traceback" not in more.stderr, more.stderr[-2000:]
    error = [line for line in more.stderr.splitlines() if "pybullet" in line]
    assert error and str(tmp_path / "data") in error[0] and "not installed" in error[0], more.stderr[-2000:]
