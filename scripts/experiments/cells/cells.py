"""A real cell whose bin moves: one model per cell, scored where the bin stood in training and where it did not.

The IPD cell of ``../shared/data/ipd_real_obj18`` (its Photoneo at the pose measured from the frames' ground
truth, the wire basket, IPD object 18): training piles whose basket stands anywhere on a working area of
the floor (``scene.bin_area``) in any yaw, the network's input cropped around the basket found in each image
(``data.roi=auto:S``, S metres); scored on generated piles of another seed with the basket where the earlier
recipe always put it (``trained``: within 4 cm of the camera's aim point) and moved beyond that (``moved``:
the four corners of the working area), each as decoded and with the depth-agreement search, beside the
earlier fixed-box recipe's shipped model on the same piles.

    python scripts/experiments/cells/cells.py                       # generate, train, evaluate: results/cells/
    python scripts/experiments/cells/cells.py --stage report        # re-make results/cells/ from the evaluations

Every setting here is chosen without the real frames: the cell (camera, its pose, the basket's size) is what
a user measures; S is 1.1 x the basket's outer diagonal (the basket in any yaw with the finder's error to
spare); the training recipe is the earlier one's (its generated-pile A/B: results/real_ipd/ab.md). The
real frames are scored once, by ``--stage real``, with the recipe fixed before.

Training piles are rendered at half the camera's resolution (the same field of view and pose; the sensor
model's pixel-unit settings halved), four times faster than full frames; the test piles and the real frames
are full frames, as the camera gives them.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
import os
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np

from opnet.paths import REPO_ROOT, best_checkpoint, shared_dir
from opnet.studies import mean_sd, mean_sd_text, run_logged, train_command

FRAMES = shared_dir() / "data" / "ipd_real_obj18"
OBJECT_ID = 18
#: the working volume (metres): the basket's height range seen by the camera, as the earlier recipe
CLIP = (1.55, 2.05)
#: the camera over the floor, measured from the frames' ground truth (python -m opnet.synthesis.camera_pose)
CAMERA_POSE = {"camera_height": 1.7748, "camera_tilt_deg": 19.86, "camera_azimuth_deg": -30.26}
#: the basket (measured sizes), standing 0.6 m above the ground, in any yaw
BASKET = {"bin_inner": 0.3, "bin_inner_y": 0.65, "bin_wall_height": 0.1, "bin_wall_thickness": 0.002,
          "bin_clearance": 0.6, "bin_jitter_deg": 180.0, "camera_jitter_deg": 3.0, "camera_jitter_m": 0.03,
          "outside_clip": "clamp", "clutter": 8}  # fmt: skip
#: the basket perforations (SIZE, PITCH metres): the training cycles shared out among them
HOLES = ((0.012, 0.018), (0.016, 0.021), (0.02, 0.026))
#: where the basket may stand: [x0, y0, x1, y1] metres of the ground around the camera's aim point
AREA = (-0.2, -0.2, 0.2, 0.2)
#: the earlier recipe's placement (its bin_jitter_m) and the moved test piles: the area's four corners
TRAINED_JITTER = 0.04
#: the validation piles' seed (the training piles use 0-2, the test piles 100-113)
VALIDATION_SEED = 200
CORNERS = ((0.1, 0.1, 0.2, 0.2), (-0.2, 0.1, -0.1, 0.2), (-0.2, -0.2, -0.1, -0.1), (0.1, -0.2, 0.2, -0.1))
#: the earlier recipe's fixed box (pixels of the full frames) and its shipped model
OLD_ROI = (560, 230, 1250, 1160)
OLD_MODEL = REPO_ROOT / "models" / "fixed_box_ipd_plate.ckpt"
#: the one command's model (``--stage cell``: train.py experiment=cell), shipped as this file
CELL_MODEL = REPO_ROOT / "models" / "real_ipd_plate.ckpt"
#: the sensor model's settings in pixels (halved with the resolution)
PIXEL_SENSOR_KEYS = {"lateral_px": 0.5, "edge_missing_px": 2, "blob_scale_px": 15.0}
FIELDS = ("policy", "model", "placement", "refine", "scenes", "required", "ap", "found", "found_of_all",
          "t_err_mm_p50", "r_err_deg_p50", "ms_per_frame")  # fmt: skip


def roi_side() -> float:
    """S of ``auto:S``: 1.1 x the basket's outer diagonal, rounded up to 5 cm."""
    t = BASKET["bin_wall_thickness"]
    diagonal = math.hypot(BASKET["bin_inner"] + 2 * t, BASKET["bin_inner_y"] + 2 * t)
    return math.ceil(1.1 * diagonal * 20) / 20


def run(cmd: list[str], log: Path) -> None:
    """A command of the framework, its console in ``log``; a failure names the log."""
    run_logged(cmd, log, REPO_ROOT)


def camera_file(scale: float, out: Path, clip: tuple[float, float] = CLIP) -> Path:
    """The cell's camera (the frames' Photoneo) with the clip planes ``clip``, its pixels scaled by ``scale``."""
    from opnet.datasets.camera_file import read_camera_file

    cam = read_camera_file(FRAMES / "camera_photoneo.yaml").scaled(scale)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(f"# the Photoneo of the IPD frames at {scale:g} x its pixels, clip planes {clip} (scripts/cells.py)\n"
                   f"fx: {cam.fx!r}\nfy: {cam.fy!r}\ncx: {cam.cx!r}\ncy: {cam.cy!r}\n"
                   f"width: {cam.width}\nheight: {cam.height}\nclip_start: {clip[0]!r}\nclip_end: {clip[1]!r}\n")  # fmt: skip
    return out


def generate(camera: Path, out: Path, cycles: int, views: int, seed: int, scale: float, logs: Path,
             **scene: Any) -> None:  # fmt: skip
    settings = {"camera_file": str(camera), "clip": "camera", "views": views, **CAMERA_POSE, **BASKET,
                **scene}  # fmt: skip
    from opnet.synthesis.sensor import SensorModel

    pixel = SensorModel(**PIXEL_SENSOR_KEYS).scaled(scale)
    sensor = [f"sensor.{k}={getattr(pixel, k)}" for k in PIXEL_SENSOR_KEYS]
    value = lambda v: "[" + ",".join(map(str, v)) + "]" if isinstance(v, (list, tuple)) else v  # noqa: E731
    run([sys.executable, "generate.py", "object=ipd_plate", "sensor=photoneo", *sensor, f"cycles={cycles}",
         "drops=10", "workers=2", f"seed={seed}", f"out={out}", "progress=false", "previews=2",
         *(f"scene.{k}={value(v)}" for k, v in settings.items())], logs / f"generate_{out.name}.log")  # fmt: skip


def planes_tag(clip: tuple[float, float]) -> str:
    """The name tag of what is written within ``clip``: none for the study's planes."""
    return "" if tuple(clip) == CLIP else f"_clip{clip[0]:g}-{clip[1]:g}"


def datasets(data: Path, cycles: int, test_cycles: int, clip: tuple[float, float] = CLIP) -> tuple[list[tuple[Path, int, dict]], dict[str, list[tuple[Path, dict]]]]:
    """(training sets: (root, cycles, scene settings)), {placement: test sets (root, scene settings)}; the test
    piles written within ``clip`` (the study's working volume, or a cell file's: then in folders of their own)."""
    train = []
    for k, (size, pitch) in enumerate(HOLES):
        n = cycles // len(HOLES) + (k < cycles % len(HOLES))
        train.append((data / f"train_c{n}_h{size * 1000:g}", n,
                      {"bin_area": AREA, "bin_hole_size": size, "bin_hole_pitch": pitch, "seed": k}))
    size, pitch = HOLES[0]
    holes = {"bin_hole_size": size, "bin_hole_pitch": pitch}
    planes = planes_tag(clip)
    tests = {"trained": [(data / f"test_trained_c{test_cycles}{planes}", {"bin_jitter_m": TRAINED_JITTER, **holes,
                                                                           "cycles": test_cycles})],
             "moved": [(data / f"test_moved{k}_c{test_cycles // 4}{planes}", {"bin_area": area, **holes, "cycles": test_cycles // 4})
                       for k, area in enumerate(CORNERS)]}  # fmt: skip
    return train, tests


def generate_tests(data: Path, tests: dict[str, list[tuple[Path, dict]]], clip: tuple[float, float], logs: Path) -> None:
    """The test piles of :func:`datasets` at the camera's full resolution, one view each, written within
    ``clip``: the same seeds (so the same piles) whatever the planes; cycles complete before are kept."""
    full = camera_file(1.0, data / f"camera_x1{planes_tag(clip)}.yaml", clip)
    for k, sets in enumerate(tests.values()):
        for j, (root, scene) in enumerate(sets):
            scene = dict(scene)
            generate(full, root, scene.pop("cycles"), 1, 100 + 10 * k + j, 1.0, logs, **scene)


def validation_set(data: Path, cycles: int) -> tuple[Path, dict]:
    """The validation piles the refinement's settings are chosen on (``scripts/verify_ab.py --parts cell_plate``): the basket
    anywhere in the working area, any yaw, full resolution, a seed neither training nor the test piles use."""
    size, pitch = HOLES[0]
    return data / f"val_c{cycles}", {"bin_area": AREA, "bin_hole_size": size, "bin_hole_pitch": pitch, "cycles": cycles}


def evaluate(ckpt: Path, roots: list[Path], out: Path, overrides: list[str],
             clip: tuple[float, float] = CLIP) -> dict[str, Any]:  # fmt: skip
    """``eval.py`` of ``ckpt`` on the datasets ``roots`` (one test split, written within ``clip``) with
    ``overrides``; its summary."""
    listed = "[" + ",".join(str(r) for r in roots) + "]"
    run([sys.executable, "eval.py", f"ckpt={ckpt}", f"data.root={listed}", f"data.test_root={listed}",
         f"+data.clip=[{clip[0]},{clip[1]}]", "+data.cache=false", f"out={out}", "examples=2", *overrides],
        out.with_suffix(".log"))  # the depth at the camera's resolution, for the network's crop and the search
    return json.loads((out / "summary.json").read_text())


#: the refinements scored: none, the search, and the recipe's (RECIPE_REFINE): the most accurate on the cell
#: study's validation piles within the speed target, 300 ms per frame on 2 cores (results/verification/speed.md)
REFINE = {"none": ["refine=none"], "search": ["refine=search", "+decoding.averaging=false"],
          "search_fast": ["refine=search_fast", "+decoding.averaging=false"],
          "search_flat": ["refine=search_flat", "+decoding.averaging=false"]}  # fmt: skip
RECIPE_REFINE = "search_fast"


def row(summary: dict[str, Any], **keys: Any) -> dict[str, Any]:
    d = summary["diagnostics"]
    n = max(d["to_find"], 1)
    return {**keys, "scenes": summary["num_scenes"], "required": d["to_find"], "ap": round(summary["ap"], 4),
            "found": round(d["matched"] / n, 4), "matched": d["matched"], "t_err_mm_p50": d["t_err_mm_p50"], "r_err_deg_p50": d["r_err_deg_p50"],
            "ms_per_frame": (summary.get("icp") or {}).get("ms_per_image", "")}  # fmt: skip


def frame_required(roots: list[Path]) -> int:
    """The parts the metric requires in the whole frames of ``roots`` (visibility >= 0.5, max occlusion 0.5):
    a fixed box's evaluation counts only those inside it (the crop scales each part's visibility), so its
    ``found`` and AP are not over the same parts as a crop that holds the whole basket."""
    from opnet.datasets.ipa import IPADataset

    total = 0
    for root in roots:
        dataset = IPADataset(root)
        total += sum(int((np.asarray(dataset[i].visibility) >= 0.5).sum()) for i in range(len(dataset)))
    return total


def write_table(csv_path: Path, rows: list[dict[str, Any]], head: list[str], columns: tuple[str, ...]) -> None:
    """``rows`` as ``csv_path`` and as a markdown table of ``columns`` after ``head`` beside it (README.md for
    cells.csv, else the CSV's name with .md)."""
    csv_path.parent.mkdir(parents=True, exist_ok=True)
    with csv_path.open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=FIELDS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    titles = {"policy": "policy", "model": "model", "placement": "placement", "refine": "refine", "scenes": "scenes",
              "required": "required", "ap": "**AP**", "found": "found %", "found_of_all": "found % of the frame's parts",
              "t_err_mm_p50": "t p50 mm",
              "r_err_deg_p50": "r p50 °", "ms_per_frame": "ms/frame"}  # fmt: skip
    cell = {"ap": lambda v: f"**{float(v):.3f}**", "found": lambda v: f"{100 * float(v):.1f}",
            "found_of_all": lambda v: "" if v in ("", None) else f"{100 * float(v):.1f}",
            "t_err_mm_p50": lambda v: f"{float(v):.1f}", "r_err_deg_p50": lambda v: f"{float(v):.1f}",
            "ms_per_frame": lambda v: "" if v in ("", None) else f"{float(v):.0f}"}  # fmt: skip
    lines = [*head, "| " + " | ".join(titles[c] for c in columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(cell.get(c, str)(r[c]) for c in columns) + " |" for r in rows]
    md = csv_path.with_name("README.md") if csv_path.name == "cells.csv" else csv_path.with_suffix(".md")
    md.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def report(rows: list[dict[str, Any]], out: Path, command: str, notes: list[str]) -> None:
    head = ["# A cell whose bin moves: generated piles where the basket stood in training and where it did not", "",
            f"Made by {command}.\n\nIPD object 18 in the IPD cell (its Photoneo at the measured pose, the wire basket "
            f"standing 0.6 m above the ground, up to 10 plates and 8 foreign pieces); test piles of another seed "
            f"at the camera's full resolution: `trained` = the basket within {TRAINED_JITTER * 100:g} cm of the "
            f"camera's aim point (where the earlier recipe always put it), `moved` = in the four corners of the "
            f"working area {list(AREA)} m (0.14-0.28 m from the aim point), any yaw. AP: Brégier, max occlusion "
            "0.5, over every scene of the split (piles of 0-10 plates).", ""]  # fmt: skip
    write_table(out / "cells.csv", rows, head, FIELDS)
    with (out / "README.md").open("a") as f:
        f.write("\n" + "\n".join(seed_table(rows)) + "\n" + "\n" + "\n\n".join(notes) + "\n")


def seed_table(rows: list[dict[str, Any]]) -> list[str]:
    """Mean ± sample sd over the training seeds of each policy's rows that have more than one seed (AP, and
    moved minus trained: the recipe's acceptance holds where |moved - trained| <= 0.05)."""
    groups: dict[tuple[str, str, str], dict[str, list[float]]] = {}
    for r in rows:  # the seeds of one arm (its name without a seed suffix) at one input size
        name, _, size = r.get("model", "").split(", seed")[0].partition(" (")
        arm = re.sub(r"_s\d+$", "", name)
        piles = r.get("model", "").partition(", piles ")[2]  # one model on the same piles within other planes: no seed
        groups.setdefault((r["policy"], r["refine"], f"{arm} {size} {piles}"), {}).setdefault(r["placement"], []).append(
            float(r["ap"]))
    lines = []
    for (policy, refine, _), by in groups.items():
        trained, moved = by.get("trained", []), by.get("moved", [])
        if len(trained) < 2 or len(trained) != len(moved):
            continue
        gap = mean_sd(moved)[0] - mean_sd(trained)[0]
        lines.append(f"| {policy} | {refine} | {len(trained)} | {mean_sd_text(trained)} | {mean_sd_text(moved)} | "
                     f"{gap:+.3f} ({'within' if abs(gap) <= 0.05 else 'beyond'} 0.05) |")
    if not lines:
        return []
    return ["Over the training seeds (mean ± sample sd of the rows above):", "",
            "| policy | refine | seeds | AP trained | AP moved | moved - trained |", "|---|---|---|---|---|---|", *lines]


def score_real(ckpt: Path, run_dir: Path, clip: tuple[float, float], policy: str, refines: list[str]) -> list[dict[str, Any]]:
    """eval.py of ``ckpt`` on the three real frames, read within ``clip``, once per refinement of ``refines``
    (into ``<run_dir>/eval_real/<refine>``); their rows."""
    rows = []
    split = (FRAMES / "test").resolve()
    for refine in refines:
        out = run_dir / "eval_real" / refine
        run([sys.executable, "eval.py", f"ckpt={ckpt}", f"data.root={split}", f"data.test_root={split}",
             f"+data.object_id={OBJECT_ID}", f"+data.clip=[{clip[0]},{clip[1]}]", "+data.cache=false", f"out={out}",
             "examples=3", *REFINE[refine]], out.with_suffix(".log"))  # fmt: skip
        rows.append(row(json.loads((out / "summary.json").read_text()), policy=policy,
                        model=os.path.relpath(ckpt, REPO_ROOT), placement="real frames", refine=refine))
    return rows


def score_real_frames(run_dir: Path) -> int:
    """The three real frames scored once by the trained recipe as it stands (the checkpoint's ROI policy and
    clip planes), as decoded and with the search: ``results/real_ipd/cell.md`` and ``cell.csv``; the one
    command's model (``run_dir`` named ``cell``): ``results/real_ipd/cell_one_command.md`` and its CSV."""
    if run_dir.name in CELL_FILE_ARMS:
        return score_real_frames_cell_file(run_dir)
    one_command = run_dir.name == CELL_ARM
    ckpt = best_checkpoint(run_dir)
    if ckpt is None:
        print(f"error: {run_dir}: no checkpoint; train first (--stage {'cell' if one_command else 'train'})",
              file=sys.stderr)  # fmt: skip
        return 2
    # the model scored is the model shipped
    shipped = CELL_MODEL if one_command else REPO_ROOT / "models" / "cell_ipd_plate.ckpt"
    policy = f"auto:{roi_side():g}" if one_command else str(ARMS[run_dir.name]["roi"])
    if not shipped.is_file() or shipped.read_bytes() != ckpt.read_bytes():
        import shutil

        shutil.copyfile(ckpt, shipped)
    ckpt = shipped
    rows = score_real(ckpt, run_dir, CLIP, policy, [r for r in REFINE if run_dir.name in REFINE_OF.get(r, (run_dir.name,))])
    recorded = CELL_REFINE if one_command else RECIPE_REFINE
    stages = (json.loads((run_dir / "eval_real" / recorded / "summary.json").read_text()).get("icp") or {}) \
        .get("ms_per_image_by_stage", {})  # fmt: skip
    head = ["# The real frames, scored by the cell recipe", "",
            f"`python scripts/experiments/cells/cells.py --stage real --real-arm {run_dir.name}` (every setting fixed on "
            "generated piles before this ran: results/cells/README.md). The three Photoneo frames of IPD object 18, "
            "official `visib_fract`, the whole frame given: the ROI is the checkpoint's "
            f"(`{policy}`), the clip planes too. The recipe's refinement is `{RECIPE_REFINE}`, "
            "the most accurate on the cell study's generated validation piles within the speed target "
            "(results/verification/speed.md); the `search` row is for comparison, not the recipe. The frames were "
            "scored three times: twice with `search` (its earlier speed settings: [cell_first_scoring.md]"
            "(cell_first_scoring.md); its present ones, before `search_fast` existed: [cell_second_scoring.md]"
            "(cell_second_scoring.md)), then here, after the refinement was made faster; no setting was chosen on "
            "these frames.", ""]  # fmt: skip
    notes = ["", f"`{recorded}`'s milliseconds per frame by stage: " + ", ".join(f"{k} {v:.0f}" for k, v in stages.items())
             + " (scene: the depth as points; icp: ICP of every hypothesis; search: the turn search of all of them; "
             "polish: ICP of the searched poses; rank: agreement and duplicates; a stage's time is its slowest "
             "thread's)."] if stages else []  # fmt: skip
    stem = "cell_one_command" if one_command else "cell"
    if one_command:
        head = ["# The real frames, scored by the one command's model", "",
                f"`python scripts/experiments/cells/cells.py --stage real --real-arm {CELL_ARM}`: `models/real_ipd_plate.ckpt`, "
                "made by `python scripts/experiments/cells/cells.py --stage cell`, the one command for the cell (`python train.py "
                "experiment=cell` with the camera's own file, its pose, the working volume and area, the basket and its "
                "three perforations as bin models; results/cells/README.md), nothing changed after it ran. The three "
                "Photoneo frames of IPD object 18, official `visib_fract`, the whole frame given: the ROI, the clip "
                f"planes and the refinement (`{CELL_REFINE}`, which eval.py runs by default) are the checkpoint's. "
                "The model is the flat part's recipe (the grid sized to the plate, 6000 steps, threshold 0.05, "
                "`search_flat`: results/flat_parts); the one it replaced (grid 16, 3000 steps, `search_fast`) scored "
                "these frames before it ([cell_one_command_grid16.md](cell_one_command_grid16.md)). No setting was "
                "chosen on them.", ""]  # fmt: skip
    write_table(REPO_ROOT / "results" / "real_ipd" / f"{stem}.csv", rows, head,
                ("refine", "scenes", "required", "ap", "found", "t_err_mm_p50", "r_err_deg_p50", "ms_per_frame"))
    with (REPO_ROOT / "results" / "real_ipd" / f"{stem}.md").open("a") as f:
        f.write("\n".join(notes) + ("\n" if notes else ""))
    return 0


def score_real_frames_cell_file(run_dir: Path) -> int:
    """The three real frames scored once by the model trained from opnet-cell's file (``--stage cell --cell-file
    ipd``), as it stands: its ROI policy, the clip planes the cell file measured, each refinement of
    :data:`REFINE` (``search_flat``: the one it records); ``results/real_ipd/<arm>.md`` and its CSV."""
    name = CELL_FILE_ARMS[run_dir.name]
    clip = cell_file_clip(name)
    ckpt = best_checkpoint(run_dir)
    if ckpt is None:
        print(f"error: {run_dir}: no checkpoint; train first (--stage cell --cell-file ipd)", file=sys.stderr)
        return 2
    rows = score_real(ckpt, run_dir, clip, arm_policy(run_dir.name), list(REFINE))
    head = ["# The real frames, scored by the model set up from the cell's own frames", "",
            f"`python scripts/experiments/cells/cells.py --stage real --real-arm {run_dir.name}`: the model of "
            f"`python scripts/experiments/cells/cells.py --stage cell --cell-file {name} --steps 3000` (`python train.py "
            f"experiment=cell cell={name} object=ipd_plate`: every measured key from `conf/cell/{name}.yaml`, which opnet-cell "
            "wrote from these frames' depth, no ground truth; given only the basket's three perforations and the "
            "budget), nothing changed after it ran. The three Photoneo frames of IPD object 18, official "
            "`visib_fract`, the whole frame given; `search_flat` is the refinement the checkpoint records. Scored "
            "once; no setting was chosen on them.", ""]  # fmt: skip
    write_table(REPO_ROOT / "results" / "real_ipd" / f"{run_dir.name}.csv", rows, head,
                ("refine", "scenes", "required", "ap", "found", "t_err_mm_p50", "r_err_deg_p50", "ms_per_frame"))
    return 0


#: the recipe's settings and the evidence that chose each (results/cells/README.md)
SETTINGS = [
    "- the cell: camera intrinsics (the frames' camera file), its pose over the floor (height 1.775 m, tilt 19.9 deg, "
    "azimuth -30.3 deg: `python -m opnet.synthesis.camera_pose` on the frames' ground truth, as a user would take it "
    "from a calibration), the basket's sizes and the working volume 1.55-2.05 m (from the frames' depth): geometry "
    "a user measures, no score involved;",
    "- where the basket may stand (`scene.bin_area` +-0.2 m, any yaw): the floor the camera sees with the basket "
    "whole in the image (the area's corners are checked to be in view);",
    f"- the network's input (`data.roi=auto:{roi_side():g}`): 1.1 x the basket's outer diagonal (any yaw, the "
    "finder's error to spare); the policy as built for a basket that moves, the generated table above showing what "
    "it holds where the basket moved, beside a fixed box and the whole frame at 128 and 256 pixels (the whole frame "
    "at 128 leaves a plate a few network pixels wide and finds almost nothing; at 256 it comes near the crop at 128, "
    "one seed against three, for four times the network's work per frame and twice its training time): the crop "
    "at 128 stays;",
    "- three perforations, 8 foreign pieces, the wire basket 0.6 m above the ground: generated-pile AP of the "
    "earlier recipe's arms (results/real_ipd/ab.md: foreign pieces 0.098 -> 0.242, three perforations "
    "0.242 -> 0.320); EVE, the small preset, 3000 steps: that recipe's. The depth channel weighted 10x "
    "(`loss.lambda_z=10`, the dense recipe's) at the same 3000 steps, seed and piles (`auto_lz10`): 0.442 trained / "
    "0.425 moved with `search_fast` against the recipe's 0.468 / 0.455 (seed 0; 0.481 / 0.445 over three seeds): "
    "not taken. (The earlier recipe's arm with it and 6000 steps, 0.388 on its generated piles, doubles the budget "
    "and was not tried here.);",
    "- the sensor model (`sensor=photoneo`): made earlier to match the frames' missing-depth statistics, the one "
    "setting no generated data can choose; its pixel settings halved with the training piles' resolution;",
    "- the refinement (`refine=search_fast +decoding.averaging=false`): the search (ICP, the depth-agreement "
    "search, ICP again, ranked by agreement) by generated piles (results/real_ipd/search_ab.md, 240 held-out "
    "scenes; results/verification/README.md), and of its variants the most accurate within the speed target, 300 "
    "ms per frame on this 2-core CPU, on the cell study's validation piles (`val_c6`: the basket anywhere in the "
    "working area, a seed of their own; results/verification/speed.md: `search` 0.519 AP at 573 ms per frame, "
    "`search_fast` 0.496 at 290 ms). Its speed settings before that (every 4th depth pixel for ICP, ICP to a "
    "hundredth of a degree and millimetre, merge 0.1, the local fine stage) were chosen on generated plate piles "
    "too (results/verification/README.md). The real frames were scored with `search` twice before "
    "(results/real_ipd/cell_first_scoring.md, cell_second_scoring.md): with earlier speed settings, then with "
    "today's before `search_fast` existed.",
]


#: the arms: the network's input policy (``data.roi``; None: the whole frame, which here is the working
#: area), its input size and training seed
ARMS = {
    "auto": {"roi": f"auto:{roi_side():g}", "input": 128, "seed": 0},
    "auto_s1": {"roi": f"auto:{roi_side():g}", "input": 128, "seed": 1},
    "auto_s2": {"roi": f"auto:{roi_side():g}", "input": 128, "seed": 2},
    "frame128": {"roi": None, "input": 128, "seed": 0},
    "frame256": {"roi": None, "input": 256, "seed": 0},
    # the depth channel weighted 10x in the position loss (the dense recipe's loss.lambda_z), the same budget
    "auto_lz10": {"roi": f"auto:{roi_side():g}", "input": 128, "seed": 0, "extra": ["loss.lambda_z=10"]},
}
OLD_ARM = "fixed_box"
#: the one command's run (``--stage cell``)
CELL_ARM = "cell"
#: the one command with every measured key from the cell file opnet-cell wrote from the frames' depth
#: (``--stage cell --cell-file ipd``: ``cell=ipd``, no ground truth; its run and model apart from the above):
#: run name -> cell name
CELL_FILE_ARMS = {"cell_ipd": "ipd", "cell_ipd_area": "ipd_area"}
#: the refinements a model is scored with: search_flat only where the model records it (a flat part's recipe)
REFINE_OF = {"search_flat": (CELL_ARM, *CELL_FILE_ARMS)}
#: the refinement the one command's model records (experiment=cell, a flat part: search_flat)
CELL_REFINE = "search_flat"
#: the shipped one-command model's name in the tables; the model it replaced keeps its rows under its own
CELL_MODEL_LABEL = "models/real_ipd_plate.ckpt (experiment=cell, the flat part's recipe, seed 0)"


def cell_file_clip(name: str) -> tuple[float, float]:
    """The working volume ``conf/cell/<name>.yaml`` measured: the planes its model trained within (the real
    frames are read within them)."""
    import yaml

    near, far = yaml.safe_load((REPO_ROOT / "conf" / "cell" / f"{name}.yaml").read_text())["scene"]["clip"]
    return float(near), float(far)


def piles_of(arm: str) -> dict[str, tuple[float, float]]:
    """The test piles ``arm`` is scored on: {folder suffix: the planes they are written within}. Every model on
    the study's (written within CLIP); a cell-file model also on the same piles written within its cell file's
    planes, as the cell's frames reach it at prediction (the depth beyond the far plane at the far plane)."""
    if arm not in CELL_FILE_ARMS:
        return {"": CLIP}
    return {"": CLIP, "_own_planes": cell_file_clip(CELL_FILE_ARMS[arm])}


def arm_policy(arm: str) -> str:
    if arm == OLD_ARM:
        return f"fixed box {list(OLD_ROI)}"
    if arm == CELL_ARM:  # apart from the seeds of the study's own training (the table over seeds)
        return f"auto:{roi_side():g}, one command"
    if arm in CELL_FILE_ARMS:
        return f"auto:{roi_side():g}, one command, cell={CELL_FILE_ARMS[arm]} (opnet-cell)"
    roi = ARMS[arm]["roi"]
    return roi if roi else "working area (whole frame)"


def perforations() -> str:
    """The basket's three perforations as the bin models of one dataset (the override)."""
    models = ",".join(f"{{bin_hole_size:{size},bin_hole_pitch:{pitch}}}" for size, pitch in HOLES)
    return f"scene.bin_models=[{models}]"


def _steps(steps: int | None) -> list[str]:
    """The training steps when given; None: the recipe's own (experiment=cell trains a flat part twice as long)."""
    return [] if steps is None else [f"trainer.max_steps={steps}"]


def cell_overrides(cycles: int, views: int, scale: float, steps: int | None) -> list[str]:
    """``python train.py experiment=cell`` for this cell as a user gives it: the camera's own file, its pose,
    the working volume and area, the basket's sizes and its three perforations as bin models, the ROI policy;
    the rest is the experiment's (its recorded refinement included)."""
    basket = ("bin_inner", "bin_inner_y", "bin_wall_height", "bin_wall_thickness", "bin_clearance")
    return ["experiment=cell", "object=ipd_plate", "sensor=photoneo", f"scene.camera_file={FRAMES / 'camera_photoneo.yaml'}",
            f"scene.camera_scale={scale:g}", f"scene.clip=[{CLIP[0]},{CLIP[1]}]",
            *(f"scene.{k}={v}" for k, v in CAMERA_POSE.items()), f"scene.bin_area=[{','.join(map(str, AREA))}]",
            *(f"scene.{k}={BASKET[k]}" for k in basket), perforations(), f"data.roi=auto:{roi_side():g}",
            f"data.generate.cycles={cycles}", f"scene.views={views}", *_steps(steps),
            "trainer.enable_progress_bar=false"]  # fmt: skip


def cell_file_overrides(name: str, cycles: int, views: int, scale: float, steps: int | None) -> list[str]:
    """``python train.py experiment=cell cell=<name>`` as a user runs it after ``opnet-cell``: every measured key
    (the camera and its pose, the working volume and area, the basket's sizes, the crop side, the sensor preset)
    from the cell file; given as in :func:`cell_overrides` only what a depth frame does not show (the basket's
    three perforations) and the budget (cycles, views, the rendering scale, the steps)."""
    return ["experiment=cell", f"cell={name}", "object=ipd_plate", f"scene.camera_scale={scale:g}", perforations(),
            f"data.generate.cycles={cycles}", f"scene.views={views}",
            *_steps(steps), "trainer.enable_progress_bar=false"]  # fmt: skip


def train_cell(runs: Path, cycles: int, views: int, scale: float, steps: int | None, cell_file: str | None = None) -> Path:
    """The one command for the cell (generates its piles, trains, records the ROI policy, clip planes and
    refinement in the checkpoint), its best checkpoint shipped as ``models/real_ipd_plate.ckpt``."""
    import shutil

    run_dir = runs / (f"cell_{cell_file}" if cell_file else CELL_ARM)
    last = run_dir / "checkpoints" / "last.ckpt"  # a run stopped part-way resumes where it stopped
    resume = [f"ckpt_path={last}"] if last.is_file() else []
    overrides = cell_file_overrides(cell_file, cycles, views, scale, steps) if cell_file else \
        cell_overrides(cycles, views, scale, steps)  # fmt: skip
    run(train_command([*overrides, "test=false", *resume], run_dir), run_dir / "console.log")
    ckpt = best_checkpoint(run_dir)
    if ckpt is None:
        raise SystemExit(f"error: {run_dir}: train.py wrote no checkpoint (see {run_dir / 'console.log'})")
    if cell_file:
        return ckpt
    shutil.copyfile(ckpt, CELL_MODEL)
    return CELL_MODEL


#: the study's arms' training steps (the earlier recipe's)
ARM_STEPS = 3000

#: --stage budget: the one command's recipe at these multiples of its steps, each scored on the same test piles
BUDGET_MULTIPLES = (1, 2, 4)
#: the one command's steps for the plate (experiment=cell's flat_part.max_steps)
RECIPE_STEPS = 6000
#: the refinements a budget's model is scored with: as decoded, and the one the recipe records
BUDGET_REFINES = ("none", CELL_REFINE)


def learning_curve(run: Path) -> list[dict[str, str]]:
    """The rows of a train.py run's ``learning_curve.csv`` (step, train_minutes, val_ap, ...); none before its
    first validation."""
    curve = run / "learning_curve.csv"
    if not curve.is_file():
        return []
    with curve.open() as f:
        return list(csv.DictReader(f))


def budget_dir(runs: Path, multiple: int) -> Path:
    return runs / "budget" / f"x{multiple}"


def train_budget(runs: Path, multiples: list[int], jobs: int, cycles: int, views: int, scale: float,
                 extra: list[str], val_every: int = 1) -> list[int]:  # fmt: skip
    """The one command at ``m`` x its steps for each ``m`` (its learning-rate schedule spanning them), ``jobs``
    at once (several share one GPU well), each validated every ``val_every`` x ``m`` epochs (as many validations
    each) into ``budget/x<m>/``, a run stopped part-way resuming from its last checkpoint; ``extra``: overrides
    after the recipe's (``trainer=gpu``, the loader's workers, an existing dataset). Returns the multiples whose
    training failed."""
    from concurrent.futures import ThreadPoolExecutor
    import subprocess

    threads = max(1, (os.cpu_count() or 1) // jobs)
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)} if jobs > 1 else None

    def one(m: int) -> int | None:
        out = budget_dir(runs, m)
        out.mkdir(parents=True, exist_ok=True)
        last = out / "checkpoints" / "last.ckpt"
        cmd = train_command([*cell_overrides(cycles, views, scale, RECIPE_STEPS * m),
                             f"trainer.check_val_every_n_epoch={val_every * m}", "test=false", *extra,
                             *([f"ckpt_path={last}"] if last.is_file() else [])], out)
        started = time.perf_counter()
        with (out / "console.log").open("w") as log:
            code = subprocess.run(cmd, cwd=REPO_ROOT, stdout=log, stderr=subprocess.STDOUT, env=env, check=False).returncode
        state = "done" if code == 0 else f"FAILED (exit {code}, see {out / 'console.log'})"
        print(f"x{m}: {state} in {time.perf_counter() - started:.0f} s", flush=True)
        return m if code else None

    with ThreadPoolExecutor(max(1, jobs)) as pool:
        return [m for m in pool.map(one, multiples) if m is not None]


BUDGET_FIELDS = ("multiple", "steps", "steps_done", "placement", "refine", "scenes", "ap", "found", "t_err_mm_p50",
                 "r_err_deg_p50", "ms_per_frame", "best_val_ap", "best_step", "train_minutes")


def collect_budget(files: Path, runs: Path) -> list[Path]:
    """Put what a GPU call brought back (scripts/dev/gpu_check.sh, step budget: ``budget.tar.gz`` and each
    budget's best checkpoint as ``budget_x<m>_<its name>``) where :func:`budget_report` reads them; returns the
    checkpoints placed."""
    import re
    import shutil
    import tarfile

    archive = files / "budget.tar.gz"
    if not archive.is_file():
        raise SystemExit(f"error: {archive}: no such file (the budget step's runs)")
    with tarfile.open(archive) as tar:
        tar.extractall(runs, filter="data")
    placed = []
    for ckpt in sorted(files.glob("budget_x*_*.ckpt")):
        m, name = re.fullmatch(r"budget_x(\d+)_(.+\.ckpt)", ckpt.name).groups()
        dest = budget_dir(runs, int(m)) / "checkpoints" / name
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(ckpt, dest)
        placed.append(dest)
    return placed


def budget_report(runs: Path, data_dir: Path, cycles: int, test_cycles: int, out: Path, where: str) -> int:
    """Score each budget's best checkpoint on the study's test piles (as decoded and with the recorded search)
    and write ``budget.csv``, ``budget_curve.csv`` (every validation of every budget) and ``budget.md``."""
    _, tests = datasets(data_dir, cycles, test_cycles)
    rows, curve = [], []
    for m in sorted(int(d.name[1:]) for d in (runs / "budget").glob("x*") if d.name[1:].isdigit()):
        run_dir = budget_dir(runs, m)
        ckpt = best_checkpoint(run_dir)
        points = learning_curve(run_dir)
        if ckpt is None or not points:
            print(f"x{m}: no checkpoint or learning curve in {run_dir}: skipped", flush=True)
            continue
        best = max(points, key=lambda p: float(p["val_ap"] or 0))
        curve += [{"multiple": m, "step": p["step"], "train_minutes": p["train_minutes"], "val_ap": p["val_ap"]} for p in points]
        for placement, sets in tests.items():
            for refine in BUDGET_REFINES:
                folder = runs / "eval_generated" / f"budget_x{m}_{placement}_{refine}"
                summary = json.loads((folder / "summary.json").read_text()) if (folder / "summary.json").is_file() else \
                    evaluate(ckpt, [r for r, _ in sets], folder, REFINE[refine])  # fmt: skip
                r = row(summary, placement=placement, refine=refine)
                rows.append({**{k: r[k] for k in BUDGET_FIELDS if k in r}, "multiple": m, "steps": RECIPE_STEPS * m,
                             "steps_done": points[-1]["step"], "best_val_ap": round(float(best["val_ap"]), 4),
                             "best_step": best["step"], "train_minutes": points[-1]["train_minutes"]})
    if not rows:
        print(f"error: {runs / 'budget'}: no budget trained there", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    for name, table, fields in (("budget.csv", rows, BUDGET_FIELDS), ("budget_curve.csv", curve, ("multiple", "step", "train_minutes", "val_ap"))):
        with (out / name).open("w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=fields)
            w.writeheader()
            w.writerows(table)
    write_budget_page(rows, curve, out / "budget.md", where)
    return 0


#: what the budget page says of how its figures were made (the lent GPU's run, the cadence, the carried piles)
BUDGET_NOTES = [
    "Trained at once on a lent NVIDIA H200 with 16 cores, within the 15 minutes of device time a task is lent "
    "(`scripts/dev/gpu_check.sh`, step `budget`; the piles travelled as their scene cache, "
    "`scripts/dev/carry_dataset.py pack-cache`, 36 MiB). Each trained about 20 steps/s (one budget alone, with 15 "
    "loader workers, 26 steps/s: three at once spend a short lease better). So 2 x and 4 x stopped at the 7.5-minute limit "
    "(`trainer.max_time`) at step 8800, their learning rate still above its schedule's end: their rows are the budget "
    "spent by then, not the budget's end.",
    "1 x on the GPU reproduces the shipped model, trained on this CPU by the same command, seed and piles: where the "
    "basket moved 0.387 as decoded and 0.652 refined, against 0.389 and 0.660 (results/cells/README.md).",
    "Validated every 2 m epochs (about 200 m steps), so each budget validates as often; one seed each.",
    "What it says: the recipe's 6000 steps leave the plate short of what it learns. At 8800 steps, with the rate still "
    "high, 2 x and 4 x lift it where the basket moved from 0.387 to 0.449 and 0.447 as decoded (the recipe's spread "
    "over 3 seeds: ± 0.014, results/flat_parts) and from 0.652 to 0.669 refined. The recipe keeps 6000 steps: 12,000 "
    "take about 50 minutes on 2 cores, and a full 2 x or 4 x run over 3 seeds needs a longer lease than this one.",
]


def write_budget_page(rows: list[dict[str, Any]], curve: list[dict[str, Any]], path: Path, where: str) -> None:
    cols = sorted({(r["placement"], r["refine"]) for r in rows})
    by = {(r["multiple"], r["placement"], r["refine"]): r for r in rows}
    lines = ["# The cell's one command at several times its training budget", "",
             "Made by `python scripts/experiments/cells/cells.py --stage budget` (" + where + ") and `--stage "
             "budget-report --collect <what the call brought back>` (scoring here). `experiment=cell`'s recipe for the plate (`models/real_ipd_plate.ckpt`'s) at "
             "1, 2 and 4 times its 6000 steps, the schedule spanning them, seed 0; each budget's best checkpoint on "
             f"validation, scored on the study's test piles as decoded and with its recorded `{CELL_REFINE}`.", "",
             "| budget | steps | best val AP (step) | " + " | ".join(f"{p} {'as decoded' if f == 'none' else f}" for p, f in cols)
             + " |", "|---|---|---|" + "---|" * len(cols)]
    for m in sorted({r["multiple"] for r in rows}):
        first = next(r for r in rows if r["multiple"] == m)
        lines.append(f"| {m} x | {first['steps_done']} of {first['steps']} | {float(first['best_val_ap']):.3f} "
                     f"({first['best_step']}) | " + " | ".join(f"**{float(by[(m, p, f)]['ap']):.3f}**"
                                                          if (m, p, f) in by else "" for p, f in cols) + " |")
    multiples = sorted({int(c["multiple"]) for c in curve})
    vals = {(int(c["multiple"]), int(c["step"])): float(c["val_ap"]) for c in curve if c["val_ap"]}
    # the rows: the validations of the budget validated least often, each budget's latest validation up to then
    marks = sorted({s for (m, s) in vals if m == multiples[-1]})
    lines += ["", "Validation AP during training (`budget_curve.csv` holds every validation):", "",
              "| step | " + " | ".join(f"{m} x" for m in multiples) + " |", "|---|" + "---|" * len(multiples)]
    for mark in marks:
        cells = []
        for m in multiples:
            done = [s for (k, s) in vals if k == m and s <= mark]
            cells.append(f"{vals[(m, max(done))]:.3f}" if done and mark - max(done) < 400 * m else "")
        lines.append(f"| {mark} | " + " | ".join(cells) + " |")
    lines += ["", *(f"- {note}" for note in BUDGET_NOTES)]
    path.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def train_arm(arm: str, train_sets: list, runs: Path, steps: int) -> None:
    a = ARMS[arm]
    roots = "[" + ",".join(str(r) for r, *_ in train_sets) + "]"
    run(train_command(["object=ipd_plate", "data=ipa", f"data.root={roots}", "data.generate=null",
                       f"data.roi={a['roi'] or 'null'}", f"data.input_size={a['input']}", f"model.in_size={a['input']}",
                       f"parameterization.grid={16 * a['input'] // 128}", f"seed={a['seed']}", "parameterization=eve",
                       "augmentation.p_rotate=0.5", "test=false", f"trainer.max_steps={steps}",
                       "trainer.max_epochs=100000", "trainer.enable_progress_bar=false", *a.get("extra", [])],
                      runs / arm),
        runs / arm / "console.log")  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--stage", choices=("all", "generate", "train", "cell", "eval", "report", "real", "budget",
                                        "budget-report"), default="all",
                    help="cell: the one command (train.py experiment=cell) -> models/real_ipd_plate.ckpt; "
                         "real: score the real frames once with --real-arm (results/real_ipd/cell.md); budget: the "
                         "one command at --multiples of its steps (--jobs at once, --extra overrides), budget-report: "
                         "each scored on the test piles -> results/cells/budget.md")
    ap.add_argument("--multiples", nargs="+", type=int, default=list(BUDGET_MULTIPLES))
    ap.add_argument("--jobs", type=int, default=1, help="--stage budget: trainings at once")
    ap.add_argument("--val-every", type=int, default=1, help="--stage budget: validate every this x m epochs")
    ap.add_argument("--extra", nargs="*", default=[], help="--stage budget: train.py overrides after the recipe's")
    ap.add_argument("--where", default="here", help="--stage budget-report: where the budgets trained (the page says)")
    ap.add_argument("--collect", type=Path, default=None,
                    help="--stage budget-report: first place the files a GPU call brought back (gpu_check.sh's budget step)")
    ap.add_argument("--arms", nargs="+", default=list(ARMS), choices=list(ARMS))
    ap.add_argument("--real-arm", default="auto", choices=[*ARMS, CELL_ARM, *CELL_FILE_ARMS])
    ap.add_argument("--cell-file", default=None, help="--stage cell: train with cell=<this> (opnet-cell's file) "
                                                      "into cell_<this>/ instead of the keys given here", choices=list(CELL_FILE_ARMS.values()))
    ap.add_argument("--cycles", type=int, default=200)
    ap.add_argument("--views", type=int, default=2)
    ap.add_argument("--test-cycles", type=int, default=12)
    ap.add_argument("--val-cycles", type=int, default=6, help="validation piles (the refinement's settings)")
    ap.add_argument("--rescore", action="store_true", help="--stage eval: score again what was scored before")
    ap.add_argument("--refine", nargs="+", default=list(REFINE), choices=list(REFINE),
                    help="--stage cell / eval: the refinements to score with (default: all)")
    ap.add_argument("--steps", type=int, default=None,
                    help=f"training steps (default: the study's arms {ARM_STEPS}; --stage cell: the recipe's own)")
    ap.add_argument("--scale", type=float, default=0.5, help="the training piles' resolution, x the camera's")
    ap.add_argument("--data-dir", type=Path, default=REPO_ROOT / "outputs" / "data" / "cells")
    ap.add_argument("--runs", type=Path, default=REPO_ROOT / "outputs" / "cells")
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "cells")
    args = ap.parse_args(argv)
    if not (FRAMES / "camera_photoneo.yaml").is_file():
        print(f"error: {FRAMES}: the cell's camera is not there (../shared, or OPNET_SHARED)", file=sys.stderr)
        return 2
    logs = args.runs / "logs"
    if args.stage == "budget":
        if min(args.jobs, args.val_every, *args.multiples) < 1:
            print(f"error: --jobs {args.jobs} --val-every {args.val_every} --multiples {args.multiples}: expected "
                  "whole numbers >= 1", file=sys.stderr)
            return 2
        failed = train_budget(args.runs, args.multiples, args.jobs, args.cycles, args.views, args.scale, args.extra,
                              args.val_every)
        return 1 if failed else 0
    if args.stage == "budget-report":
        if args.collect is not None:
            print(f"{len(collect_budget(args.collect, args.runs))} checkpoint(s) placed under {args.runs / 'budget'}")
        return budget_report(args.runs, args.data_dir, args.cycles, args.test_cycles, args.out, args.where)
    train_sets, tests = datasets(args.data_dir, args.cycles, args.test_cycles)
    if args.stage == "real":
        return score_real_frames(args.runs / args.real_arm)
    if args.stage in ("all", "generate"):
        started = time.perf_counter()
        half = camera_file(args.scale, args.data_dir / f"camera_x{args.scale:g}.yaml")
        full = camera_file(1.0, args.data_dir / "camera_x1.yaml")
        for root, cycles, scene in train_sets:
            scene = dict(scene)
            generate(half, root, cycles, args.views, scene.pop("seed"), args.scale, logs, **scene)
        generate_tests(args.data_dir, tests, CLIP, logs)
        root, scene = validation_set(args.data_dir, args.val_cycles)
        scene = dict(scene)
        generate(full, root, scene.pop("cycles"), 1, VALIDATION_SEED, 1.0, logs, **scene)
        print(f"generated in {(time.perf_counter() - started) / 60:.1f} min", flush=True)
    if args.stage in ("all", "train"):
        for arm in args.arms:
            train_arm(arm, train_sets, args.runs, args.steps or ARM_STEPS)
    if args.stage in ("all", "cell"):
        train_cell(args.runs, args.cycles, args.views, args.scale, args.steps, args.cell_file)
    if args.stage in ("all", "cell", "eval"):
        cell_arm = f"cell_{args.cell_file}" if args.cell_file else CELL_ARM
        arms = [cell_arm] if args.stage == "cell" else [*args.arms, OLD_ARM, CELL_ARM, *CELL_FILE_ARMS]
        made: set[tuple[float, float]] = {CLIP} if args.stage == "all" else set()  # test piles made this run
        for arm in arms:
            ckpt = {OLD_ARM: OLD_MODEL, CELL_ARM: CELL_MODEL}.get(arm) or best_checkpoint(args.runs / arm)
            if ckpt is None or not ckpt.is_file():
                continue  # not trained
            extra = [f"+data.roi=[{','.join(map(str, OLD_ROI))}]"] if arm == OLD_ARM else []
            for suffix, clip in piles_of(arm).items():
                arm_tests = datasets(args.data_dir, args.cycles, args.test_cycles, clip)[1]
                if clip not in made:  # the piles made where missing (complete cycles are kept), once a run
                    generate_tests(args.data_dir, arm_tests, clip, logs)
                    made.add(clip)
                for placement, sets in arm_tests.items():
                    for refine, overrides in REFINE.items():
                        if arm not in REFINE_OF.get(refine, (arm,)) or refine not in args.refine:
                            continue
                        folder = args.runs / "eval_generated" / f"{arm}_{placement}_{refine}{suffix}"
                        if (arm == OLD_ARM or not args.rescore) and (folder / "summary.json").is_file():
                            continue  # scored before (the shipped model: once)
                        evaluate(ckpt, [r for r, _ in sets], folder, [*extra, *overrides], clip)
    rows = []
    # a row whose evaluation is not on this machine (scored in another session) is kept as the page has it
    published = args.out / "cells.csv"
    kept = {(r["model"], r["placement"], r["refine"]): r
            for r in (csv.DictReader(published.open()) if published.is_file() else [])}  # fmt: skip
    whole = {placement: frame_required([r for r, _ in sets]) for placement, sets in tests.items()}
    for arm, (suffix, clip) in ((a, p) for a in [OLD_ARM, *ARMS, CELL_ARM, *CELL_FILE_ARMS] for p in piles_of(a).items()):
        for placement in tests:
            for refine in REFINE:
                summary = args.runs / "eval_generated" / f"{arm}_{placement}_{refine}{suffix}" / "summary.json"
                model = {OLD_ARM: "models/fixed_box_ipd_plate.ckpt",
                         CELL_ARM: CELL_MODEL_LABEL,
                         **{a: f"{a} (experiment=cell cell={n}, seed 0)" for a, n in CELL_FILE_ARMS.items()}}.get(arm) or \
                    f"{arm} (input {ARMS[arm]['input']}, seed {ARMS[arm]['seed']})"
                model += f", piles within its planes {clip[0]:g}-{clip[1]:g} m" if suffix else ""
                if summary.is_file():
                    rows.append(row(json.loads(summary.read_text()), policy=arm_policy(arm), model=model,
                                    placement=placement, refine=refine))
                    rows[-1]["found_of_all"] = round(rows[-1]["matched"] / max(whole[placement], 1), 4)
                elif (model, placement, refine) in kept:
                    rows.append(kept[(model, placement, refine)])
    # a model no longer made here (the one command's before the flat part's recipe) keeps its published rows
    made_here = {(r["model"], r["placement"], r["refine"]) for r in rows}
    rows += [r for k, r in kept.items() if k not in made_here]
    notes = ["Models: trained on piles whose basket stands anywhere in the working area (" f"{args.cycles} cycles, "
             f"{args.views} views per pile, three perforations, rendered at {args.scale:g} x the camera's pixels; EVE, "
             f"small preset, {args.steps or ARM_STEPS} steps). `auto:S`: the network's input is a square of S m at the basket's "
             "depth centred on the basket found in each image (`data.roi`, opnet.data.bin_finder); `working area`: "
             "the whole frame (here the working area is most of it) at the input size given. "
             f"`models/fixed_box_ipd_plate.ckpt`: the earlier recipe's model (the basket within 4 cm of the aim point "
             f"in training) with its fixed box {list(OLD_ROI)}. `models/real_ipd_plate.ckpt`: the one command for "
             "the cell (`--stage cell`: `python train.py experiment=cell` with the camera's own file rendered at "
             f"`scene.camera_scale={args.scale:g}`, its pose, the working volume and area, the basket's sizes and its "
             "three perforations as `scene.bin_models` of one dataset, `data.roi=auto:S`; the flat part's recipe: the "
             "grid sized to the plate, 6000 steps, threshold 0.05; it records its refinement, `search_flat`, which "
             "eval.py runs by default). The model it replaced (`earlier models/real_ipd_plate.ckpt`: grid 16, 3000 "
             "steps, `search_fast` recorded) keeps its rows. `search`: `refine=search +decoding.averaging=false`; "
             "`search_fast` (the recipe's): `refine=search_fast +decoding.averaging=false`, the first ICP projective "
             "and ICP stopping sooner (docs/deployment.md). The `search` rows' ms/frame are from the refinement's "
             "code when they were scored (seed 0's fixed-box and whole-frame rows the oldest); `search_fast`'s from "
             "today's, which gives `search` the same poses in about half the time (results/verification/speed.md). "
             "`frame256`'s training stopped at 1700 of its 3000 steps when a session ended and was resumed from its "
             "last checkpoint (`ckpt_path=last`); its rows' ms/frame were measured while other jobs shared the CPU."]
    notes += ["Every setting of the recipe, and what chose it (no setting was chosen by a score on the real frames):", "",
              *SETTINGS]
    arms = sorted({r["model"].split(" ")[0] for r in rows} & set(ARMS))
    command = (f"`python scripts/experiments/cells/cells.py --stage generate`, then `--stage train --arms {' '.join(arms)}`, "
               f"`--stage cell` (the one command), `--stage cell --cell-file ipd --steps 3000` (the same set up by "
               f"opnet-cell) and `--stage eval --arms {' '.join(arms)}` (`--stage report` re-makes this page)")
    notes.append("`cell_ipd`, `cell_ipd_area`: the one command with every measured key from `conf/cell/ipd.yaml` "
                 "(opnet-cell on the frames' depth, no ground truth; the working area where the basket stood in them "
                 "plus 0.1 m) or `conf/cell/ipd_area.yaml` (the same with `--area=-0.2,-0.2,0.2,0.2`, the area above), "
                 "given only the perforations, at 3000 steps; the flat part's recipe otherwise (the grid sized to the "
                 "plate, threshold 0.05, `search_flat` recorded). They trained within the planes their cell file "
                 f"measured, while the study's test piles hold depth within {list(CLIP)} m (a surface beyond it at "
                 "2.05 m): their networks see that depth normalized otherwise than in training (eval.py warns). So "
                 "each is also scored on the same piles written within its own planes (`piles within its planes`), "
                 "as the cell's frames reach it. `cell_ipd` was trained with the earlier bin finder, which counted a "
                 "perforated basket by its bars alone: within a cell file's wider volume the ground under the stand, "
                 "reaching into it at the tilted camera's far side, outweighed the basket (75 % of `cell_ipd_area`'s "
                 "training frames before, 4 % after it counted the outline, none since a region wider than the crop, or a patch of floor beyond a region about as large, gives way); `cell_ipd_area` was re-made with the outline rule (crops `_f2`).")
    notes.insert(1, "`found % of the frame's parts`: matched parts over every part the metric requires in the whole "
                 "frames (visibility >= 0.5). A fixed box's own `required`, `found` and AP count only the parts "
                 "inside it (the crop scales each part's visibility by its share inside), so where the basket moved "
                 "out of the box they are not over the same parts as a crop that holds the whole basket.")
    report(rows, args.out, command, notes)
    return 0


if __name__ == "__main__":
    sys.exit(main())
