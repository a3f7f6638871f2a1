"""opnet never goes on the network: albumentations' update check (a PyPI request at import) is off
in every process that imports opnet. Each run refuses and records every name lookup and socket
connection before anything is imported."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from opnet.datasets.png import encode_depth, write_png
from opnet.paths import REPO_ROOT

GUARDED = """
import socket, sys
attempts = []

def refuse(what):
    def call(*args, **kwargs):
        attempts.append(f"{what} {args[1] if what.startswith('connect') else args[0]!r}")
        raise OSError(f"no network in this test ({what})")
    return call

socket.getaddrinfo = refuse("getaddrinfo")
socket.create_connection = refuse("create_connection")
socket.socket.connect = refuse("connect")
socket.socket.connect_ex = refuse("connect_ex")
code, sys.argv = sys.argv[1], sys.argv[2:] or ["-c"]  # the code, then the command line it runs as
try:
    exec(code)
finally:
    print("network attempts:", attempts or "none", flush=True)
"""

#: the modules of the three commands and the augmentation pipeline of training, used on an image
IMPORT_ALL = """
import numpy as np
import opnet.cli.eval, opnet.cli.predict, opnet.cli.train
from opnet.data.augment import DepthAugmenter
out = DepthAugmenter(p_elastic=1.0, p_blur=1.0, p_noise=1.0)(np.full((64, 64), 0.5, np.float32),
                                                             np.random.default_rng(0))
print("augmented", out.shape)
"""


def _guarded(code: str, *args: str) -> subprocess.CompletedProcess:
    env = {k: v for k, v in os.environ.items() if k != "NO_ALBUMENTATIONS_UPDATE"}  # as a user has it
    return subprocess.run([sys.executable, "-c", GUARDED, code, *args], cwd=REPO_ROOT, capture_output=True,
                          text=True, timeout=300, env={**env, "PYOPENGL_PLATFORM": "egl"})


def test_the_guard_sees_albumentations_phone_home_on_its_own() -> None:
    """Without opnet, albumentations asks PyPI at import: the guard of the other tests catches it."""
    proc = _guarded("import albumentations")
    assert proc.returncode == 0, proc.stderr
    assert "network attempts: none" not in proc.stdout and "pypi.org" in proc.stdout, proc.stdout


@pytest.mark.slow
def test_importing_opnet_and_augmenting_stay_offline() -> None:
    proc = _guarded(IMPORT_ALL)
    assert proc.returncode == 0, proc.stderr
    assert "augmented (64, 64)" in proc.stdout
    assert "network attempts: none" in proc.stdout, proc.stdout


def test_predict_py_stays_offline(checkpoint: Path, tmp_path: Path) -> None:
    depth = np.full((120, 150), 1.2, np.float32)
    depth[40:70, 50:90] = 1.05
    write_png(tmp_path / "frame.png", encode_depth(depth, 0.5, 1.5))
    camera = ["camera.fx=180", "camera.fy=181", "camera.cx=70.5", "camera.cy=60.25", "camera.clip_start=0.5",
              "camera.clip_end=1.5"]
    proc = _guarded("import runpy; runpy.run_path('predict.py', run_name='__main__')", "predict.py",
                    f"ckpt={checkpoint}", f"input={tmp_path / 'frame.png'}", f"out={tmp_path / 'out'}",
                    f"hydra.run.dir={tmp_path / 'hydra'}", *camera)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "1 of 1 predictions written" in proc.stdout and (tmp_path / "out" / "frame.json").is_file()
    assert "network attempts: none" in proc.stdout, proc.stdout
