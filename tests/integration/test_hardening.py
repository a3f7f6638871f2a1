"""Regression tests of the hardening work: each case failed (hung, went silent, printed a raw
traceback or rewrote files) before its fix."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from conftest import small_builtin_dataset, tiny_train_cfg

from opnet.cli import train as train_cli
from opnet.objects import builtin_object, object_from_config
from opnet.paths import REPO_ROOT
from opnet.synthesis import SceneConfig, generate_dataset
from opnet.synthesis.collision import build_collision_model, coacd_cached, vhacd_cached


def _copy(dataset: Path, dest: Path) -> Path:
    shutil.copytree(dataset, dest, ignore=shutil.ignore_patterns("cache_*"))
    return dest


def _scale_rotation(csv: Path, factor: float) -> None:
    lines = csv.read_text().splitlines()
    cells = lines[1].split(",")
    cells[5:14] = [str(factor * float(v)) for v in cells[5:14]]
    lines[1] = ",".join(cells)
    csv.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("case", ["rotation_x3", "truncated_test_png", "all_depth_missing"])
def test_invalid_dataset_stops_training_before_the_fit(case: str, tiny_dataset: Path, tmp_path: Path) -> None:
    data = _copy(tiny_dataset, tmp_path / "data")
    if case == "rotation_x3":
        bad = data / "gt" / "cycle_0002" / "001.csv"
        _scale_rotation(bad, 3.0)
        message = "not orthonormal"
    elif case == "truncated_test_png":
        bad = sorted((data / "p_depth").rglob("*.png"))[-1]  # the last cycle: a test scene
        bad.write_bytes(bad.read_bytes()[:200])
        message = "truncated PNG"
    else:
        import cv2

        for png in (data / "p_depth").rglob("*.png"):
            png.write_bytes(cv2.imencode(".png", np.full((128, 128), 65535, np.uint16))[1].tobytes())
        bad = None
        message = "no valid depth in the whole image"
    out = tmp_path / "run"
    start = time.perf_counter()
    with pytest.raises(ValueError, match=message) as err:
        train_cli.run(tiny_train_cfg(data, out, []))
    assert bad is None or str(bad) in str(err.value)
    assert "python -m opnet.datasets.check" in str(err.value)
    assert not (out / "checkpoints").exists() and time.perf_counter() - start < 60  # nothing was fitted


def test_dataset_check_command_lists_every_problem(tiny_dataset: Path, tmp_path: Path) -> None:
    data = _copy(tiny_dataset, tmp_path / "data")
    _scale_rotation(data / "gt" / "cycle_0000" / "001.csv", 3.0)
    _scale_rotation(data / "gt" / "cycle_0003" / "002.csv", -1.0)  # a reflection (det -1)
    png = data / "p_segmentation" / "cycle_0001" / "003_segmentation.png"
    png.write_bytes(png.read_bytes()[:-20])
    proc = subprocess.run([sys.executable, "-m", "opnet.datasets.check", str(data)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 1
    assert "3 problem(s)" in proc.stdout
    for name in ("cycle_0000/001.csv", "cycle_0003/002.csv", "003_segmentation.png"):
        assert name in proc.stdout
    ok = subprocess.run([sys.executable, "-m", "opnet.datasets.check", str(tiny_dataset), "--fast"],
                        capture_output=True, text=True, timeout=120)
    assert ok.returncode == 0 and "0 problem(s)" in ok.stdout


def test_flat_mesh_is_refused_at_once(tmp_path: Path) -> None:
    mesh = tmp_path / "flat.obj"
    mesh.write_text("v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nf 1 2 3\n")
    from opnet.objects.config import object_from_config

    start = time.perf_counter()
    with pytest.raises(ValueError, match=r"flat.obj: the mesh has no volume"):
        obj = object_from_config({"name": "flat", "mesh": str(mesh)})
        generate_dataset(obj, tmp_path / "out", cycles=1, drops=1, workers=1, progress=False, previews=0,
                         scene=SceneConfig(resolution=64), object_config={"name": "flat", "mesh": str(mesh)})
    assert time.perf_counter() - start < 30  # was: V-HACD busy for 300 s+
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("engine", ["mujoco", "pybullet"])
def test_decomposition_time_cap_falls_back_to_the_hull(engine: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    if engine == "pybullet":
        pytest.importorskip("pybullet", reason="pybullet not installed (its V-HACD)")
    mesh = builtin_object("zbracket").mesh
    decompose = (lambda m, d, timeout_s: vhacd_cached(m, 1_000_000, d, timeout_s)) if engine == "pybullet" else (
        lambda m, d, timeout_s: coacd_cached(m, 0.1, d, timeout_s))
    assert decompose(mesh, tmp_path, timeout_s=0.05) is None
    assert not list(tmp_path.iterdir())  # no temporary folder left behind
    monkeypatch.setenv("OPNET_VHACD_TIMEOUT", "0.05")
    model = build_collision_model(mesh, SceneConfig(collision="vhacd", cache_dir=str(tmp_path), physics=engine))
    assert model.mode == "convex_hull" and model.obj_file is None


def test_a_failing_decomposition_is_one_line_naming_the_mesh(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from opnet.synthesis import collision

    # in the child: an exception of the decomposition becomes the log line the parent reports, no output file
    def broken(src: str, dst: str, log: str, threshold: float) -> None:
        Path(dst).write_text("half")
        raise RuntimeError("qhull: input is degenerate")

    dst, log = tmp_path / "out.obj", tmp_path / "log.txt"
    collision._child(broken, str(tmp_path / "in.obj"), str(dst), str(log), 0.1)
    assert log.read_text() == "RuntimeError: qhull: input is degenerate" and not dst.exists()

    # in generate_dataset: the message names the mesh file, and nothing is written
    def failed(mesh, threshold, cache_dir, timeout_s=None):
        raise ValueError(f"convex decomposition of the mesh failed (CoACD wrote nothing; log: {log.read_text()})")

    monkeypatch.setattr(collision, "coacd_cached", failed)
    mesh = tmp_path / "part.obj"
    builtin_object("zbracket").mesh.export(mesh)
    cfg = {"name": "part", "mesh": str(mesh)}
    with pytest.raises(ValueError, match=r"part.obj: convex decomposition of the mesh failed \(CoACD wrote nothing; "
                                         r"log: RuntimeError: qhull: input is degenerate\)"):
        generate_dataset(object_from_config(cfg), tmp_path / "out", cycles=1, drops=1, workers=1, progress=False,
                         previews=0, scene=SceneConfig(resolution=64, collision="vhacd", cache_dir=str(tmp_path)),
                         object_config=cfg)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
def test_evaluator_does_not_hang_on_special_files(special: str, tmp_path: Path) -> None:
    path = special
    if special == "fifo":
        path = str(tmp_path / "poseutils.json")
        os.mkfifo(path)
    (tmp_path / "gt").mkdir()
    (tmp_path / "res").mkdir()
    proc = subprocess.run(["opnet-evaluate", "--gt", str(tmp_path / "gt"), "--results", str(tmp_path / "res"),
                           "--poseutils", path], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "not a regular file" in proc.stderr and path in proc.stderr


def test_evaluator_object_name_is_not_a_path(tmp_path: Path) -> None:
    (tmp_path / "gt").mkdir()
    (tmp_path / "res").mkdir()
    proc = subprocess.run(["opnet-evaluate", "--gt", str(tmp_path / "gt"), "--results", str(tmp_path / "res"),
                           "--object", "../../conf/train"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "not a path" in proc.stderr


def _mtimes(root: Path) -> dict[str, tuple[int, int]]:
    return {str(p.relative_to(root)): (p.stat().st_mtime_ns, p.stat().st_ino) for p in root.rglob("*") if p.is_file()}


def test_complete_dataset_is_used_without_a_single_write(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A complete synthetic dataset (and its cache) on read-only storage: data=synthetic used to
    rewrite its root files; a missing cache now goes to the user cache instead of the dataset."""
    from conftest import compose_cfg

    from opnet.cli.build import build_components, build_datamodule

    root = tmp_path / "ds"
    cfg = compose_cfg("train", ["model=tiny", "object=zbracket", f"data.root={root}", "data.generate.cycles=3",
                                "data.generate.drops=2", "data.generate.workers=1",
                                "scene.resolution=64"])  # fmt: skip
    obj = build_components(cfg).obj
    build_datamodule(cfg, obj).prepare_data()  # generates and caches
    before = _mtimes(root)
    build_datamodule(cfg, obj).prepare_data()
    assert _mtimes(root) == before  # nothing rewritten, nothing added
    # read-only storage without the cache: the cache is built in the user cache, the data untouched
    shutil.rmtree(root / "cache_s256")
    before = _mtimes(root)
    monkeypatch.setenv("OPNET_CACHE", str(tmp_path / "user_cache"))
    real_access = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if Path(p) == root and mode == os.W_OK else real_access(p, mode))
    dm = build_datamodule(cfg, obj)
    dm.prepare_data()
    assert _mtimes(root) == before
    assert list((tmp_path / "user_cache" / "scenes").glob("ds_*_s256/cache.json"))


def test_fewer_cycles_keep_number_cycles_consistent(tmp_path: Path) -> None:
    root = small_builtin_dataset(tmp_path / "ds", "zbracket", 3, 1, 0)
    small_builtin_dataset(root, "zbracket", 2, 1, 0)  # re-run with fewer cycles
    params = json.loads((root / "parameter.json").read_text())
    assert params["number_cycles"] == 3 == len(list((root / "gt").iterdir()))


def test_resume_from_a_truncated_checkpoint_names_it(tiny_dataset: Path, tmp_path: Path) -> None:
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "last.ckpt").write_bytes(b"PK\x03\x04" + b"\x00" * 100)
    proc = subprocess.run(
        [sys.executable, str(REPO_ROOT / "train.py"), "model=tiny", "object=zbracket", f"data.root={tiny_dataset}",
         "data.generate=null", "ckpt_path=last", f"hydra.run.dir={run}", "trainer.enable_progress_bar=false"],
        capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr and "last.ckpt: truncated or corrupt checkpoint" in proc.stderr


@pytest.mark.parametrize(("override", "message"), [
    ("data.check=sometimes", "data.check='sometimes'"),  # raised inside Hydra's instantiate
    ("data.batch_size=4", "/nonexistent/ds"),
])  # fmt: skip
def test_entry_point_errors_are_one_line(override: str, message: str, tmp_path: Path) -> None:
    proc = subprocess.run(
        [sys.executable, str(REPO_ROOT / "train.py"), "model=tiny", "data.generate=null", "data.root=/nonexistent/ds",
         override, f"hydra.run.dir={tmp_path / 'run'}"], capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert lines[-1].startswith("error: ") and message in lines[-1]
    assert "Traceback" not in proc.stderr + proc.stdout


def test_the_debug_switch_raises_what_the_one_line_names(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """train.py's guard, in this process: the error raised inside Hydra's instantiate is one line and exit 2;
    with HYDRA_FULL_ERROR=1 it is raised instead, for its traceback."""
    from opnet.cli.console import guarded

    cfg = tiny_train_cfg(Path("/nonexistent/ds"), tmp_path / "run", ["data.generate=null", "data.check=sometimes"])
    with pytest.raises(SystemExit) as stopped:
        guarded(train_cli.run, cfg)
    assert stopped.value.code == 2
    monkeypatch.setenv("HYDRA_FULL_ERROR", "1")
    with pytest.raises(Exception, match="sometimes"):
        guarded(train_cli.run, cfg)


@pytest.mark.slow
def test_fuzz_pass_over_the_readers_finds_no_bug(tmp_path: Path) -> None:
    """scripts/dev/fuzz_inputs.py, readers only (the command lines run in the script's full pass)."""
    spec = importlib.util.spec_from_file_location("fuzz_inputs", REPO_ROOT / "scripts" / "dev" / "fuzz_inputs.py")
    fuzz = importlib.util.module_from_spec(spec)
    sys.modules["fuzz_inputs"] = fuzz  # its dataclasses look their module up
    spec.loader.exec_module(fuzz)
    assert fuzz.main(["--no-cli", "--keep", str(tmp_path / "fuzz"), "--out", str(tmp_path / "fuzz.md")]) == 0
    table = (tmp_path / "fuzz.md").read_text()
    assert table.count("| error |") >= 60 and "bugs: 0" in table


def test_mesh_in_millimetres_names_the_file(tmp_path: Path) -> None:
    from opnet.objects.config import object_from_config

    mesh = tmp_path / "box_mm.obj"
    trimesh.creation.box((40.0, 30.0, 20.0)).export(mesh)
    with pytest.raises(ValueError, match=r"box_mm.obj: implausible units"):
        object_from_config({"name": "box", "mesh": str(mesh)})
