"""Every command of the task tables of docs/commands.md and README.md runs as printed, on tiny data.

docs/commands.md holds every command in one table (``| task | command |``); the README's "what
next" table (``| task | command | read more |``) is a selection of its rows: each README row must be
a row of docs/commands.md with the same task and, to the letter, the same command, so running the
commands page's table runs the README's too (``readme_commands`` asserts it; the fast
``tests/unit/test_doc_links.py`` calls it on every test run). The commands are read from the two
pages themselves; each placeholder (``<ckpt>``, ``<dir>``, ...) is replaced by a real path of this
test's workspace, optional ``[...]`` parts are kept, and only size overrides (fewer cycles, one
epoch, the tiny network, a CPU trainer) are appended. A row of either table without a runner here
fails the test, so the tables and this test cannot part ways.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from opnet.datasets.png import write_png
from opnet.paths import REPO_ROOT

TINY_DATA = ["data.generate.cycles=6", "data.generate.drops=3", "data.generate.workers=1",
             "scene.resolution=128"]
TINY_FIT = ["trainer.max_epochs=1", "+trainer.limit_train_batches=2", "+trainer.limit_val_batches=1",
            "trainer.enable_progress_bar=false", "example_predictions=1"]


COMMANDS_PAGE = REPO_ROOT / "docs" / "commands.md"


def task_table(page: Path) -> dict[str, str]:
    """task -> the first `command` of its row in the page's task table (the table whose header
    starts ``| task | command |``; further columns, such as the README's links, are ignored)."""
    lines = page.read_text().split("\n| task | command |", 1)[1].split("\n\n")[0].splitlines()
    assert re.fullmatch(r"\|(-+\|)+", lines[1]), f"{page}: the task table's header is not followed by its rule"
    rows = {}
    for line in lines[2:]:
        cells = line.split("|")
        task, command = cells[1].strip(), re.search(r"`([^`]+)`", cells[2]).group(1)
        assert task not in rows, f"{page}: task {task!r} twice"
        rows[task] = command
    return rows


def readme_commands() -> dict[str, str]:
    """task -> command of every row of docs/commands.md, after checking that each row of the
    README's table is one of them, command for command."""
    rows = task_table(COMMANDS_PAGE)
    for task, command in task_table(REPO_ROOT / "README.md").items():
        assert task in rows, f"README task {task!r} is not a row of docs/commands.md"
        assert rows[task] == command, f"README task {task!r}: {command!r} but docs/commands.md {rows[task]!r}"
    return rows


def fill(command: str, values: list[tuple[str, str]]) -> list[str]:
    """The README command with its placeholders replaced in order of appearance and the optional
    ``[...]`` parts kept, as an argv."""
    for placeholder, value in values:
        assert placeholder in command, f"{placeholder} not in {command!r}"
        command = command.replace(placeholder, value, 1)
    leftover = re.findall(r"<[^>]+>", command)
    assert not leftover, f"unfilled placeholders {leftover} in {command!r}"
    command = command.replace("[", "").replace("]", "")
    argv = shlex.split(command)
    if argv[0] == "python":
        argv[0] = sys.executable
    return argv


def assert_console_ends_with_the_summary(proc: subprocess.CompletedProcess, run_dir: Path) -> None:
    """train.py's console: no line twice, no banners or adverts, and the metric summary and output paths
    are the last lines, in the run's log file too."""
    out_lines = [line for line in (proc.stdout + proc.stderr).splitlines() if line.strip()]
    for banner in ("pybullet build time", "litlogger", "OpenGL_accelerate", "Traceback"):
        hits = [i for i, line in enumerate(out_lines) if banner in line]
        assert not hits, f"{banner!r} printed:\n" + "\n".join(out_lines[max(0, hits[0] - 5):hits[0] + 40])
    messages = [line.split("] - ", 1)[1] for line in out_lines if "] - " in line]
    assert messages and len(messages) == len(set(messages)), "a log line appears twice"
    assert sum("Total params" in line for line in out_lines) == 1  # the model summary once
    stdout = [line for line in proc.stdout.splitlines() if line.strip()]
    start = max(i for i, line in enumerate(stdout) if re.match(r"test \d+ scenes", line))
    tail = stdout[start:]  # test N scenes / AP ... / [errors] / run time / 5 paths: nothing after them
    assert tail[1].strip().startswith("AP ") and "run time" in tail[-6] and len(tail) in (8, 9)
    assert tail[-5].startswith("run directory : ") and tail[-1].startswith("predictions   : ")
    summary = json.loads((run_dir / "test" / "summary.json").read_text())
    assert f"AP {summary['ap']:.4f}" in tail[1]
    log_text = (run_dir / "train.log").read_text()
    assert tail[1] in log_text and log_text.rstrip().endswith(tail[-1])


def cell_rows(run: Callable[..., subprocess.CompletedProcess], ws: Path) -> None:
    """The three rows of your cell: frames of a generated pile of a known rig (its depth PNGs and camera YAML, a
    calibration of the generator's own pose), the cell file written into the workspace (train.py finds it there
    through the config search path), the check, and a tiny training of the cell."""
    from opnet.synthesis.config import SceneConfig
    from opnet.synthesis.layout import R_WORLD_CAM_DOWN, homogeneous, tilted

    camera = ws / "cell_camera.yaml"
    camera.write_text("fx: 300\nfy: 300\ncx: 159.5\ncy: 119.5\nwidth: 320\nheight: 240\nclip_start: 0.5\nclip_end: 3.0\n")
    frames = ws / "cell_frames"
    scene = SceneConfig(camera_file=str(camera), clip="camera", camera_height=1.2, camera_tilt_deg=15.0,
                        camera_azimuth_deg=40.0, bin_inner=0.3, bin_inner_y=0.45, bin_wall_height=0.12,
                        bin_wall_thickness=0.004, camera_jitter_m=0.0, camera_jitter_deg=0.0, outside_clip="clamp")
    # in a child process: this runs in a lane's thread, and the renderer's EGL context belongs to the thread
    # that made it (another lane's, or the main thread's)
    generate = (f"from opnet.objects.library import builtin_object; from opnet.synthesis.config import SceneConfig; "
                f"from opnet.synthesis.generate import generate_dataset; "
                f"generate_dataset(builtin_object('zbracket'), {str(frames)!r}, cycles=1, drops=1, workers=1, seed=0, "
                f"scene=SceneConfig.from_dict({scene.to_dict()!r}), progress=False, previews=0)")
    subprocess.run([sys.executable, "-c", generate], check=True, cwd=REPO_ROOT,
                   env={**os.environ, "PYOPENGL_PLATFORM": "egl"})
    calibration = ws / "T_base_cam.yaml"
    pose = tilted(homogeneous(R_WORLD_CAM_DOWN, np.array([0.2, 0.1, 1.3])), 15.0, 40.0)
    calibration.write_text(json.dumps({"T_base_cam": pose.tolist()}))  # JSON is YAML
    cell_file = ws / "cell" / "mine.yaml"
    printed = run("set your cell up from a few of its depth frames (no ground truth)",
                  [("<frames>", str(frames)), ("<camera file>", str(camera)), ("<N>", "mine"),
                   ("<preset>", "structured_light"), ("<cell file>", str(cell_file)),
                   ("<T_base_cam yaml>", str(calibration))]).stdout
    assert "bin inner 0.300" in printed and cell_file.is_file() and cell_file.with_suffix(".png").is_file()
    run("check your cell against generated piles before training",
        [("<N>", str(cell_file)), ("<frames>", str(frames)), ("<o>", "zbracket"), ("<dir>", str(ws / "cell_check"))],
        ["--piles", "1", "--drops", "2"])
    assert (ws / "cell_check" / "README.md").is_file()
    trained = run("train for your cell (every measured key from its cell file)", [("<N>", "mine"), ("<o>", "zbracket")],
                  [f"hydra.searchpath=[file://{ws}]", *TINY_DATA, "model=tiny", *TINY_FIT,
                   f"hydra.run.dir={ws / 'cell_run'}"]).stdout
    assert trained.startswith("cell mine: camera") and "sensor structured_light" in trained
    assert next((ws / "outputs" / "data").glob("cell_mine_*_zbracket_c6_v2_d3_s0_sl"))


@pytest.mark.slow
def test_readme_table_commands_run_as_printed(tmp_path: Path) -> None:
    rows = readme_commands()
    ws = tmp_path
    # a fresh machine: no reference data beside the clone (the tables' commands must not need it)
    env = {**os.environ, "OPNET_ROOT": str(ws), "PYOPENGL_PLATFORM": "egl", "OPNET_SHARED": str(ws / "no_shared")}
    done: set[str] = set()

    def run(task: str, values: list[tuple[str, str]], extra: list[str] = ()) -> subprocess.CompletedProcess:
        argv = [*fill(rows[task], values), *extra]
        proc = subprocess.run(argv, cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, f"task table command failed: {shlex.join(argv)}\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
        assert "Traceback" not in proc.stdout + proc.stderr
        done.add(task)
        return proc

    qs_dir = ws / "qs_run"
    qs_extra = [*TINY_DATA, "model=tiny", *TINY_FIT]
    # from a fresh root: the generation included
    assert_console_ends_with_the_summary(
        run("quickstart (data → train → test → predictions)", [], [*qs_extra, f"hydra.run.dir={qs_dir}"]), qs_dir)
    ckpt = qs_dir / "checkpoints" / "last.ckpt"
    data = next((ws / "outputs" / "data").glob("shaft_*"))

    run("resume an interrupted run", [("<same overrides>", shlex.join(["experiment=quickstart", *qs_extra])),
                                      ("<run dir>", str(qs_dir))], ["trainer.max_epochs=2"])

    # the rest in two lanes side by side (each command a process of its own; the two cores both at work): one
    # trains, the other evaluates, predicts, generates and exports; neither writes what the other reads
    def lane_training() -> None:
        run("train a parameterization", [], [*TINY_DATA, *TINY_FIT, "model=tiny", f"hydra.run.dir={ws / 'eve_run'}"])

        run("sweep the paper's six variants", [], [*TINY_DATA, *TINY_FIT, "model=tiny"])
        sweep = next((ws / "outputs" / "train" / "multiruns").iterdir())
        assert len([p for p in sweep.iterdir() if p.is_dir()]) == 6
        run("compare a sweep (Table I layout)", [("outputs/train/multiruns/<date_time>", str(sweep))])
        # one row per arm (named <n>_<parameterization>_<object>_<model>), its AP the arm's own test AP
        tested = {arm.name.split("_")[1]: json.loads((arm / "test" / "summary.json").read_text())["ap"]
                  for arm in sweep.iterdir() if arm.is_dir()}  # fmt: skip
        compared = (sweep / "comparison.csv").read_text().splitlines()
        assert compared[0].startswith("parameterization,object,ap") and len(compared) == 7
        assert {r.split(",")[0]: float(r.split(",")[2]) for r in compared[1:]} == pytest.approx(tested, abs=1e-6)
        assert (sweep / "comparison.png").stat().st_size > 1000 and "| vanilla |" in (sweep / "comparison.md").read_text()
        # TensorBoard is a server: its command is checked to exist and the sweep to hold event files
        assert fill(rows["TensorBoard over a sweep"], [("outputs/train/multiruns/<date_time>", str(sweep))])[0] == "tensorboard"
        assert subprocess.run(["tensorboard", "--version_tb"], capture_output=True, timeout=120).returncode == 0
        assert len(list(sweep.rglob("events.out.tfevents*"))) >= 6
        done.add("TensorBoard over a sweep")

        bop = ws / "bop"
        run("write a dataset as BOP", [("<ipa dataset>", str(data)), ("<bop dataset>", str(bop))])
        run("train on a BOP split", [("<bop dataset>", str(bop))],
            ["model=tiny", "data.num_workers=0", *TINY_FIT, f"hydra.run.dir={ws / 'bop_run'}"])
        assert (ws / "bop_run" / "test" / "bop_results.csv").is_file()
        run("paper network on a GPU", [], ["trainer=cpu", "trainer.precision=32", *TINY_DATA, *TINY_FIT, "test=false",
                                           "data.batch_size=2", "data.num_workers=0", f"hydra.run.dir={ws / 'paper_run'}"])
        assert (ws / "paper_run" / "checkpoints" / "last.ckpt").is_file()  # the full network trained (tested above)

    def lane_inference() -> None:
        run("evaluate a checkpoint", [("<run dir>", str(qs_dir)), ("<other data>", str(data)),
                                      ("<score all of other data>", str(data))], ["examples=0"])

        run("refine the poses with ICP against the depth (eval, predict)", [("<ckpt>", str(ckpt))],
            ["examples=0", f"out={ws / 'eval_icp'}"])
        assert "icp" in json.loads((ws / "eval_icp" / "summary.json").read_text())
        run("refine flat parts: ICP + the depth-agreement search, ranked by agreement (eval, predict)", [("<ckpt>", str(ckpt))],
            ["examples=0", f"out={ws / 'eval_search'}", "refine.search.turn_step_deg=45", "refine.search.shift=0.04"])
        searched = json.loads((ws / "eval_search" / "summary.json").read_text())["icp"]
        assert searched["settings"]["search"]["turn_step_deg"] == 45 and "searched" in searched["statuses"]
        run("evaluate with another decoding than the checkpoint's", [("<ckpt>", str(ckpt))],
            ["examples=0", f"out={ws / 'eval_decoding'}"])
        assert (ws / "eval_decoding" / "summary.json").is_file()
        run("estimate poses", [("<ckpt>", str(ckpt)), ("<depth png, .npy, or folder>", str(data / "p_depth")),
                               ("<dir>", str(ws / "pred"))])
        assert len(list((ws / "pred" / "results").glob("*.json"))) == len(list((data / "p_depth").rglob("*.png")))
        frame = ws / "camera_frame.png"  # a frame of "your camera": no camera file anywhere above it
        depth = np.full((120, 160), 1.1, np.float32)
        depth[40:80, 60:100] = 1.0
        write_png(frame, np.round(depth * 1000).astype(np.uint16))
        printed = run("estimate poses on your camera's 16-bit PNG",
                      [("<ckpt>", str(ckpt)), ("<png or folder>", str(frame)), ("<px>", "150"), ("<px>", "150"),
                       ("<px>", "79.5"), ("<px>", "59.5"), ("<m>", "0.5"), ("<m>", "1.5")],
                      [f"out={ws / 'pred_camera'}"]).stdout
        assert "camera: fx=150 fy=150 cx=79.5 cy=59.5 160x120" in printed and "depth = value x 0.001 m" in printed
        assert (ws / "pred_camera" / "camera_frame.json").is_file()

        gen = ws / "generated"
        run("generate data", [("<dir>", str(gen))], ["cycles=2", "drops=3", "scene.resolution=128", "previews=0",
                                                     "workers=1"])  # the other lane has the other core
        assert (gen / "parameter.json").is_file()

        cam = ws / "camera.yaml"  # an off-centre camera of non-square pixels
        cam.write_text("fx: 140.0\nfy: 142.0\ncx: 50.3\ncy: 44.6\nwidth: 128\nheight: 96\nclip_start: 0.3\nclip_end: 2.0\n")
        run("generate with your camera and a depth-sensor model",
            [("<camera.yaml or camera_params.txt>", str(cam)), ("<dir>", str(ws / "gen_camera"))],
            ["cycles=1", "drops=3", "previews=0"])
        assert json.loads((ws / "gen_camera" / "parameter.json").read_text())["opnet_intrinsics"] == [140.0, 142.0, 50.3, 44.6]
        run("generate bulk piles (70–80 parts, many hidden)", [("<dir>", str(ws / "gen_bulk"))],
            ["drops=10", "cycles=1", "workers=1", "scene.resolution=96", "previews=0"])
        dense = run("train on dense bulk piles seen by your camera (generates them first)",
                    [("<o>", "bracket"), ("<camera.yaml or camera_params.txt>", str(cam)), ("<m>", "1.0")],
                    ["data.generate.cycles=6", "data.generate.drops=4", "data.generate.workers=1", "scene.views=2",
                     "model=tiny", *TINY_FIT, f"hydra.run.dir={ws / 'dense_run'}"]).stdout
        assert "run directory : " in dense
        dense_data = next((ws / "outputs" / "data").glob("dense_bracket_c6_v2_d4_s0*"))
        dense_scene = json.loads((dense_data / "generation.json").read_text())["scene"]
        assert dense_scene["views"] == 2 and dense_scene["camera_height"] == 1.0  # your rig as it stands (rig_d=null)
        cell_rows(run, ws)
        # your part, your camera, your cell: its first command here (a part's mesh into its object config, written
        # into the workspace); the others are the rows of the cell, its training, the export and the runtime
        import trimesh

        mesh = ws / "part.stl"
        trimesh.creation.box(extents=(0.08, 0.04, 0.02)).export(mesh)
        run("your part, your camera, your cell", [("<mesh>", str(mesh)), ("<o>", "mypart")],
            ["--out", str(ws / "object" / "mypart.yaml")])
        assert "name: mypart" in (ws / "object" / "mypart.yaml").read_text()
        model = ws / "model.onnx"
        printed = run("export to ONNX (network + decoder + metadata)", [("<ckpt>", str(ckpt)), ("<model.onnx>", str(model))]).stdout
        assert model.is_file() and "ONNX Runtime vs PyTorch" in printed
        run("estimate poses without PyTorch", [("<model.onnx>", str(model)),
                                               ("<depth png, .npy, or folder>", str(data / "p_depth" / "cycle_0000")),
                                               ("<dir>", str(ws / "pred_onnx"))])
        assert len(list((ws / "pred_onnx" / "results").glob("*.json"))) == len(list((data / "p_depth" / "cycle_0000").glob("*.png")))

        run("score any results", [("<dir>", str(qs_dir / "test" / "gt")), ("<dir>", str(qs_dir / "test" / "results")),
                                  ("<json>", str(data / "poseutils.json"))],
            ["--out", str(ws / "summary.json"), "--plot", str(ws / "pr.png")])  # the README's relative names: in ws
        assert (ws / "pr.png").stat().st_size > 1000
        run("parameterization ceiling", [("<dir>", str(gen)), ("<dir>", str(data)), ("<dir>", str(ws / "ceiling"))])
        assert (ws / "ceiling" / "ceiling.csv").is_file()


    with ThreadPoolExecutor(2) as pool:
        for lane in [pool.submit(lane_training), pool.submit(lane_inference)]:
            lane.result()  # a lane's failure, with its message
    assert set(rows) == done, f"task table rows without a runner here: {sorted(set(rows) - done)}"
