"""Training, evaluation, prediction and export on a complete synthetic dataset need neither a
physics engine (MuJoCo, pybullet), the convex decomposition (CoACD) nor the renderer (pyrender):
a training box without them uses data generated elsewhere; making cycles without them is a
one-line error.

Each run blocks those packages (``sys.modules[name] = None`` makes ``import name`` fail) before
the script starts, as on a machine where they cannot be installed.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import compose_cfg
from opnet.cli.build import build_components, build_datamodule
from opnet.paths import REPO_ROOT

TINY = ["experiment=quickstart", "data.generate.cycles=4", "data.generate.drops=2", "data.generate.workers=1",
        "scene.resolution=128", "model=tiny", "trainer.max_epochs=1", "+trainer.limit_train_batches=2",
        "+trainer.limit_val_batches=1", "trainer.enable_progress_bar=false", "example_predictions=0"]  # fmt: skip

GENERATOR = ("pybullet", "mujoco", "coacd", "pyrender")
#: runs the entry scripts given as ``script args... --then script args...`` one after another in one
#: interpreter with the generator's packages blocked; stops at the first that exits non-zero
BLOCKED_RUN = """
import runpy, sys
for name in %r:
    sys.modules[name] = None
runs, run = [], []
for arg in sys.argv[1:]:
    if arg == "--then":
        runs.append(run); run = []
    else:
        run.append(arg)
try:
    for script, *args in [*runs, run]:
        sys.argv = [script, *args]
        try:
            runpy.run_path(script, run_name="__main__")
        except SystemExit as e:
            if e.code:
                raise
        print("ran", script, flush=True)
finally:
    loaded = [m for m in (*%r, "OpenGL") if sys.modules.get(m) is not None]
    print("generator modules loaded:", loaded or "none")
""" % (GENERATOR, GENERATOR)


def _run(ws: Path, *runs: tuple[str, list[str]]) -> subprocess.CompletedProcess:
    """The entry scripts ``runs`` ((script, args), ...) in one interpreter without the generator."""
    env = {**os.environ, "OPNET_ROOT": str(ws), "PYOPENGL_PLATFORM": "egl"}
    argv = [part for k, (script, args) in enumerate(runs) for part in ([] if k == 0 else ["--then"]) + [script, *args]]
    return subprocess.run([sys.executable, "-c", BLOCKED_RUN, *argv], cwd=REPO_ROOT, env=env, capture_output=True,
                          text=True, timeout=600)  # fmt: skip


def _train(ws: Path, overrides: list[str]) -> subprocess.CompletedProcess:
    return _run(ws, ("train.py", [*TINY, f"data.root={ws / 'data'}", *overrides]))


@pytest.mark.slow
def test_a_complete_dataset_trains_evaluates_predicts_and_exports_without_the_generator(tmp_path: Path) -> None:
    # the data made here as train.py makes it (its datamodule's prepare_data), without a training
    cfg = compose_cfg("train", [*TINY, f"data.root={tmp_path / 'data'}"])
    build_datamodule(cfg, build_components(cfg).obj, train=True).prepare_data()

    used = _train(tmp_path, [f"hydra.run.dir={tmp_path / 'run_used'}"])
    assert used.returncode == 0, used.stderr[-2000:]
    assert "generator modules loaded: none" in used.stdout
    assert (tmp_path / "run_used" / "test" / "summary.json").is_file()

    ckpt = tmp_path / "run_used" / "checkpoints" / "last.ckpt"
    png = sorted((tmp_path / "data" / "p_depth").rglob("*.png"))[-1]
    runs = {"eval.py": ([f"ckpt={ckpt}", f"out={tmp_path / 'eval'}"], tmp_path / "eval" / "summary.json"),
            "predict.py": ([f"ckpt={ckpt}", f"input={png}", f"out={tmp_path / 'pred'}"], tmp_path / "pred" / f"{png.stem}.json"),
            "export.py": ([f"ckpt={ckpt}", f"out={tmp_path / 'model.onnx'}"], tmp_path / "model.onnx")}  # fmt: skip
    done = _run(tmp_path, *[(script, [*args, f"hydra.run.dir={tmp_path / ('run_' + script)}"])
                            for script, (args, _) in runs.items()])  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert "generator modules loaded: none" in done.stdout
    for script, (_, made_file) in runs.items():
        assert f"ran {script}" in done.stdout and made_file.is_file(), script

    # one more cycle to make: the generator is needed, and its absence is one line naming it and the folder
    more = _train(tmp_path, ["data.generate.cycles=5", f"hydra.run.dir={tmp_path / 'run_more'}"])
    assert more.returncode != 0
    assert "Traceback" not in more.stderr, more.stderr[-2000:]
    error = [line for line in more.stderr.splitlines() if "mujoco" in line]
    assert error and str(tmp_path / "data") in error[0] and "not installed" in error[0], more.stderr[-2000:]
