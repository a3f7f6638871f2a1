"""predict.py answers a bad setting, from its command line or from the checkpoint, with the schema's one
line and exit status 2, and writes nothing (docs/reliability.md#one-schema-for-every-source)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from opnet.paths import REPO_ROOT

CKPT = REPO_ROOT / "models" / "dense_bunny.ckpt"


@pytest.mark.parametrize(("case", "line"), [
    ("+decoding.averaging.eps=true", "error: decoding.averaging.eps=True: expected a fraction of delta in (0, 100]"),
    ("grid true in the checkpoint",
     "error: {ckpt}: the checkpoint's config parameterization.grid=True: expected a whole number in [1, 1024]"),
])  # fmt: skip
def test_predict_refuses_a_bad_setting_in_one_line(case: str, line: str, tmp_path: Path) -> None:
    ckpt, extra = CKPT, [case]
    if case.startswith("grid"):
        saved = torch.load(CKPT, map_location="cpu", weights_only=True)
        saved["hyper_parameters"]["config"]["parameterization"]["grid"] = True  # was read as a 1 x 1 grid
        ckpt, extra = tmp_path / "edited.ckpt", []
        torch.save(saved, ckpt)
    np.save(tmp_path / "frame.npy", np.full((64, 64), 1.2, np.float32))
    out = tmp_path / "poses"
    proc = subprocess.run(
        [sys.executable, str(REPO_ROOT / "predict.py"), f"ckpt={ckpt}", f"input={tmp_path / 'frame.npy'}", f"out={out}",
         "camera.fx=60", "camera.fy=60", "camera.cx=32", "camera.cy=32", *extra, f"hydra.run.dir={tmp_path / 'run'}"],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    lines = [text for text in proc.stderr.splitlines() if text.strip()]
    assert proc.returncode == 2 and lines == [line.format(ckpt=ckpt)], proc.stderr[-2000:]
    assert not out.exists()
