"""Fuzz every reader and command line with bad input; print the table of verdicts.

``python scripts/dev/fuzz_inputs.py [--out results/fuzz.md] [--no-cli] [--only FAMILY ...]``

Each case is a file (or argument) a careless or hostile user could hand us, derived from a valid
tiny dataset: truncated, garbled, impossible values, wrong units, special files; BOP copies of it,
meshes, camera YAMLs, its checkpoint edited and exported to ONNX (metadata edited), full disks (a
1 MB tmpfs, where this machine may mount one) and concurrent runs into one folder. Every case runs in
its own process with a time limit. The cases of each kind of defect (decoding overrides, booleans
read as numbers, ground-truth integrity, a split with nothing to find, two writers into one folder,
the checkpoint tools, generation settings, inputs foreign to the model, messages that mislead) are
in their own families, as are the newer surfaces: the object tool's paths and numbers, the console
tools' arguments, training's overrides and the bin finder's crop ``roi=auto:S`` (each entry run in a
forked child as its command runs, :func:`new_surface_cases`). ``--only FAMILY ...`` runs some
families while cases are added. Verdicts:

- ``error``: refused with a one-line error that names the file (or the option / key);
- ``ok``: a valid input, accepted (the controls: each family has one);
- ``TRACEBACK``: a raw traceback or an exception other than the readers' ValueError /
  FileNotFoundError (a bug);
- ``HANG``: no answer within the limit (a bug);
- ``SILENT``: an impossible value accepted without a word (a bug);
- ``VAGUE``: an error that does not name the file or key (a bug);
- ``EXIT``: a refusal with another exit status than the command documents (a bug);
- ``WRONG``: a valid input whose output does not say what it must (a bug: a split with nothing to
  find printed as a score);
- ``DIRTY``: the run left a temporary file behind, or concurrent runs lost outputs (a bug);
- ``skipped``: the machine cannot stage the case (no tmpfs for a full disk); the reason is printed.

Exit status 1 when any case is a bug.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import random
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402

from opnet.paths import REPO_ROOT

READER_TIMEOUT_S = 20.0
CLI_TIMEOUT_S = 120.0
USER_ERRORS = (ValueError, FileNotFoundError)


@dataclass
class Case:
    family: str
    name: str
    valid: bool  # a control: must be accepted
    run: Callable[[], Any] | None = None  # in-process reader call (run in a forked child)
    argv: list[str] | None = None  # a command line (run as a subprocess)
    names: tuple[str, ...] = ()  # what a clear error must mention (a file name, a key)
    concurrent: list[list[str]] | None = None  # command lines started together
    skip: str = ""  # why the case cannot run on this machine
    after: Callable[[], str] | None = None  # a check after the run: what it left or lost ("" = clean)
    status: int | None = None  # the exit status a refused command line must give (None: any but 0)
    says: str = ""  # what an accepted input's output must state (a reader's returned text, a command's output)
    timeout: float = READER_TIMEOUT_S  # an in-process case's time limit


# ---------------------------------------------------------------------------------------- fixtures


def garbage(size: int, tag: str) -> bytes:
    """``size`` random bytes, the same in every run (the table is deterministic): seeded by ``tag``."""
    return random.Random(f"fuzz garbage {tag}").randbytes(size)


def make_base(ws: Path) -> dict[str, Path]:
    """A valid tiny dataset, a checkpoint trained for 2 steps on it, and evaluation folders."""
    from opnet.objects import builtin_object
    from opnet.synthesis import SceneConfig, generate_dataset

    data = ws / "data"
    generate_dataset(builtin_object("zbracket"), data, cycles=4, drops=3, workers=1, seed=0,
                     scene=SceneConfig(resolution=96), progress=False, previews=0,
                     object_config={"name": "zbracket", "builtin": "zbracket"})  # fmt: skip
    run = ws / "run"
    from omegaconf import OmegaConf

    from opnet.cli.train import run as train_run
    from opnet.studies import compose_train

    cfg = compose_train([
        "model=tiny", "object=zbracket", f"data.root={data}", "data.generate=null", "data.batch_size=4",
        "data.val_fraction=0.25", "data.test_fraction=0.25", "trainer.max_epochs=1", "+trainer.limit_train_batches=2",
        "+trainer.limit_val_batches=1", "trainer.enable_progress_bar=false", "example_predictions=0"])  # fmt: skip
    OmegaConf.update(cfg, "paths.output_dir", str(run), force_add=True)
    train_run(cfg)  # train.py's own run, in this process: a second interpreter would add only its start-up
    return {"data": data, "ckpt": run / "checkpoints" / "last.ckpt", "gt": run / "test" / "gt",
            "results": run / "test" / "results"}


def mutated(ws: Path, name: str, source: Path | None, change: Callable[[bytes], bytes] | bytes | str) -> Path:
    """A copy of ``source`` (or nothing) with its bytes changed, at ``ws/cases/<name>/<source name>``."""
    folder = ws / "cases" / name
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / (source.name if source is not None else name)
    if callable(change):
        data = change(source.read_bytes() if source is not None else b"")
    else:
        data = change.encode() if isinstance(change, str) else change
    path.write_bytes(data)
    return path


def special(ws: Path, name: str, kind: str) -> Path:
    folder = ws / "cases" / name
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "dir":
        path.mkdir()
    elif kind == "missing":
        pass
    return path


def csv_with(base: Path, row_change: Callable[[list[str]], list[str]]) -> Callable[[bytes], bytes]:
    def change(data: bytes) -> bytes:
        lines = data.decode().splitlines()
        cells = lines[1].split(",")
        lines[1] = ",".join(row_change(cells))
        return ("\n".join(lines) + "\n").encode()

    return change


def json_with(change: Callable[[Any], Any]) -> Callable[[bytes], bytes]:
    return lambda data: json.dumps(change(json.loads(data))).encode()


def _set(obj: dict, key: str, value: Any) -> dict:
    obj[key] = value
    return obj


def _entry0(doc: list, key: str, value: Any) -> list:
    doc[0][key] = value
    return doc


# ------------------------------------------------------------------------------------------- cases


def reader_cases(ws: Path, base: dict[str, Path]) -> list[Case]:
    from opnet.datasets.ipa_csv import read_ipa_csv
    from opnet.datasets.ipa_params import read_parameters
    from opnet.datasets.png import read_png
    from opnet.datasets.sileane import read_camera_params
    from opnet.datasets.sileane_json import read_gt_json, read_results_json
    from opnet.objects.model import ObjectModel

    data = base["data"]
    csv = data / "gt" / "cycle_0000" / "002.csv"
    depth = data / "p_depth" / "cycle_0000" / "002_depth_uint16.png"
    seg = data / "p_segmentation" / "cycle_0000" / "002_segmentation.png"
    params = data / "parameter.json"
    poseutils = data / "poseutils.json"
    gt_json = next(base["gt"].glob("*.json"))
    res_json = next(base["results"].glob("*.json"))
    cases: list[Case] = []

    def add(family: str, name: str, valid: bool, fn: Callable[[Path], Any], path: Path) -> None:
        cases.append(Case(family, name, valid, run=lambda: fn(path), names=(path.name,)))

    # --- IPA ground-truth CSV
    rows = {
        "valid copy": (True, lambda d: d),
        "UTF-8 BOM": (True, lambda d: b"\xef\xbb\xbf" + d),
        "header only (no objects)": (True, lambda d: d.split(b"\n")[0] + b"\n"),
        "empty file": (False, b""),
        "binary garbage": (False, bytes(range(256)) * 4),
        "truncated mid-row": (False, lambda d: d[: len(d) // 2 + 7]),
        "wrong header": (False, lambda d: d.replace(b"id,class", b"ident,klass", 1)),
        "missing column": (False, csv_with(csv, lambda c: c[:-1])),
        "extra column": (False, csv_with(csv, lambda c: [*c, "1"])),
        "NaN translation": (False, csv_with(csv, lambda c: [*c[:2], "nan", *c[3:]])),
        "inf rotation": (False, csv_with(csv, lambda c: [*c[:5], "inf", *c[6:]])),
        "text value": (False, csv_with(csv, lambda c: [*c[:3], "abc", *c[4:]])),
        "rotation scaled by 3": (False, csv_with(csv, lambda c: [*c[:5], *(str(3 * float(v)) for v in c[5:14]), *c[14:]])),
        "reflection (z axis negated)": (False, csv_with(csv, lambda c: [*c[:11], *(str(-float(v)) for v in c[11:14]), *c[14:]])),
        "visibility -5": (False, csv_with(csv, lambda c: [*c[:14], "-5", c[15]])),
        "visibility 50": (False, csv_with(csv, lambda c: [*c[:15], "50"])),
        "translation 1e300": (False, csv_with(csv, lambda c: [*c[:4], "1e300", *c[5:]])),
        "translation in millimetres": (False, csv_with(csv, lambda c: [*c[:4], str(1000 * float(c[4])), *c[5:]])),
        "id 300 (beyond uint8)": (False, csv_with(csv, lambda c: ["300", *c[1:]])),
        "negative id": (False, csv_with(csv, lambda c: ["-1", *c[1:]])),
        "duplicate id": (False, lambda d: d + d.split(b"\n")[-2] + b"\n" if d.endswith(b"\n") else d),
    }
    for name, (valid, change) in rows.items():
        add("IPA CSV", name, valid, read_ipa_csv, mutated(ws, f"csv_{len(cases)}", csv, change))
    for kind in ("fifo", "dir", "missing"):
        add("IPA CSV", f"{kind} named .csv", False, read_ipa_csv, special(ws, f"csv_{kind}.csv", kind))
    add("IPA CSV", "/dev/zero", False, read_ipa_csv, Path("/dev/zero"))

    # --- parameter.json
    pj = {
        "valid copy": (True, lambda d: d),
        "not JSON": (False, b"{perspectiveAngle: 40"),
        "a list": (False, b"[1, 2]"),
        "missing clip_end": (False, json_with(lambda o: {k: v for k, v in o.items() if k != "clip_end"})),
        "clip planes in millimetres": (False, json_with(lambda o: _set(_set(o, "clip_start", 500.0), "clip_end", 1500.0))),
        "clip_end < clip_start": (False, json_with(lambda o: _set(o, "clip_end", o["clip_start"] / 2))),
        "pixel offset 100000": (False, json_with(lambda o: _set(o, "pixelOffset_X_KoSyTopLeft", 100000))),
        "resolution 10^6": (False, json_with(lambda o: _set(_set(o, "resolutionX", 10**6), "resolution_big", 10**6))),
        "perspectiveAngle 0": (False, json_with(lambda o: _set(o, "perspectiveAngle", 0))),
        "perspectiveAngle 'wide'": (False, json_with(lambda o: _set(o, "perspectiveAngle", "wide"))),
        "resolution 0": (False, json_with(lambda o: _set(o, "resolutionX", 0))),
        "resolution true": (False, json_with(lambda o: _set(o, "resolutionX", True))),
        "NaN angle": (False, lambda d: d.replace(b'"perspectiveAngle": ', b'"perspectiveAngle": NaN, "x": ', 1)),
        "deeply nested": (False, b"[" * 50000 + b"]" * 50000),
    }
    for name, (valid, change) in pj.items():
        add("parameter.json", name, valid, read_parameters, mutated(ws, f"params_{len(cases)}", params, change))
    add("parameter.json", "FIFO named parameter.json", False, read_parameters, special(ws, "pfifo", "fifo"))

    # --- depth / segmentation PNG
    import cv2

    def png_of(img: np.ndarray) -> bytes:
        return cv2.imencode(".png", img)[1].tobytes()

    pngs = {
        "valid depth": (True, depth, np.uint16, lambda d: d),
        "valid segmentation": (True, seg, np.uint8, lambda d: d),
        "truncated depth": (False, depth, np.uint16, lambda d: d[: len(d) // 2]),
        "header only": (False, depth, np.uint16, lambda d: d[:40]),
        "not a PNG (JPEG bytes)": (False, depth, np.uint16, lambda d: b"\xff\xd8\xff\xe0" + d[4:]),
        "8-bit depth": (False, depth, np.uint16, png_of(np.zeros((96, 96), np.uint8))),
        "RGB depth": (False, depth, np.uint16, png_of(np.zeros((96, 96, 3), np.uint8))),
        "16-bit segmentation": (False, seg, np.uint8, png_of(np.zeros((96, 96), np.uint16))),
        "empty file": (False, depth, np.uint16, b""),
        "garbage after signature": (False, depth, np.uint16, b"\x89PNG\r\n\x1a\n" + b"x" * 100),
    }
    for name, (valid, src, dtype, change) in pngs.items():
        path = mutated(ws, f"png_{len(cases)}", src, change)
        cases.append(Case("PNG", name, valid, run=lambda p=path, t=dtype: read_png(p, t), names=(path.name,)))
    fifo_png = special(ws, "fifo.png", "fifo")
    cases.append(Case("PNG", "FIFO named .png", False, run=lambda: read_png(fifo_png, np.uint16), names=(fifo_png.name,)))

    # --- Siléane ground truth and results JSON
    sj = {
        "valid ground truth": (True, gt_json, read_gt_json, lambda d: d),
        "empty list": (True, gt_json, read_gt_json, b"[]"),
        "segmentation_id 1e30": (False, gt_json, read_gt_json, json_with(lambda o: _entry0(o, "segmentation_id", 1e30))),
        "segmentation_id 2.5": (False, gt_json, read_gt_json, json_with(lambda o: _entry0(o, "segmentation_id", 2.5))),
        "occlusion 1.5": (False, gt_json, read_gt_json, json_with(lambda o: _entry0(o, "occlusion_rate", 1.5))),
        "occlusion -5": (False, gt_json, read_gt_json, json_with(lambda o: _entry0(o, "occlusion_rate", -5))),
        "t = 1e300": (False, gt_json, read_gt_json, json_with(lambda o: _entry0(o, "t", [0, 0, 1e300]))),
        "R scaled by 3": (False, gt_json, read_gt_json, json_with(lambda o: _entry0(o, "R", (3 * np.array(o[0]["R"])).tolist()))),
        "R a reflection": (False, gt_json, read_gt_json, json_with(lambda o: _entry0(o, "R", (np.array(o[0]["R"]) @ np.diag([1, 1, -1])).tolist()))),
        "R 2x3": (False, gt_json, read_gt_json, json_with(lambda o: _entry0(o, "R", o[0]["R"][:2]))),
        "R with NaN": (False, gt_json, read_gt_json, lambda d: d.replace(b"[[", b"[[NaN, ", 1)),
        "missing t": (False, gt_json, read_gt_json, json_with(lambda o: [{k: v for k, v in o[0].items() if k != "t"}])),
        "an object, not a list": (False, gt_json, read_gt_json, b'{"R": 1}'),
        "nested 100000 deep": (False, gt_json, read_gt_json, b"[" * 100000 + b"]" * 100000),
        "valid results": (True, res_json, read_results_json, lambda d: d),
        "score 'high'": (False, res_json, read_results_json, b'[{"R": [[1,0,0],[0,1,0],[0,0,1]], "t": [0,0,1], "score": "high"}]'),
        "score true": (False, res_json, read_results_json, b'[{"R": [[1,0,0],[0,1,0],[0,0,1]], "t": [0,0,1], "score": true}]'),
        "results not UTF-8": (False, res_json, read_results_json, b"\xff\xfe[\x00]\x00"),
    }
    for name, (valid, src, fn, change) in sj.items():
        add("Siléane JSON", name, valid, fn, mutated(ws, f"json_{len(cases)}", src, change))
    add("Siléane JSON", "/dev/zero", False, read_gt_json, Path("/dev/zero"))

    # --- Siléane camera_params.txt
    cam_text = ("width 96\nheight 96\nfu 100\nfv 100\ncu 47.5\ncv 47.5\nclip_start 0.5\nclip_end 1.5\n"
                "location 0 0 1\nrotation 1 0 0 0\n")
    cams = {
        "valid": (True, cam_text),
        "cu 100000": (False, cam_text.replace("cu 47.5", "cu 100000")),
        "clip in millimetres": (False, cam_text.replace("clip_start 0.5", "clip_start 500").replace("clip_end 1.5", "clip_end 1500")),
        "fu -100": (False, cam_text.replace("fu 100", "fu -100")),
        "width 1e9": (False, cam_text.replace("width 96", "width 1000000000")),
        "missing height": (False, cam_text.replace("height 96\n", "")),
        "zero quaternion": (False, cam_text.replace("rotation 1 0 0 0", "rotation 0 0 0 0")),
        "text value": (False, cam_text.replace("fu 100", "fu abc")),
    }
    for name, (valid, text) in cams.items():
        add("camera_params.txt", name, valid, read_camera_params, mutated(ws, f"cam_{len(cases)}", None, text))

    # --- poseutils.json
    pu = {
        "valid copy": (True, lambda d: d),
        "not JSON": (False, b"{"),
        "unknown type": (False, json_with(lambda o: _set(o, "type", "Magic"))),
        "missing field": (False, json_with(lambda o: {k: v for i, (k, v) in enumerate(o.items()) if i != 1})),
        "negative distance_threshold": (False, json_with(lambda o: _set(o, "distance_threshold", -1.0))),
        "distance_threshold 'far'": (False, json_with(lambda o: _set(o, "distance_threshold", "far"))),
        "Lambda 2x2": (False, json_with(lambda o: _set(o, "Lambda", [[1, 0], [0, 1]]))),
        "G not a group": (False, json_with(lambda o: _set(o, "G", [o["G"][0], [[0, -1, 0], [1, 0, 0], [0, 0, 1]]]))),
        "deeply nested": (False, b"[" * 50000 + b"]" * 50000),
    }
    for name, (valid, change) in pu.items():
        add("poseutils.json", name, valid, ObjectModel.from_poseutils, mutated(ws, f"pu_{len(cases)}", poseutils, change))
    add("poseutils.json", "/dev/zero", False, ObjectModel.from_poseutils, Path("/dev/zero"))

    # --- dataset check (the whole folder)
    def broken_dataset(name: str, change: Callable[[Path], None]) -> Path:
        root = ws / "cases" / name
        shutil.copytree(data, root, ignore=shutil.ignore_patterns("cache_*"))
        change(root)
        return root

    def truncate(p: Path) -> None:
        p.write_bytes(p.read_bytes()[: p.stat().st_size // 2])

    datasets = {
        "valid copy": (True, lambda r: None),
        "truncated depth PNG in one scene": (False, lambda r: truncate(r / "p_depth" / "cycle_0003" / "002_depth_uint16.png")),
        "rotation x3 in one CSV": (False, lambda r: (r / "gt" / "cycle_0001" / "001.csv").write_bytes(
            csv_with(csv, lambda c: [*c[:5], *(str(3 * float(v)) for v in c[5:14]), *c[14:]])((r / "gt" / "cycle_0001" / "001.csv").read_bytes()))),
        "depth PNG of another size": (False, lambda r: (r / "p_depth" / "cycle_0002" / "001_depth_uint16.png").write_bytes(png_of(np.zeros((50, 60), np.uint16)))),
        "empty segmentation PNG": (False, lambda r: (r / "p_segmentation" / "cycle_0000" / "001_segmentation.png").write_bytes(b"")),
        "all depth missing": (False, lambda r: [p.write_bytes(png_of(np.full((96, 96), 65535, np.uint16))) for p in (r / "p_depth").rglob("*.png")]),
    }
    for name, (valid, change) in datasets.items():
        root = broken_dataset(f"ds_{len(cases)}", change)
        cases.append(Case("dataset check", name, valid, run=lambda r=root: _check_finds(r), names=(root.name,)))
    return cases


def cli_cases(ws: Path, base: dict[str, Path]) -> list[Case]:
    py = sys.executable
    data, ckpt = base["data"], base["ckpt"]
    png = data / "p_depth" / "cycle_0000" / "002_depth_uint16.png"
    out = ws / "cli_out"
    evil = ws / "cases" / "evil.ckpt"
    evil.parent.mkdir(parents=True, exist_ok=True)
    evil.write_bytes(b"PK\x03\x04" + garbage(200, "zip"))
    trunc = ws / "cases" / "trunc.ckpt"
    trunc.write_bytes(ckpt.read_bytes()[: ckpt.stat().st_size // 3])
    npy_zero = ws / "cases" / "zero.npy"
    np.save(npy_zero, np.zeros((0, 0), np.float32))
    npy_ok = ws / "cases" / "ok.npy"
    np.save(npy_ok, np.full((64, 64), 1.0, np.float32))
    cam = ["camera.fx=60", "camera.fy=60", "camera.cx=31.5", "camera.cy=31.5", "camera.clip_start=0.5", "camera.clip_end=1.5"]
    deep = ws / "cases" / "deepres"
    deep.mkdir(parents=True, exist_ok=True)
    for g in base["gt"].glob("*.json"):
        (deep / g.name).write_bytes(b"[" * 100000 + b"]" * 100000)
    seg_gt = ws / "cases" / "seggt"
    seg_gt.mkdir(parents=True, exist_ok=True)
    for g in base["gt"].glob("*.json"):
        doc = json.loads(g.read_text())
        if doc:
            doc[0]["segmentation_id"] = 1e30
        (seg_gt / g.name).write_text(json.dumps(doc))
    fifo_dir = ws / "cases" / "fifo_in"
    fifo_dir.mkdir(parents=True, exist_ok=True)
    os.mkfifo(fifo_dir / "x.png")
    import trimesh

    box, box_mm = ws / "cases" / "box.obj", ws / "cases" / "box_mm.obj"
    trimesh.creation.box((0.04, 0.03, 0.02)).export(box)
    trimesh.creation.box((40.0, 30.0, 20.0)).export(box_mm)
    ev = ["opnet-evaluate", "--gt", str(base["gt"]), "--results", str(base["results"])]
    h = lambda name: f"hydra.run.dir={ws / 'hydra' / name}"  # noqa: E731
    c = [
        ("opnet-evaluate", "valid", True, [*ev, "--object", "zbracket"], ()),
        ("opnet-evaluate", "--poseutils /dev/zero", False, [*ev, "--poseutils", "/dev/zero"], ("/dev/zero",)),
        ("opnet-evaluate", "--poseutils a FIFO", False, [*ev, "--poseutils", str(fifo_dir / "x.png")], ("x.png",)),
        ("opnet-evaluate", "--object ../../x", False, [*ev, "--object", "../../x"], ("../../x",)),
        ("opnet-evaluate", "--object unknown", False, [*ev, "--object", "teapot"], ("teapot",)),
        ("opnet-evaluate", "results nested 100000 deep", False,
         ["opnet-evaluate", "--gt", str(base["gt"]), "--results", str(deep), "--object", "zbracket"], ("deepres",)),
        ("opnet-evaluate", "segmentation_id 1e30", False,
         ["opnet-evaluate", "--gt", str(seg_gt), "--results", str(base["results"]), "--object", "zbracket"], ("seggt",)),
        ("opnet-evaluate", "--max-occlusion 7", False, [*ev, "--object", "zbracket", "--max-occlusion", "7"], ("max-occlusion",)),
        ("opnet-evaluate", "--gt missing folder", False, ["opnet-evaluate", "--gt", str(ws / "nope"), "--results",
                                                          str(base["results"]), "--object", "zbracket"], ("nope",)),
        ("predict.py", "valid PNG", True, [py, "predict.py", f"ckpt={ckpt}", f"input={png}", f"out={out / 'p1'}", h("p1")], ()),
        ("predict.py", "valid npy + camera", True, [py, "predict.py", f"ckpt={ckpt}", f"input={npy_ok}", f"out={out / 'p2'}", *cam, h("p2")], ()),
        ("predict.py", "malformed checkpoint", False, [py, "predict.py", f"ckpt={evil}", f"input={png}", f"out={out / 'p3'}", h("p3")], ("evil.ckpt",)),
        ("predict.py", "truncated checkpoint", False, [py, "predict.py", f"ckpt={trunc}", f"input={png}", f"out={out / 'p4'}", h("p4")], ("trunc.ckpt",)),
        ("predict.py", "0x0 .npy", False, [py, "predict.py", f"ckpt={ckpt}", f"input={npy_zero}", f"out={out / 'p5'}", *cam, h("p5")], ("zero.npy",)),
        ("predict.py", "camera.cx=100000", False, [py, "predict.py", f"ckpt={ckpt}", f"input={npy_ok}", f"out={out / 'p6'}",
                                                   *cam[:2], "camera.cx=100000", *cam[3:], h("p6")], ("ok.npy",)),
        ("predict.py", "camera.fx=-5", False, [py, "predict.py", f"ckpt={ckpt}", f"input={npy_ok}", f"out={out / 'p7'}",
                                               "camera.fx=-5", *cam[1:], h("p7")], ("camera.fx",)),
        ("predict.py", "clip planes in mm", False, [py, "predict.py", f"ckpt={ckpt}", f"input={npy_ok}", f"out={out / 'p8'}",
                                                    *cam[:4], "camera.clip_start=500", "camera.clip_end=1500", h("p8")], ("clip_end",)),
        ("predict.py", "FIFO in the input folder", False, [py, "predict.py", f"ckpt={ckpt}", f"input={fifo_dir}", f"out={out / 'p9'}", h("p9")], ("x.png",)),
        ("predict.py", "rerun into the same out", False, [py, "predict.py", f"ckpt={ckpt}", f"input={png}", f"out={out / 'p1'}", h("p10")], ("overwrite",)),
        ("predict.py", "conflicting camera.fx on a dataset PNG", False, [py, "predict.py", f"ckpt={ckpt}", f"input={png}",
                                                                         f"out={out / 'p11'}", "camera.fx=1000", h("p11")], ("camera.fx",)),
        ("eval.py", "valid", True, [py, "eval.py", f"ckpt={ckpt}", f"out={out / 'e1'}", "examples=0", h("e1")], ()),
        ("eval.py", "missing checkpoint", False, [py, "eval.py", f"ckpt={ws / 'none.ckpt'}", h("e2")], ("none.ckpt",)),
        ("eval.py", "data.root not a dataset", False, [py, "eval.py", f"ckpt={ckpt}", f"data.root={ws / 'cases'}", h("e3")], ("cases",)),
        ("train.py", "data.root missing", False, [py, "train.py", "model=tiny", f"data.root={ws / 'nope'}", "data.generate=null", h("t1")], ("nope",)),
        ("train.py", "resume from a truncated last.ckpt", False, [py, "train.py", "model=tiny", f"data.root={data}", "data.generate=null",
                                                                  f"ckpt_path={trunc}", h("t2")], ("trunc.ckpt",)),
        ("train.py", "data.check=sometimes", False, [py, "train.py", "model=tiny", f"data.root={data}", "data.generate=null",
                                                     "data.check=sometimes", h("t3")], ("data.check",)),
        ("generate.py", "scene.resolution=100000", False, [py, "generate.py", "cycles=1", "drops=1", "scene.resolution=100000",
                                                           f"out={ws / 'g1'}", h("g1")], ("resolution",)),
        ("generate.py", "cycles=-1", False, [py, "generate.py", "cycles=-1", f"out={ws / 'g2'}", h("g2")], ("cycles",)),
        ("generate.py", "valid mesh file (a box)", True, [py, "generate.py", "cycles=1", "drops=1", "object=bunny",
                                                          f"object.mesh={box}", "scene.resolution=64", f"out={ws / 'g0'}", h("g0")], ()),
        ("generate.py", "symmetry order 2.5", False, [py, "generate.py", "cycles=1", "drops=1", "object=bunny", f"object.mesh={box}",
                                                     "object.symmetry.kind=cyclic", "+object.symmetry.order=2.5",
                                                     f"out={ws / 'g3'}", h("g3")], ("order",)),
        ("generate.py", "symmetry order 10^6", False, [py, "generate.py", "cycles=1", "drops=1", "object=bunny", f"object.mesh={box}",
                                                      "object.symmetry.kind=cyclic", "+object.symmetry.order=1000000",
                                                      f"out={ws / 'g5'}", h("g5")], ("order",)),
        ("generate.py", "flat mesh", False, [py, "generate.py", "cycles=1", "drops=1", "object=bunny",
                                             f"object.mesh={ws / 'cases' / 'flat.obj'}", f"out={ws / 'g4'}", h("g4")], ("flat.obj",)),
        ("generate.py", "mesh in millimetres", False, [py, "generate.py", "cycles=1", "drops=1", "object=bunny",
                                                       f"object.mesh={box_mm}", f"out={ws / 'g6'}", h("g6")], ("box_mm.obj",)),
    ]  # fmt: skip
    (ws / "cases" / "flat.obj").write_text("v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nf 1 2 3\n")
    return [Case(f, n, v, argv=a, names=names, status=_documented_status(n)) for f, n, v, a, names in c]


#: refusals of one image among the inputs: predict.py and python -m opnet.deploy name it on its line, go on
#: with the others and exit 1; every other refusal of a command line exits 2
IMAGE_FAILURES = ("0x0 .npy", "camera.cx=100000", "FIFO in the input folder", "conflicting camera.fx on a dataset PNG",
                  "camera.fx=1e12", ".npy depth in millimetres", "--fx 1e-9")  # fmt: skip


def _documented_status(name: str) -> int:
    return 1 if name in IMAGE_FAILURES else 2


# ------------------------------------------------------------------------------- more families


def make_extra(ws: Path, base: dict[str, Path]) -> dict[str, Path]:
    """A BOP copy of the dataset, the checkpoint exported to ONNX, and a fresh checkpoint copy."""
    from opnet.cli.export import run as export_run
    from opnet.datasets.bop import convert_ipa_to_bop
    from opnet.studies import compose_entry

    extra = {"bop": convert_ipa_to_bop(base["data"], ws / "bop", split="train_synt", obj_id=1).parent}
    onnx = ws / "model.onnx"
    export_run(compose_entry("export", [f"ckpt={base['ckpt']}", f"out={onnx}", "check=false"]))  # export.py's run
    extra["onnx"] = onnx
    return extra


def _reader(cases: list[Case], family: str, name: str, valid: bool, fn: Callable[[], Any], *names: str) -> None:
    cases.append(Case(family, name, valid, run=fn, names=names))


def _read_bop(split: Path) -> None:
    from opnet.datasets.bop import BOPDataset

    ds = BOPDataset(split, 1)
    for i in range(len(ds)):
        ds[i]


def _rz(deg: float) -> list[float]:
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return [c, -s, 0, 0, s, c, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]


def _last_image(change: Callable[[dict], Any]) -> Callable[[Any], Any]:
    """A change of the last image's entry of a BOP scene JSON (image id -> entry): the full bin."""
    def apply(doc: dict) -> dict:
        key = sorted(doc, key=int)[-1]
        doc[key] = change(doc[key])
        return doc

    return apply


def _inst0(key: str, value: Callable[[Any], Any] | Any) -> Callable[[Any], Any]:
    def change(entries: list) -> list:
        entries[0][key] = value(entries[0][key]) if callable(value) else value
        return entries

    return _last_image(change)


def bop_cases(ws: Path, extra: dict[str, Path]) -> list[Case]:
    """Every BOP file of the split, garbled: scene_gt, scene_camera, scene_gt_info, models_info, PNGs."""
    import cv2

    src = extra["bop"]
    cases: list[Case] = []

    def bop_copy(i: int, rel: str, change: Callable[[bytes], bytes] | bytes) -> Path:
        root = ws / "cases" / f"bop_{i}"
        shutil.copytree(src, root)
        path = root / rel
        path.write_bytes(change(path.read_bytes()) if callable(change) else change)
        return root / "train_synt"

    g, c, n, m = ("train_synt/000000/scene_gt.json", "train_synt/000000/scene_camera.json",
                  "train_synt/000000/scene_gt_info.json", "models/models_info.json")
    png = "train_synt/000000/depth/000003.png"
    mask = "train_synt/000000/mask_visib/000003_000000.png"
    J = json_with
    rows: list[tuple[str, bool, str, Callable[[bytes], bytes] | bytes, str]] = [
        ("valid copy", True, g, lambda d: d, ""),
        ("cam_t_m2c in metres", False, g, J(_last_image(lambda e: [{**x, "cam_t_m2c": [v / 1000 for v in x["cam_t_m2c"]]} for x in e])), "cam_t_m2c"),
        ("cam_t_m2c in micrometres", False, g, J(_inst0("cam_t_m2c", lambda t: [v * 1000 for v in t])), "cam_t_m2c"),
        ("obj_id 1.9", False, g, J(_inst0("obj_id", 1.9)), "obj_id"),
        ("obj_id true", False, g, J(_inst0("obj_id", True)), "obj_id"),
        ("obj_id 'abc'", False, g, J(_inst0("obj_id", "abc")), "obj_id"),
        ("obj_id -1", False, g, J(_inst0("obj_id", -1)), "obj_id"),
        ("image entry a dict", False, g, J(_last_image(lambda e: {"obj_id": 1})), "scene_gt.json"),
        ("instance a number", False, g, J(_last_image(lambda e: [5])), "scene_gt.json"),
        ("image id 'abc'", False, g, J(lambda d: {**d, "abc": []}), "scene_gt.json"),
        ("cam_R_m2c scaled by 3", False, g, J(_inst0("cam_R_m2c", lambda r: [3 * v for v in r])), "scene_gt.json"),
        ("cam_R_m2c a reflection", False, g, J(_inst0("cam_R_m2c", lambda r: [*r[:6], *(-v for v in r[6:])])), "scene_gt.json"),
        ("cam_R_m2c 8 numbers", False, g, J(_inst0("cam_R_m2c", lambda r: r[:8])), "cam_R_m2c"),
        ("cam_t_m2c strings", False, g, J(_inst0("cam_t_m2c", ["a", "b", "c"])), "cam_t_m2c"),
        ("cam_t_m2c 1e300", False, g, J(_inst0("cam_t_m2c", [0, 0, 1e300])), "scene_gt.json"),
        ("cam_t_m2c missing", False, g, J(_last_image(lambda e: [{k: v for k, v in e[0].items() if k != "cam_t_m2c"}, *e[1:]])), "cam_t_m2c"),
        ("NaN in cam_t_m2c", False, g, lambda d: d.replace(b'"cam_t_m2c": [', b'"cam_t_m2c": [NaN, ', 1), "scene_gt.json"),
        ("scene_gt not JSON", False, g, b"{", "scene_gt.json"),
        ("scene_gt a list", False, g, b"[]", "scene_gt.json"),
        ("scene_gt nested 100000 deep", False, g, b"[" * 100000 + b"]" * 100000, "scene_gt.json"),
        ("cam_K fx 1e-9", False, c, J(_last_image(lambda e: {**e, "cam_K": [1e-9, *e["cam_K"][1:]]})), "scene_camera.json"),
        ("cam_K fx 1e12", False, c, J(_last_image(lambda e: {**e, "cam_K": [1e12, *e["cam_K"][1:]]})), "scene_camera.json"),
        ("cam_K 8 numbers", False, c, J(_last_image(lambda e: {**e, "cam_K": e["cam_K"][:8]})), "cam_K"),
        ("cam_K booleans", False, c, J(_last_image(lambda e: {**e, "cam_K": [True] * 9})), "cam_K"),
        ("cam_K principal point 1e6", False, c, J(_last_image(lambda e: {**e, "cam_K": [*e["cam_K"][:2], 1e6, *e["cam_K"][3:]]})), "scene_camera.json"),
        ("depth_scale 0", False, c, J(_last_image(lambda e: {**e, "depth_scale": 0})), "depth_scale"),
        ("depth_scale 'x'", False, c, J(_last_image(lambda e: {**e, "depth_scale": "x"})), "depth_scale"),
        ("camera entry missing", False, c, J(lambda d: {k: v for k, v in d.items() if k != sorted(d, key=int)[-1]}), "scene_camera.json"),
        ("camera entry a list", False, c, J(_last_image(lambda e: [1, 2])), "scene_camera.json"),
        ("visib_fract 1.5", False, n, J(_last_image(lambda e: [{**e[0], "visib_fract": 1.5}, *e[1:]])), "visib_fract"),
        ("visib_fract 'a'", False, n, J(_last_image(lambda e: [{**e[0], "visib_fract": "a"}, *e[1:]])), "visib_fract"),
        ("gt_info one entry short", False, n, J(_last_image(lambda e: e[:-1])), "scene_gt_info.json"),
        ("gt_info entry a number", False, n, J(_last_image(lambda e: [7] * len(e))), "scene_gt_info.json"),
        ("obj 1 missing from models_info", False, m, b'{"2": {"diameter": 50}}', "models_info.json"),
        ("symmetries_discrete 5", False, m, J(lambda d: {"1": {**d["1"], "symmetries_discrete": 5}}), "symmetries_discrete"),
        ("symmetries_discrete repeated (valid)", True, m, J(lambda d: {"1": {**d["1"], "symmetries_discrete": [_rz(180), _rz(180)]}}), ""),
        ("symmetries_discrete 3000 rotations", False, m, J(lambda d: {"1": {**d["1"], "symmetries_discrete": [_rz(a) for a in np.arange(1, 3001) * 0.12]}}), "models_info.json"),
        ("symmetries_discrete a reflection", False, m, J(lambda d: {"1": {**d["1"], "symmetries_discrete": [[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]]}}), "symmetries_discrete"),
        ("symmetries_continuous a dict", False, m, J(lambda d: {"1": {**d["1"], "symmetries_continuous": {"axis": [0, 0, 1]}}}), "symmetries_continuous"),
        ("two continuous axes", False, m, J(lambda d: {"1": {**d["1"], "symmetries_continuous": [{"axis": [0, 0, 1]}, {"axis": [1, 0, 0]}]}}), "models_info.json"),
        ("diameter 'big'", False, m, J(lambda d: {"1": {**d["1"], "diameter": "big"}}), "diameter"),
        ("model entry a list", False, m, J(lambda d: {"1": [1, 2]}), "models_info.json"),
        ("models_info not JSON", False, m, b"{", "models_info.json"),
        ("depth PNG truncated", False, png, lambda d: d[: len(d) // 2], "000003.png"),
        ("depth PNG 8-bit", False, png, lambda d: cv2.imencode(".png", np.zeros((96, 96), np.uint8))[1].tobytes(), "000003.png"),
        ("depth PNG header 50000 x 50000", False, png, lambda d: d[:16] + (50000).to_bytes(4, "big") * 2 + d[24:], "000003.png"),
        ("mask of another size", False, mask, lambda d: cv2.imencode(".png", np.zeros((50, 60), np.uint8))[1].tobytes(), "000003_000000.png"),
    ]  # fmt: skip
    for i, (name, valid, rel, change, key) in enumerate(rows):
        split = bop_copy(i, rel, change)
        _reader(cases, "BOP", name, valid, lambda s=split: _read_bop(s), *((key,) if key else ()))
    empty = ws / "cases" / "bop_empty"
    shutil.copytree(src, empty)
    for p in (empty / "train_synt").glob("*/scene_gt.json"):
        p.write_text("{}")
    _reader(cases, "BOP", "every scene_gt.json empty", False, lambda: _read_bop(empty / "train_synt"), "train_synt")
    return cases


def mesh_cases(ws: Path) -> list[Case]:
    """Object configs with bad meshes and keys (object_from_config, what generate.py calls)."""
    import trimesh

    from opnet.objects import object_from_config

    folder = ws / "cases" / "meshes"
    folder.mkdir(parents=True, exist_ok=True)
    box = trimesh.creation.box((0.04, 0.03, 0.02))
    box.export(folder / "box.obj")
    inv = box.copy()
    inv.invert()
    inv.export(folder / "inside_out.ply")
    mixed = trimesh.Trimesh(box.vertices, np.vstack([box.faces[:4, ::-1], box.faces[4:]]), process=False)
    mixed.export(folder / "mixed_winding.obj")
    trimesh.creation.box((40.0, 30.0, 20.0)).export(folder / "box_mm.stl")
    files = {
        "huge.ply": b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    b"property float z\nelement face 5000000\nproperty list uchar int vertex_indices\nend_header\n",
        "huge.stl": b"\0" * 80 + (5_000_000).to_bytes(4, "little") + b"\0" * 100,
        "empty.obj": b"",
        "garbage.stl": garbage(300, "stl"),
        "nan.obj": b"v 0 0 0\nv nan 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf 1 2 4\nf 2 3 4\n",
        "bad_index.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",
        "points.ply": b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                      b"end_header\n0 0 0\n0.01 0 0\n0 0.01 0\n",
        "part.dxf": b"0\nSECTION\n",
        "text.obj": "v é 0 0\n".encode(),
    }
    for name, data in files.items():
        (folder / name).write_bytes(data)
    os.mkfifo(folder / "fifo.stl")
    (folder / "dir.obj").mkdir(exist_ok=True)
    cases: list[Case] = []

    def obj(name: str, valid: bool, key: str | None = None, **cfg: Any) -> None:
        mesh = cfg.pop("mesh", None)
        config = {"name": "part", **({"mesh": str(folder / mesh)} if mesh else {}), **cfg}
        names = (key,) if key else ((mesh,) if mesh else ())
        _reader(cases, "mesh / object config", name, valid, lambda c=config: object_from_config(c), *names)

    obj("valid box", True, mesh="box.obj")
    obj("inside-out box (repaired)", True, mesh="inside_out.ply")
    obj("mixed winding (repaired)", True, mesh="mixed_winding.obj")
    obj("mesh in mm with mesh_scale 0.001", True, mesh="box_mm.stl", mesh_scale=0.001)
    obj("mesh in mm", False, mesh="box_mm.stl")
    (folder / "flat.obj").write_bytes(b"v 0 0 0\nv 0.05 0 0\nv 0 0.05 0\nf 1 2 3\n")
    obj("flat mesh (a surface model; generate.py refuses it)", True, mesh="flat.obj")
    for name in files:
        obj(f"{name}", False, mesh=name)
    obj("FIFO named .stl", False, mesh="fifo.stl")
    obj("folder named .obj", False, mesh="dir.obj")
    obj("missing mesh", False, mesh="nope.obj")
    obj("/dev/zero as mesh", False, "zero", mesh="../../../../../../dev/zero")
    obj("mesh_scale -1", False, "mesh_scale", mesh="box.obj", mesh_scale=-1)
    obj("mesh_scale 'abc'", False, "mesh_scale", mesh="box.obj", mesh_scale="abc")
    obj("mesh_scale true", False, "mesh_scale", mesh="box.obj", mesh_scale=True)
    obj("mesh_scale NaN", False, "mesh_scale", mesh="box.obj", mesh_scale=float("nan"))
    obj("symmetry [revolution]", False, "object.symmetry", mesh="box.obj", symmetry=["revolution"])
    obj("symmetry 'magic'", False, "object.symmetry", mesh="box.obj", symmetry="magic")
    obj("symmetry order 2.5", False, "order", mesh="box.obj", symmetry={"kind": "cyclic", "order": 2.5})
    obj("symmetry order 10^6", False, "order", mesh="box.obj", symmetry={"kind": "cyclic", "order": 10**6})
    obj("rotoreflection 'false'", False, "rotoreflection", mesh="box.obj", symmetry={"kind": "revolution", "rotoreflection": "false"})
    obj("rotations [I, reflection]", False, "object.symmetry", mesh="box.obj",
        symmetry={"kind": "finite", "rotations": [np.eye(3).tolist(), np.diag([1, 1, -1]).tolist()]})
    obj("model_rotation a reflection", False, "model_rotation", mesh="box.obj", model_rotation=np.diag([1, 1, -1]).tolist())
    obj("model_rotation 2x2", False, "model_rotation", mesh="box.obj", model_rotation=[[1, 0], [0, 1]])
    obj("unknown key", False, "colour", mesh="box.obj", colour="red")
    obj("bop_obj_id 1.9", False, "bop_obj_id", bop_models=str(folder), bop_obj_id=1.9)
    obj("unknown builtin", False, "teapot", builtin="teapot")
    return cases


CAMERA_YAML = "fx: 100\nfy: 100\ncx: 47.5\ncy: 47.5\nwidth: 96\nheight: 96\nclip_start: 0.5\nclip_end: 1.5\n"


def camera_yaml_cases(ws: Path) -> list[Case]:
    """Camera YAMLs as generate.py (read_camera_file) and predict.py (camera.file) read them."""
    from opnet.datasets.camera_file import read_camera_file
    from opnet.datasets.depth_inputs import _camera_from_given, given_camera

    def as_predict(path: Path) -> Any:  # predict.py camera.file=<yaml> for a 96 x 96 .npy
        return _camera_from_given(Path("image.npy"), given_camera({"file": str(path)}), 96, 96)

    y = CAMERA_YAML
    bomb = "fx:\n  - &a [x, x, x, x, x, x, x, x, x]\n" + "".join(  # 9^9 strings once expanded
        f"  - &{k} [*{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}, *{p}]\n" for p, k in zip("abcdefgh", "bcdefghi"))
    texts = {
        "valid": (True, y),
        "duplicate key fx": (False, y + "fx: 6\n"),
        "fx true": (False, y.replace("fx: 100", "fx: true")),
        "fx 1e-9": (False, y.replace("fx: 100", "fx: 1.0e-9")),
        "fx 1e12": (False, y.replace("fx: 100", "fx: 1.0e+12")),
        "fx 0.0035": (False, y.replace("fx: 100", "fx: 0.0035")),
        "fx .nan": (False, y.replace("fx: 100", "fx: .nan")),
        "fx 'abc'": (False, y.replace("fx: 100", "fx: abc")),
        "fx a list": (False, y.replace("fx: 100", "fx: [1, 2]")),
        "width 1.5": (False, y.replace("width: 96", "width: 1.5")),
        "width -96": (False, y.replace("width: 96", "width: -96")),
        "clip planes in mm": (False, y.replace("clip_start: 0.5", "clip_start: 500").replace("clip_end: 1.5", "clip_end: 1500")),
        "cx 1e6": (False, y.replace("cx: 47.5", "cx: 1000000")),
        "missing clip_end": (False, y.replace("clip_end: 1.5\n", "")),
        "unknown key k1": (False, y + "k1: 0.1\n"),
        "a list": (False, "- 1\n- 2\n"),
        "malformed": (False, "fx: [100\n"),
        "alias bomb": (False, bomb),
        "empty file": (False, ""),
        "tab indentation": (False, "fx:\n\t100\n"),
        "python tag": (False, y + "depth: !!python/object/apply:os.system ['true']\n"),
    }
    folder = ws / "cases" / "camyaml"
    folder.mkdir(parents=True, exist_ok=True)
    cases: list[Case] = []
    for i, (name, (valid, text)) in enumerate(texts.items()):
        path = folder / f"cam_{i}.yaml"
        path.write_text(text)
        _reader(cases, "camera YAML (generate)", name, valid, lambda p=path: read_camera_file(p), path.name)
        if i % 2 == 0 or name in ("duplicate key fx", "alias bomb", "fx 1e-9"):
            _reader(cases, "camera YAML (predict)", name, valid, lambda p=path: as_predict(p), path.name, "camera.")
    os.mkfifo(folder / "fifo.yaml")
    _reader(cases, "camera YAML (generate)", "FIFO named .yaml", False, lambda: read_camera_file(folder / "fifo.yaml"), "fifo.yaml")
    return cases


def _onnx_with_meta(src: Path, dst: Path, change: Callable[[dict], Any] | str | None) -> Path:
    import onnx

    proto = onnx.load(str(src))
    entry = next(e for e in proto.metadata_props if e.key == "opnet")
    if change is None:
        proto.metadata_props.remove(entry)
    elif isinstance(change, str):
        entry.value = change
    else:
        entry.value = json.dumps(change(json.loads(entry.value)))
    onnx.save(proto, str(dst))
    return dst


def _nested_set(path: str, value: Any) -> Callable[[dict], dict]:
    """A change of a nested mapping: ``path`` (dotted) set to ``value``, or deleted (``_DROP``)."""
    def change(meta: dict) -> dict:
        node = meta
        *parents, last = path.split(".")
        for p in parents:
            node = node[p]
        if value is _DROP:
            del node[last]
        else:
            node[last] = value
        return meta

    return change


_DROP = object()


def onnx_cases(ws: Path, extra: dict[str, Path]) -> list[Case]:
    """ONNX files and their opnet metadata, as the torch-free runtime loads them."""
    from opnet.deploy.runtime import OnnxPoseEstimator

    src = extra["onnx"]
    folder = ws / "cases" / "onnx"
    folder.mkdir(parents=True, exist_ok=True)
    cases: list[Case] = []

    def add(name: str, valid: bool, path: Path, *names: str) -> None:
        _reader(cases, "ONNX", name, valid, lambda p=path: OnnxPoseEstimator(p), *(names or (path.name,)))

    data = src.read_bytes()
    for i, (name, content) in enumerate({"truncated": data[: len(data) // 2], "empty": b"", "garbage": garbage(2000, "onnx"),
                                         "a PNG renamed": b"\x89PNG\r\n\x1a\n" + garbage(100, "png")}.items()):
        path = folder / f"file_{i}.onnx"
        path.write_bytes(content)
        add(name, False, path)
    metas: dict[str, tuple[bool, Callable[[dict], Any] | str | None, str]] = {
        "valid copy": (True, lambda m: m, ""),
        "no metadata": (False, None, ""),
        "metadata not JSON": (False, "{threshold", ""),
        "metadata a list": (False, "[1, 2]", ""),
        "metadata nested 100000 deep": (False, "[" * 100000 + "]" * 100000, ""),
        "threshold NaN": (False, lambda m: json.loads(json.dumps(m).replace('"threshold": ', '"threshold": NaN, "x": ')), "threshold"),
        "threshold -1": (False, _nested_set("decoding.threshold", -1), "threshold"),
        "threshold missing": (False, _nested_set("decoding.threshold", _DROP), "threshold"),
        "threshold 'high'": (False, _nested_set("decoding.threshold", "high"), "threshold"),
        "threshold true": (False, _nested_set("decoding.threshold", True), "threshold"),
        "score 'magic'": (False, _nested_set("decoding.score", "magic"), "score"),
        "decoding missing": (False, _nested_set("decoding", _DROP), "decoding"),
        "averaging eps -1": (False, lambda m: _nested_set("decoding.averaging", {"eps": -1, "min_samples": 1, "cluster_score": "sum"})(m), "eps"),
        "interpolation 'cubic'": (False, _nested_set("input.interpolation", "cubic"), "interpolation"),
        "fit 'stretch'": (False, _nested_set("input.fit", "stretch"), "fit"),
        "input size 0": (False, _nested_set("input.size", 0), "size"),
        "input size 10^6": (False, _nested_set("input.size", 10**6), "size"),
        "grid_size wrong": (False, lambda m: _nested_set("grid_size", m["grid_size"] + 1)(m), ""),
        "pose_space missing": (False, _nested_set("pose_space", _DROP), "pose_space"),
        "pose_space Lambda 2x2": (False, _nested_set("pose_space.Lambda", [[1, 0], [0, 1]]), "Lambda"),
        "pose_space group not a group": (False, _nested_set("pose_space.group", [np.eye(3).tolist(), [[0, -1, 0], [1, 0, 0], [0, 0, 1]]]), "group"),
        "pose_space delta 0": (False, _nested_set("pose_space.delta", 0), "delta"),
        "object name of 10^5 characters": (False, _nested_set("object", "x" * 100000), "object"),
        "outputs renamed": (False, _nested_set("outputs", ["a", "b", "c", "d"]), "outputs"),
    }
    for i, (name, (valid, change, key)) in enumerate(metas.items()):
        path = _onnx_with_meta(src, folder / f"meta_{i}.onnx", change)
        add(name, valid, path, *((key,) if key else (path.name,)))
    os.mkfifo(folder / "fifo.onnx")
    add("FIFO named .onnx", False, folder / "fifo.onnx")
    add("/dev/zero", False, Path("/dev/zero"))
    return cases


def checkpoint_cases(ws: Path, base: dict[str, Path]) -> list[Case]:
    """Checkpoints edited by hand, as every entry point loads them (load_checkpoint)."""
    import pickle

    import torch

    from opnet.cli.build import load_checkpoint

    ckpt = torch.load(base["ckpt"], map_location="cpu", weights_only=True)
    folder = ws / "cases" / "ckpt"
    folder.mkdir(parents=True, exist_ok=True)
    cases: list[Case] = []

    def edited(change: Callable[[dict], Any]) -> Any:
        copy = pickle.loads(pickle.dumps(ckpt))
        return change(copy)

    def cfg(key: str, value: Any) -> Callable[[dict], dict]:
        return lambda c: _nested_set(f"hyper_parameters.config.{key}", value)(c)

    def sd(change: Callable[[dict], None]) -> Callable[[dict], dict]:
        def apply(c: dict) -> dict:
            change(c["state_dict"])
            return c

        return apply

    first = next(k for k, v in ckpt["state_dict"].items() if v.is_floating_point() and v.ndim == 4)
    evil = {"_target_": "opnet.fileio.atomic.write_text_atomic", "_args_": [str(ws / "pwned.txt"), "x"]}
    rows: dict[str, tuple[bool, Callable[[dict], Any], str]] = {
        "valid copy": (True, lambda c: c, ""),
        "a list": (False, lambda c: [1, 2, 3], ""),
        "no state_dict": (False, lambda c: {k: v for k, v in c.items() if k != "state_dict"}, "state_dict"),
        "state_dict a list": (False, lambda c: {**c, "state_dict": [1, 2]}, "state_dict"),
        "no hyper_parameters": (False, lambda c: {k: v for k, v in c.items() if k != "hyper_parameters"}, ""),
        "config a string": (False, lambda c: {**c, "hyper_parameters": {"config": "loss: x"}}, "config"),
        "another object's config (shaft, other rotation layout)": (False, cfg("object", {"name": "shaft", "builtin": "shaft"}), ""),
        "another object's config (bunny, not a built-in)": (False, cfg("object", {"name": "bunny", "builtin": "bunny"}), "bunny"),
        "unknown object": (False, cfg("object", {"name": "teapot"}), "teapot"),
        "object mesh missing": (False, cfg("object", {"name": "part", "mesh": "/nonexistent/part.obj"}), "part.obj"),
        "object symmetry [revolution]": (False, cfg("object.symmetry", ["revolution"]), "object.symmetry"),
        "loss target writes a file": (False, cfg("loss", evil), "loss._target_"),
        "model target os.system": (False, cfg("model._target_", "os.system"), "model._target_"),
        "interpolation in data": (False, cfg("data.root", "${oc.env:HOME}"), "data.root"),
        "parameterization with an unknown key": (False, cfg("parameterization.colour", "red"), "parameterization"),
        "model without growth_rate (its default differs)": (False, cfg("model.growth_rate", _DROP), ""),
        "wrong tensor shape": (False, sd(lambda s: s.__setitem__(first, s[first][:1])), ""),
        "NaN weight": (False, sd(lambda s: s[first].view(-1).__setitem__(0, float("nan"))), "NaN"),
        "missing weight": (False, sd(lambda s: s.pop(first)), ""),
        "unexpected weight": (False, sd(lambda s: s.__setitem__("backbone.extra.weight", torch.zeros(3))), ""),
        "weights as strings": (False, sd(lambda s: s.__setitem__(first, "abc")), ""),
    }
    for i, (name, (valid, change, key)) in enumerate(rows.items()):
        path = folder / f"ck_{i}.ckpt"
        torch.save(edited(change), path)
        _reader(cases, "checkpoint", name, valid, lambda p=path: load_checkpoint(p), *((key,) if key else (path.name,)))
    pk = folder / "object.ckpt"
    pk.write_bytes(pickle.dumps({"state_dict": Path("x")}))
    _reader(cases, "checkpoint", "pickle of a Path object", False, lambda: load_checkpoint(pk), pk.name)
    return cases


# ------------------------------------------------------------- defects by kind, in-process readers


def decoding_cases(base: dict[str, Path]) -> list[Case]:
    """``+decoding.<key>=...`` of predict.py and eval.py, as both read them (with_decoding_overrides on the
    checkpoint's parameterization): out of range, NaN, booleans, text, unknown keys."""
    from omegaconf import OmegaConf

    from opnet.cli.build import load_checkpoint
    from opnet.cli.eval import with_decoding_overrides

    param = load_checkpoint(base["ckpt"])[0].parameterization  # loaded once, before the forks
    nan = float("nan")
    rows: dict[str, tuple[bool, dict[str, Any], str]] = {
        "threshold 0.3": (True, {"threshold": 0.3}, ""),
        "averaging false": (True, {"averaging": False}, ""),
        "averaging eps 0.8, min_samples 2": (True, {"averaging": {"eps": 0.8, "min_samples": 2}}, ""),
        "threshold 1.5": (False, {"threshold": 1.5}, "decoding.threshold"),
        "threshold 1 (the open end)": (False, {"threshold": 1}, "decoding.threshold"),
        "threshold -0.1": (False, {"threshold": -0.1}, "decoding.threshold"),
        "threshold NaN": (False, {"threshold": nan}, "decoding.threshold"),
        "threshold inf": (False, {"threshold": float("inf")}, "decoding.threshold"),
        "threshold true": (False, {"threshold": True}, "decoding.threshold"),
        "threshold 'abc'": (False, {"threshold": "abc"}, "decoding.threshold"),
        "threshold '0.5' (text)": (False, {"threshold": "0.5"}, "decoding.threshold"),
        "threshold null": (False, {"threshold": None}, "decoding.threshold"),
        "threshold [0.5]": (False, {"threshold": [0.5]}, "decoding.threshold"),
        "min_visibility 1": (False, {"min_visibility": 1}, "decoding.min_visibility"),
        "min_visibility -0.1": (False, {"min_visibility": -0.1}, "decoding.min_visibility"),
        "min_visibility false": (False, {"min_visibility": False}, "decoding.min_visibility"),
        "min_visibility NaN": (False, {"min_visibility": nan}, "decoding.min_visibility"),
        "score 'magic'": (False, {"score": "magic"}, "decoding.score"),
        "score null": (False, {"score": None}, "decoding.score"),
        "score true": (False, {"score": True}, "decoding.score"),
        "averaging 5": (False, {"averaging": 5}, "decoding.averaging"),
        "averaging 'abc'": (False, {"averaging": "abc"}, "decoding.averaging"),
        "averaging eps -1": (False, {"averaging": {"eps": -1}}, "eps"),
        "averaging eps NaN": (False, {"averaging": {"eps": nan}}, "eps"),
        "averaging min_samples 0": (False, {"averaging": {"min_samples": 0}}, "min_samples"),
        "averaging cluster_score 'x'": (False, {"averaging": {"cluster_score": "x"}}, "cluster_score"),
        "averaging cluster_score true": (False, {"averaging": {"cluster_score": True}}, "cluster_score"),
        "unknown averaging key 'foo'": (False, {"averaging": {"foo": 1}}, "foo"),
        "unknown key 'colour'": (False, {"colour": "red"}, "colour"),
    }  # fmt: skip
    cases: list[Case] = []
    for name, (valid, settings, key) in rows.items():
        overrides = OmegaConf.create({"decoding": settings}).decoding  # as Hydra hands them over
        _reader(cases, "decoding override", name, valid, lambda o=overrides: with_decoding_overrides(param, o),
                *((key,) if key else ()))
    return cases


def _ckpt_with(ckpt: dict, path: Path, key: str, value: Any) -> Path:
    """A copy of the checkpoint ``ckpt`` with its run config's ``key`` (dotted) set to ``value``, at ``path``."""
    import copy

    import torch

    torch.save(_nested_set(f"hyper_parameters.config.{key}", value)(copy.deepcopy(ckpt)), path)
    return path


def boolean_cases(ws: Path, base: dict[str, Path], extra: dict[str, Path]) -> list[Case]:
    """Booleans where a checkpoint's config or an ONNX file's metadata holds numbers (trained_clip, the
    averaging, the input size): true is no 1, false no 0."""
    import torch

    from opnet.cli.build import load_checkpoint
    from opnet.deploy.runtime import OnnxPoseEstimator

    folder = ws / "cases" / "booleans"
    folder.mkdir(parents=True, exist_ok=True)
    ckpt = torch.load(base["ckpt"], map_location="cpu", weights_only=True)
    cases: list[Case] = []
    configs: dict[str, tuple[str, Any, str]] = {
        "trained_clip true": ("trained_clip", True, "trained_clip"),
        "trained_clip false": ("trained_clip", False, "trained_clip"),
        "trained_clip [true, false]": ("trained_clip", [True, False], "trained_clip"),
        "trained_clip [0.2, true]": ("trained_clip", [0.2, True], "trained_clip"),
        "trained_clip '0.1,0.3' (text)": ("trained_clip", "0.1,0.3", "trained_clip"),
        "data.input_size true": ("data.input_size", True, "input_size"),
        "data.input_size false": ("data.input_size", False, "input_size"),
        "data.input_size 128.0": ("data.input_size", 128.0, "input_size"),
        "parameterization.threshold true": ("parameterization.threshold", True, "threshold"),
    }
    for i, (name, (key, value, named)) in enumerate(configs.items()):
        path = _ckpt_with(ckpt, folder / f"ck_{i}.ckpt", key, value)
        _reader(cases, "checkpoint booleans", name, False, lambda p=path: load_checkpoint(p), named)
    metas: dict[str, tuple[str, Any, str]] = {
        "trained_clip true": ("trained_clip", True, "trained_clip"),
        "trained_clip [true, false]": ("trained_clip", [True, False], "trained_clip"),
        "input.size true": ("input.size", True, "input.size"),
        "input.size false": ("input.size", False, "input.size"),
        "decoding.averaging true": ("decoding.averaging", True, "decoding.averaging"),
        "decoding.averaging false": ("decoding.averaging", False, "decoding.averaging"),
        "averaging min_samples true": ("decoding.averaging.min_samples", True, "min_samples"),
        "averaging eps true": ("decoding.averaging.eps", True, "eps"),
        "averaging keep_noise 1": ("decoding.averaging.keep_noise", 1, "keep_noise"),
        "decoding.min_visibility false": ("decoding.min_visibility", False, "min_visibility"),
        "grid_size true": ("grid_size", True, "grid_size"),
        "pose_space.revolution 1": ("pose_space.revolution", 1, "revolution"),
    }
    averaging = {"eps": 0.5, "min_samples": 1, "cluster_score": "sum"}  # a model exported with its averaging
    for i, (name, (key, value, named)) in enumerate(metas.items()):
        def change(meta: dict, key: str = key, value: Any = value) -> dict:
            if key.startswith("decoding.averaging."):
                meta["decoding"]["averaging"] = {**averaging, **(meta["decoding"].get("averaging") or {})}
            return _nested_set(key, value)(meta)

        path = _onnx_with_meta(extra["onnx"], folder / f"meta_{i}.onnx", change)
        _reader(cases, "ONNX metadata booleans", name, False, lambda p=path: OnnxPoseEstimator(p), named)
    return cases


def _check_finds(root: Path, object_id: int | None = None) -> Any:
    """The dataset check (fast) of ``root``: its first problem as the error, or the report."""
    from opnet.datasets.check import check_dataset

    report = check_dataset(root, fast=True, object_id=object_id)
    if report.problems:
        raise ValueError(str(report.problems[0]))
    return report


def _bop_edited(ws: Path, src: Path, name: str, change: Callable[[Path], None]) -> Path:
    """A copy of the BOP dataset ``src`` changed by ``change(split)``; its split folder."""
    root = ws / "cases" / name
    shutil.copytree(src, root)
    change(root / "train_synt")
    return root / "train_synt"


def _edit_scene_json(path: Path, change: Callable[[dict], Any]) -> None:
    path.write_text(json.dumps(change(json.loads(path.read_text()))))


def _duplicate_last_instance(split: Path) -> None:
    """The full bin's first instance listed twice: in scene_gt.json, its info and its mask (a consistent
    duplicate, which only the check can tell)."""
    scene = split / "000000"
    for name in ("scene_gt.json", "scene_gt_info.json"):
        _edit_scene_json(scene / name, _last_image(lambda e: [*e, dict(e[0])]))
    image = max(json.loads((scene / "scene_gt.json").read_text()), key=int)
    count = len(json.loads((scene / "scene_gt.json").read_text())[image])
    masks = scene / "mask_visib"
    shutil.copy(masks / f"{int(image):06d}_000000.png", masks / f"{int(image):06d}_{count - 1:06d}.png")


def _camera_world(R: list[float]) -> Callable[[Path], None]:
    """A change of a split: the full bin's camera given the world rotation ``R`` (cam_R_w2c)."""
    return lambda split: _edit_scene_json(split / "000000" / "scene_camera.json",
                                          _last_image(lambda e: {**e, "cam_R_w2c": R, "cam_t_w2c": [0.0, 0.0, 900.0]}))


def ground_truth_cases(ws: Path, extra: dict[str, Path]) -> list[Case]:
    """BOP ground truth that thins out or swells unseen: a deleted visible mask (the reader names the
    file), a duplicate instance and a camera rotation that is no rotation (the dataset check reports them)."""
    src = extra["bop"]
    mask = "000000/mask_visib/000003_000001.png"
    splits = {
        "deleted mask_visib file": lambda s: (s / mask).unlink(),
        "duplicate instance (gt, info and mask)": _duplicate_last_instance,
        "cam_R_w2c scaled by 2": _camera_world(np.diag([2.0, 2.0, 2.0]).reshape(-1).tolist()),
        "cam_R_w2c a reflection": _camera_world(np.diag([1.0, 1.0, -1.0]).reshape(-1).tolist()),
        "cam_R_w2c 6 numbers": _camera_world([1.0, 0.0, 0.0, 0.0, 1.0, 0.0]),
        "cam_R_w2c a turn about z": _camera_world([0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]),
        "scene without a mask_visib folder": lambda s: shutil.rmtree(s / "000000" / "mask_visib"),
    }
    found = {"deleted mask_visib file": "000003_000001.png", "duplicate instance (gt, info and mask)": "duplicates",
             "cam_R_w2c scaled by 2": "cam_R_w2c", "cam_R_w2c a reflection": "cam_R_w2c", "cam_R_w2c 6 numbers": "cam_R_w2c"}
    cases: list[Case] = []
    for i, (name, change) in enumerate(splits.items()):
        split = _bop_edited(ws, src, f"gt_{i}", change)
        valid, names = name not in found, (found[name],) if name in found else ()
        if "mask_visib" in name:  # the reader itself
            _reader(cases, "BOP ground truth", f"{name}: reader", valid, lambda s=split: _read_bop(s), *names)
        _reader(cases, "BOP ground truth", f"{name}: dataset check", valid, lambda s=split: _check_finds(s, 1), *names)
    return cases


def _scene_jsons(folder: Path, change: Callable[[list[dict]], list[dict]], source: Path) -> Path:
    """``folder`` holding each Siléane JSON of ``source``, its entries changed by ``change``."""
    folder.mkdir(parents=True, exist_ok=True)
    for path in sorted(source.glob("*.json")):
        (folder / path.name).write_text(json.dumps(change(json.loads(path.read_text()))))
    return folder


def _as_results(entries: list[dict]) -> list[dict]:
    """Ground-truth entries as hypotheses at their poses, score 0.9."""
    return [{"R": e["R"], "t": e["t"], "score": 0.9} for e in entries]


def _evaluated(gt: Path, results: Path) -> str:
    """The AP table of the Siléane scenes of ``gt`` and ``results``, as opnet-evaluate prints it."""
    from opnet.datasets.sileane_json import read_gt_json, read_results_json
    from opnet.metrics.bregier import evaluate_scenes
    from opnet.objects import builtin_object

    scenes = {p.stem: (read_gt_json(p), read_results_json(results / p.name)) for p in sorted(gt.glob("*.json"))}
    return evaluate_scenes(scenes, builtin_object("zbracket").pose_space).table()


def empty_metric_cases(ws: Path, base: dict[str, Path]) -> list[Case]:
    """The metric's empty case: a split with nothing to find has AP 1.0 by convention, which the table must
    say as such (with its false positives), not print as a score."""
    folder, gt = ws / "cases" / "nothing", base["gt"]
    hyps = _scene_jsons(folder / "hyps", _as_results, gt)
    none = _scene_jsons(folder / "none", lambda e: [], gt)
    empty = _scene_jsons(folder / "empty_gt", lambda e: [], gt)
    hidden = _scene_jsons(folder / "occluded_gt", lambda e: [{**x, "occlusion_rate": 0.9} for x in e], gt)
    one = _scene_jsons(folder / "one_empty", lambda e: e, gt)
    first = min(one.glob("*.json"))
    first.write_text("[]")
    rows = [
        ("every scene empty, hypotheses in each", empty, hyps, "nothing to find in this split: AP is reported as 1.0 by convention, 6 false positives"),
        ("every scene empty, no hypothesis", empty, none, "nothing to find in this split: AP is reported as 1.0 by convention, 0 false positives"),
        ("every part occluded beyond max_occlusion", hidden, hyps, "nothing to find in this split"),
        ("one scene of three empty", one, hyps, "1 of 3 scenes had nothing to find (recall 1 there by convention), 1 false positives"),
    ]  # fmt: skip
    cases: list[Case] = []
    for name, g, r, says in rows:
        cases.append(Case("metric, nothing to find", name, True, run=lambda g=g, r=r: _evaluated(g, r), says=says))
    return cases


def scene_cases() -> list[Case]:
    """Generation settings out of bounds, as generate.py reads them (SceneConfig, then the rig): one line
    naming the key, before anything is written."""
    from opnet.objects import builtin_object
    from opnet.synthesis import SceneConfig
    from opnet.synthesis.layout import make_rig

    def rig(**values: Any) -> Any:
        return make_rig(builtin_object("zbracket"), 3, 1, SceneConfig(resolution=64, **values))

    nan = float("nan")
    rows: list[tuple[str, bool, dict[str, Any], str]] = [
        ("perforated basket (size 0.01, pitch 0.02)", True, {"bin_hole_size": 0.01, "bin_hole_pitch": 0.02}, ""),
        ("working area of 10 cm, camera raised to see it", True, {"bin_area": [-0.05, -0.05, 0.05, 0.05]}, ""),
        ("bin_hole_size -0.01", False, {"bin_hole_size": -0.01}, "bin_hole_size"),
        ("bin_hole_size NaN", False, {"bin_hole_size": nan}, "bin_hole_size"),
        ("bin_hole_size true", False, {"bin_hole_size": True}, "bin_hole_size"),
        ("bin_hole_size 0.1 mm", False, {"bin_hole_size": 0.0001, "bin_hole_pitch": 0.01}, "bin_hole_size"),
        ("bin_hole_size 0.01 without a pitch", False, {"bin_hole_size": 0.01}, "bin_hole_pitch"),
        ("bin_hole_pitch below bin_hole_size", False, {"bin_hole_size": 0.01, "bin_hole_pitch": 0.005}, "bin_hole_pitch"),
        ("bin_hole_pitch true", False, {"bin_hole_pitch": True}, "bin_hole_pitch"),
        ("bin_clearance -1", False, {"bin_clearance": -1.0}, "bin_clearance"),
        ("bin_clearance true", False, {"bin_clearance": True}, "bin_clearance"),
        ("bin_clearance 1000 m", False, {"bin_clearance": 1000.0}, "bin_clearance"),
        ("bin_clearance 'high'", False, {"bin_clearance": "high"}, "bin_clearance"),
        ("bin_inner_y 0", False, {"bin_inner_y": 0.0}, "bin_inner_y"),
        ("bin_inner_y -0.3", False, {"bin_inner_y": -0.3}, "bin_inner_y"),
        ("bin_inner_y true", False, {"bin_inner_y": True}, "bin_inner_y"),
        ("bin_inner_y 'abc'", False, {"bin_inner_y": "abc"}, "bin_inner_y"),
        ("bin_inner_y 100 m", False, {"bin_inner_y": 100.0}, "bin_inner_y"),
        ("camera_tilt_deg 90", False, {"camera_tilt_deg": 90.0}, "camera_tilt_deg"),
        ("camera_tilt_deg -5", False, {"camera_tilt_deg": -5.0}, "camera_tilt_deg"),
        ("camera_tilt_deg true", False, {"camera_tilt_deg": True}, "camera_tilt_deg"),
        ("camera_tilt_deg NaN", False, {"camera_tilt_deg": nan}, "camera_tilt_deg"),
        ("camera_tilt_deg 80 (above the horizon)", False, {"camera_tilt_deg": 80.0, "camera_height": 0.3}, "camera_tilt_deg"),
        ("camera_azimuth_deg true", False, {"camera_azimuth_deg": True}, "camera_azimuth_deg"),
        ("bin_area empty list", False, {"bin_area": []}, "bin_area"),
        ("bin_area reversed", False, {"bin_area": [0.1, 0.1, -0.1, -0.1]}, "bin_area"),
        ("bin_area [true, 0, 0, 0]", False, {"bin_area": [True, 0, 0, 0]}, "bin_area"),
        ("bin_area outside the camera's view", False, {"bin_area": [0.0, 0.0, 1.0, 1.0], "camera_height": 0.4}, "bin_area"),
        ("bin_area behind the camera's view", False, {"bin_area": [5.0, 5.0, 6.0, 6.0], "camera_height": 0.4}, "bin_area"),
        ("bin_area 200 m across (camera 232 m up)", False, {"bin_area": [-100.0, -100.0, 100.0, 100.0]}, "bin_area"),
        ("bin_yaw_deg empty list", False, {"bin_yaw_deg": []}, "bin_yaw_deg"),
        ("bin_yaw_deg reversed", False, {"bin_yaw_deg": [30.0, -30.0]}, "bin_yaw_deg"),
        ("bin_yaw_deg spanning 720", False, {"bin_yaw_deg": [0.0, 720.0]}, "bin_yaw_deg"),
        ("bin_yaw_deg [NaN, 1]", False, {"bin_yaw_deg": [nan, 1.0]}, "bin_yaw_deg"),
        ("bin_yaw_deg [true, false]", False, {"bin_yaw_deg": [True, False]}, "bin_yaw_deg"),
        ("resolution 64.5", False, {"resolution": 64.5}, "resolution"),
    ]  # fmt: skip
    cases: list[Case] = []
    for name, valid, values, key in rows:
        if "resolution" in values:
            _reader(cases, "scene settings", name, valid, lambda v=values: SceneConfig(**v), key)
        else:
            _reader(cases, "scene settings", name, valid, lambda v=values: rig(**v), *((key,) if key else ()))
    return cases


def input_cases(ws: Path, extra: dict[str, Path]) -> list[Case]:
    """Inputs foreign to the model and messages that mislead: depth frames outside the clip planes,
    regions of interest (tiny, negative, reversed, a bin finder on a frame with no bin), a BOP
    scene_camera.json as the camera, refinement settings of the newer options."""
    from omegaconf import OmegaConf

    from opnet.data.roi import parse_roi, resolve_box
    from opnet.datasets.camera_file import read_camera_file
    from opnet.datasets.depth_inputs import given_camera, load_depth_image
    from opnet.geometry.camera import Camera
    from opnet.refine import settings_from_config

    folder = ws / "cases" / "inputs"
    folder.mkdir(parents=True, exist_ok=True)
    cam = {"fx": 100, "fy": 100, "cx": 47.5, "cy": 47.5, "clip_start": 0.5, "clip_end": 1.5}
    frames = {
        "depth 1 m (between the planes)": (True, np.full((96, 96), 1.0, np.float32), ""),
        "no depth at all (0 objects, said so)": (True, np.full((96, 96), np.nan, np.float32), ""),
        "depth 5 m, beyond clip_end": (False, np.full((96, 96), 5.0, np.float32), "clip planes"),
        "depth 0.05 m, before clip_start": (False, np.full((96, 96), 0.05, np.float32), "clip planes"),
        "depth in millimetres": (False, np.full((96, 96), 1000.0, np.float32), "millimetres"),
    }
    cases: list[Case] = []
    for i, (name, (valid, depth, key)) in enumerate(frames.items()):
        path = folder / f"frame_{i}.npy"
        np.save(path, depth)
        _reader(cases, "depth frame", name, valid, lambda p=path: load_depth_image(p, cam), *((path.name, key) if key else ()))
    camera = Camera(100.0, 100.0, 47.5, 47.5, 96, 96, 0.5, 1.5)
    floor = np.full((96, 96), 2.0, np.float32)  # the floor beyond the far plane: nothing in the working volume
    rois: list[tuple[str, bool, Any, np.ndarray | None]] = [
        ("[8, 8, 88, 88]", True, [8, 8, 88, 88], None),
        ("16 x 16 box", True, [0, 0, 16, 16], None),
        ("2 x 2 box", False, [0, 0, 2, 2], None),
        ("15 x 40 box", False, [0, 0, 15, 40], None),
        ("negative origin", False, [-10, 0, 50, 50], None),
        ("reversed corners", False, [50, 50, 10, 10], None),
        ("x corners reversed", False, [50, 0, 10, 50], None),
        ("empty box (x0 = x1)", False, [10, 10, 10, 50], None),
        ("past the image", False, [0, 0, 1000, 1000], None),
        ("auto on a frame with no bin (the floor only)", False, "auto", floor),
        ("auto on a frame without depth", False, "auto", np.full((96, 96), np.nan, np.float32)),
        ("auto:0.3 on a frame with no bin", False, "auto:0.3", floor),
    ]
    for name, valid, value, depth in rois:
        _reader(cases, "region of interest", name, valid,
                lambda v=value, d=depth: resolve_box(parse_roi(v, "roi"), d, camera, "roi", "frame.npy"), "roi")
    scene_camera = extra["bop"] / "train_synt" / "000000" / "scene_camera.json"
    _reader(cases, "camera file", "BOP scene_camera.json (generate.py scene.camera_file)", False,
            lambda: read_camera_file(scene_camera), "a BOP scene_camera.json")
    _reader(cases, "camera file", "BOP scene_camera.json (predict.py camera.file)", False,
            lambda: given_camera({"file": str(scene_camera)}), "a BOP scene_camera.json")
    refine = {
        "icp, association projective": (True, "icp", {"association": "projective"}, ""),
        "search, polish_association nearest": (True, "search", {"polish_association": "nearest"}, ""),
        "icp.association closest": (False, "icp", {"association": "closest"}, "association"),
        "icp.association true": (False, "icp", {"association": True}, "association"),
        "icp.polish_association 5": (False, "search", {"polish_association": 5}, "polish_association"),
        "icp.polish_association 'closest'": (False, "search", {"polish_association": "closest"}, "polish_association"),
        "icp.stride 0": (False, "icp", {"stride": 0}, "stride"),
        "icp.stride 1.5": (False, "icp", {"stride": 1.5}, "stride"),
        "icp.stride true": (False, "icp", {"stride": True}, "stride"),
        "search.coarse 0": (False, "search", {"search": {"coarse": 0}}, "coarse"),
        "search.coarse 2.5": (False, "search", {"search": {"coarse": 2.5}}, "coarse"),
        "search.coarse true": (False, "search", {"search": {"coarse": True}}, "coarse"),
    }
    groups = {m: OmegaConf.to_container(OmegaConf.load(REPO_ROOT / "conf" / "refine" / f"{m}.yaml")) for m in ("icp", "search")}
    for name, (valid, method, change, key) in refine.items():
        group = json.loads(json.dumps(groups[method]))
        for section, values in ({"icp": change} if "search" not in change else change).items():
            group[section].update(values)
        _reader(cases, "refinement settings", name, valid, lambda g=group: settings_from_config(OmegaConf.create(g)),
                *((key,) if key else ()))
    return cases


MOUNTS: list[Path] = []


def full_disk(ws: Path, name: str, free_kb: int = 8) -> tuple[Path, str]:
    """A folder on a 1 MB tmpfs with ``free_kb`` left, and "" (or the folder and why there is none)."""
    mnt = ws / "full" / name
    why = _mount_tmpfs(mnt, "rw")
    if why:
        return mnt, why
    filler = mnt / "filler"
    with filler.open("wb") as f:
        try:
            f.write(b"\0" * (1024 - free_kb) * 1024)
        except OSError:
            pass
    return mnt, ""


def unmount_all() -> None:
    for mnt in MOUNTS:
        subprocess.run(["umount", str(mnt)], capture_output=True)
    MOUNTS.clear()


def leftovers(folder: Path) -> Callable[[], str]:
    """A check after the run: no temporary file or folder of a writer left in ``folder``."""
    def check() -> str:
        left = [p.name for p in folder.rglob("*") if p.name.endswith(".tmp")]
        return f"left {left[:3]}" if left else ""

    return check


def nothing_written(out: Path) -> Callable[[], str]:
    """A check after a refused run: it wrote no file into ``out``."""
    def check() -> str:
        written = sorted(p.name for p in out.rglob("*") if p.is_file()) if out.is_dir() else []
        return f"left {written[:3]} in {out.name}" if written else ""

    return check


def complete_predictions(out: Path, n: int) -> Callable[[], str]:
    """A check after concurrent runs: ``out`` holds the ``n`` pose files of one run, none lost."""
    def check() -> str:
        found = len([p for p in out.rglob("*.json") if p.parent.name != "results"])
        return "" if found == n else f"{found} of {n} pose files in {out.name}"

    return check


def cli_more_cases(ws: Path, base: dict[str, Path], extra: dict[str, Path]) -> list[Case]:
    """Command lines: outputs that are files or devices, bad camera YAMLs, mesh and object keys,
    edited checkpoints, full disks, concurrent runs into one folder."""
    import torch

    py = sys.executable
    data, ckpt, model = base["data"], base["ckpt"], extra["onnx"]
    png = data / "p_depth" / "cycle_0000" / "002_depth_uint16.png"
    pngs = data / "p_depth"
    n_pngs = len(list(pngs.rglob("*.png")))
    c = ws / "cases" / "cli2"
    c.mkdir(parents=True, exist_ok=True)
    h = lambda name: f"hydra.run.dir={ws / 'hydra' / name}"  # noqa: E731
    cam = ["camera.fx=100", "camera.fy=100", "camera.cx=47.5", "camera.cy=47.5", "camera.clip_start=0.5", "camera.clip_end=1.5"]
    dcam = ["--fx", "100", "--fy", "100", "--cx", "47.5", "--cy", "47.5", "--clip-start", "0.5", "--clip-end", "1.5"]
    np.save(c / "mm.npy", np.full((96, 96), 1000.0, np.float32))
    np.save(c / "ok.npy", np.full((96, 96), 1.0, np.float32))
    (c / "a_file").write_text("x")
    (c / "dup.yaml").write_text(CAMERA_YAML + "fx: 6\n")
    (c / "fxtrue.yaml").write_text(CAMERA_YAML.replace("fx: 100", "fx: true"))
    (c / "pp.yaml").write_text(CAMERA_YAML.replace("cx: 47.5", "cx: 500"))
    (c / "wide.yaml").write_text(CAMERA_YAML.replace("fx: 100", "fx: 0.0035"))
    os.mkfifo(c / "fifo.stl")
    os.mkfifo(c / "fifo.onnx")
    (c / "huge.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n"
                                 b"property float y\nproperty float z\nelement face 5000000\n"
                                 b"property list uchar int vertex_indices\nend_header\n")
    import trimesh

    inv = trimesh.creation.box((0.04, 0.03, 0.02))
    inv.invert()
    inv.export(c / "inside_out.ply")
    sd = torch.load(ckpt, map_location="cpu", weights_only=True)
    sd["hyper_parameters"]["config"]["data"]["input_size"] = "abc"
    torch.save(sd, c / "input_size.ckpt")
    torch.save([1, 2], c / "list.ckpt")
    nan_model = _onnx_with_meta(model, c / "nan_threshold.onnx",
                                lambda m: json.loads(json.dumps(m).replace('"threshold": ', '"threshold": NaN, "x": ')))
    gen = [py, "generate.py", "cycles=1", "drops=1", "scene.resolution=64", "previews=0", "progress=false"]
    predict = [py, "predict.py", f"ckpt={ckpt}"]
    deploy = [py, "-m", "opnet.deploy", str(model)]
    bop = [py, "-m", "opnet.datasets.bop", str(data)]
    bop_full = ws / "bop_nonempty"
    (bop_full / "keep").mkdir(parents=True, exist_ok=True)
    rows: list[tuple[str, str, bool, list[str], tuple[str, ...]]] = [
        ("predict.py", "out=/dev/null", False, [*predict, f"input={png}", "out=/dev/null", h("q1")], ("/dev/null",)),
        ("predict.py", "out= an existing file", False, [*predict, f"input={png}", f"out={c / 'a_file'}", h("q2")], ("a_file",)),
        ("predict.py", "out= the input PNG", False, [*predict, f"input={png}", f"out={png}", h("q3")], ("002_depth_uint16.png",)),
        ("predict.py", "camera.file with a duplicate key", False, [*predict, f"input={c / 'ok.npy'}", f"out={c / 'q4'}",
                                                                   f"camera.file={c / 'dup.yaml'}", h("q4")], ("dup.yaml",)),
        ("predict.py", "camera.file fx: true", False, [*predict, f"input={c / 'ok.npy'}", f"out={c / 'q5'}",
                                                       f"camera.file={c / 'fxtrue.yaml'}", h("q5")], ("fxtrue.yaml",)),
        ("predict.py", "camera.fx=true", False, [*predict, f"input={c / 'ok.npy'}", f"out={c / 'q6'}", "camera.fx=true",
                                                 *cam[1:], h("q6")], ("camera.fx",)),
        ("predict.py", "camera.fx=1e12", False, [*predict, f"input={c / 'ok.npy'}", f"out={c / 'q7'}", "camera.fx=1e12",
                                                 *cam[1:], h("q7")], ("camera.fx", "ok.npy")),
        ("predict.py", ".npy depth in millimetres", False, [*predict, f"input={c / 'mm.npy'}", f"out={c / 'q8'}", *cam, h("q8")], ("mm.npy",)),
        ("predict.py", "checkpoint a list", False, [py, "predict.py", f"ckpt={c / 'list.ckpt'}", f"input={png}",
                                                    f"out={c / 'q9'}", h("q9")], ("list.ckpt",)),
        ("predict.py", "checkpoint input_size 'abc'", False, [py, "predict.py", f"ckpt={c / 'input_size.ckpt'}", f"input={png}",
                                                              f"out={c / 'q10'}", h("q10")], ("input_size",)),
        ("export.py", "valid (no check)", True, [py, "export.py", f"ckpt={ckpt}", f"out={c / 'x1.onnx'}", "check=false", h("x1")], ()),
        ("export.py", "out=/dev/null overwrite=true", False, [py, "export.py", f"ckpt={ckpt}", "out=/dev/null", "overwrite=true",
                                                             "check=false", h("x2")], ("/dev/null",)),
        ("export.py", "out= a folder", False, [py, "export.py", f"ckpt={ckpt}", f"out={c}", "overwrite=true", "check=false", h("x3")], ("cli2",)),
        ("export.py", "out= an existing file", False, [py, "export.py", f"ckpt={ckpt}", f"out={c / 'a_file'}", "check=false", h("x4")], ("a_file",)),
        ("export.py", "out= the checkpoint", False, [py, "export.py", f"ckpt={ckpt}", f"out={ckpt}", "overwrite=true", h("x5")], ("last.ckpt",)),
        ("export.py", "format=tflite", False, [py, "export.py", f"ckpt={ckpt}", "format=tflite", h("x6")], ("format",)),
        ("python -m opnet.deploy", "valid .npy", True, [*deploy, str(c / "ok.npy"), "--out", str(c / "d1"), *dcam], ()),
        ("python -m opnet.deploy", "--threads 20000", False, [*deploy, str(c / "ok.npy"), "--out", str(c / "d2"), *dcam,
                                                             "--threads", "20000"], ("threads",)),
        ("python -m opnet.deploy", "model a FIFO", False, [py, "-m", "opnet.deploy", str(c / "fifo.onnx"), str(c / "ok.npy"),
                                                          "--out", str(c / "d3"), *dcam], ("fifo.onnx",)),
        ("python -m opnet.deploy", "--out /dev/null", False, [*deploy, str(c / "ok.npy"), "--out", "/dev/null", *dcam], ("/dev/null",)),
        ("python -m opnet.deploy", "metadata threshold NaN", False, [py, "-m", "opnet.deploy", str(nan_model), str(c / "ok.npy"),
                                                                    "--out", str(c / "d4"), *dcam], ("threshold",)),
        ("python -m opnet.deploy", ".npy depth in millimetres", False, [*deploy, str(c / "mm.npy"), "--out", str(c / "d5"), *dcam], ("mm.npy",)),
        ("python -m opnet.deploy", "--camera with a duplicate key", False, [*deploy, str(c / "ok.npy"), "--out", str(c / "d6"),
                                                                           "--camera", str(c / "dup.yaml")], ("dup.yaml",)),
        ("python -m opnet.deploy", "--fx 1e-9", False, [*deploy, str(c / "ok.npy"), "--out", str(c / "d7"), "--fx", "1e-9",
                                                       *dcam[2:]], ("ok.npy", "fx")),
        ("generate.py", "seed=-1", False, [*gen, "seed=-1", f"out={c / 'g1'}", h("g1")], ("seed",)),
        ("generate.py", "seed=abc", False, [*gen, "seed=abc", f"out={c / 'g2'}", h("g2")], ("seed",)),
        ("generate.py", "out=/dev/null", False, [*gen, "out=/dev/null", h("g3")], ("/dev/null",)),
        ("generate.py", "out= an existing file", False, [*gen, f"out={c / 'a_file'}", h("g4")], ("a_file",)),
        ("generate.py", "object.mesh_scale=abc", False, [*gen, "object=bunny", f"object.mesh={c / 'inside_out.ply'}",
                                                        "object.mesh_scale=abc", f"out={c / 'g5'}", h("g5")], ("mesh_scale",)),
        ("generate.py", "object.symmetry=[revolution]", False, [*gen, "object=bunny", f"object.mesh={c / 'inside_out.ply'}",
                                                               "~object.symmetry", "+object.symmetry=[revolution]",
                                                               f"out={c / 'g6'}", h("g6")], ("symmetry",)),
        ("generate.py", "object.mesh= a FIFO", False, [*gen, "object=bunny", f"object.mesh={c / 'fifo.stl'}", f"out={c / 'g7'}",
                                                      h("g7")], ("fifo.stl",)),
        ("generate.py", "object.mesh= 5 million faces", False, [*gen, "object=bunny", f"object.mesh={c / 'huge.ply'}",
                                                               f"out={c / 'g8'}", h("g8")], ("huge.ply",)),
        ("generate.py", "inside-out mesh (repaired)", True, [*gen, "object=bunny", f"object.mesh={c / 'inside_out.ply'}",
                                                            f"out={c / 'g9'}", h("g9")], ()),
        ("generate.py", "scene.camera_file duplicate key", False, [*gen, f"scene.camera_file={c / 'dup.yaml'}", f"out={c / 'g10'}",
                                                                  h("g10")], ("dup.yaml",)),
        ("generate.py", "scene.camera_file fx: true", False, [*gen, f"scene.camera_file={c / 'fxtrue.yaml'}", f"out={c / 'g11'}",
                                                             h("g11")], ("fxtrue.yaml",)),
        ("generate.py", "scene.camera_file principal point outside", False, [*gen, f"scene.camera_file={c / 'pp.yaml'}",
                                                                            f"out={c / 'g12'}", h("g12")], ("pp.yaml",)),
        ("generate.py", "scene.camera_file fx 0.0035", False, [*gen, f"scene.camera_file={c / 'wide.yaml'}", f"out={c / 'g13'}",
                                                              h("g13")], ("wide.yaml",)),
        ("BOP writer", "valid", True, [*bop, str(c / "b1")], ()),
        ("BOP writer", "--obj-id -1", False, [*bop, str(c / "b2"), "--obj-id", "-1"], ("obj-id",)),
        ("BOP writer", "--obj-id 0", False, [*bop, str(c / "b3"), "--obj-id", "0"], ("obj-id",)),
        ("BOP writer", "--obj-id 1.5", False, [*bop, str(c / "b4"), "--obj-id", "1.5"], ("obj-id",)),
        ("BOP writer", "non-empty out without --overwrite", False, [*bop, str(bop_full)], ("bop_nonempty",)),
        ("BOP writer", "out= the input dataset", False, [*bop, str(data)], ("data",)),
        ("BOP writer", "out=/dev/null", False, [*bop, "/dev/null"], ("/dev/null",)),
        ("BOP writer", "input not a dataset", False, [py, "-m", "opnet.datasets.bop", str(c), str(c / "b5")], ("cli2",)),
    ]  # fmt: skip
    cases = [Case(f, n, v, argv=a, names=names, status=_documented_status(n)) for f, n, v, a, names in rows]
    for case in cases:  # a refused camera leaves no dataset files behind to blame later
        if "scene.camera_file" in case.name:
            case.after = nothing_written(Path(next(a for a in case.argv or [] if a.startswith("out="))[4:]))
    # --- full disks: a 1 MB tmpfs with 8 kB free for each writer
    disk = [
        ("export.py", lambda d: [py, "export.py", f"ckpt={ckpt}", f"out={d / 'm.onnx'}", "check=false", h("f1")]),
        ("predict.py", lambda d: [*predict, f"input={pngs}", f"out={d / 'p'}", h("f2")]),
        ("python -m opnet.deploy", lambda d: [*deploy, str(pngs), "--out", str(d / "p")]),
        ("generate.py", lambda d: [*gen, f"out={d / 'g'}", h("f4")]),
        ("BOP writer", lambda d: [*bop, str(d / "b")]),
    ]
    for i, (family, argv) in enumerate(disk):
        mnt, why = full_disk(ws, f"full_{i}")
        cases.append(Case(family, "disk full (1 MB tmpfs)", False, argv=argv(mnt), names=(mnt.name,), skip=why,
                          after=leftovers(mnt), status=2))
    # --- concurrent writers into one folder: one run must stop, naming it; nothing lost
    conc = ws / "concurrent"
    cases.append(Case("predict.py", "two runs into one out at once", False, names=("c1",), status=2,
                      concurrent=[[*predict, f"input={pngs}", f"out={conc / 'c1'}", h(f"c1{k}")] for k in "ab"],
                      after=complete_predictions(conc / "c1", n_pngs)))
    cases.append(Case("python -m opnet.deploy", "two runs into one --out at once", False, names=("c2",), status=2,
                      concurrent=[[*deploy, str(pngs), "--out", str(conc / "c2")] for _ in "ab"],
                      after=complete_predictions(conc / "c2", n_pngs)))
    cases.append(Case("BOP writer", "two writers (obj 1 and 2) into one folder at once", False, names=("c3",), status=2,
                      concurrent=[[*bop, str(conc / "c3"), "--obj-id", k] for k in "12"]))
    return cases


def _mount_tmpfs(mnt: Path, options: str) -> str:
    """Mount a 1 MB tmpfs with ``options`` at ``mnt``: "" or why not (then the case is skipped)."""
    mnt.mkdir(parents=True, exist_ok=True)
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"{options},size=1m", "tmpfs", str(mnt)],
                          capture_output=True, text=True)  # fmt: skip
    if proc.returncode != 0:
        return f"no tmpfs here ({(proc.stderr.strip() or 'mount failed')[:80]}): not run"
    MOUNTS.append(mnt)
    return ""


def present(folder: Path, pattern: str, n: int) -> Callable[[], str]:
    """A check after concurrent runs: ``folder`` holds ``n`` files matching ``pattern``, the one run's, none lost."""
    def check() -> str:
        found = len(list(folder.glob(pattern)))
        return "" if found == n else f"{found} of {n} {pattern} in {folder.name}"

    return check


def cli_defect_cases(ws: Path, base: dict[str, Path], extra: dict[str, Path]) -> list[Case]:
    """Command lines of each kind of defect: decoding overrides, booleans in checkpoints and ONNX
    metadata, ground truth the dataset check must report, a split with nothing to find, two writers
    into one folder, the checkpoint tools, generation settings, inputs foreign to the model, messages
    that mislead, the refinement's newer options and opnet-object. A refusal exits with the status the
    command documents (2; 1 for predict.py's failed images and the dataset check's problems) and
    writes nothing."""
    import pickle

    import torch
    import trimesh

    py = sys.executable
    data, ckpt, model, bop = base["data"], base["ckpt"], extra["onnx"], extra["bop"]
    c = ws / "cases" / "cli3"
    c.mkdir(parents=True, exist_ok=True)
    h = lambda name: f"hydra.run.dir={ws / 'hydra' / name}"  # noqa: E731
    png = data / "p_depth" / "cycle_0000" / "002_depth_uint16.png"
    cam = ["camera.fx=100", "camera.fy=100", "camera.cx=47.5", "camera.cy=47.5", "camera.clip_start=0.5", "camera.clip_end=1.5"]
    dcam = ["--fx", "100", "--fy", "100", "--cx", "47.5", "--cy", "47.5", "--clip-start", "0.5", "--clip-end", "1.5"]
    for name, metres in (("far", 5.0), ("near", 0.05), ("wall", 1.0)):
        np.save(c / f"{name}.npy", np.full((96, 96), metres, np.float32))
    ck = torch.load(ckpt, map_location="cpu", weights_only=True)
    for name, key, value in (("clip_true", "trained_clip", True), ("clip_pair", "trained_clip", [True, False]),
                             ("size_true", "data.input_size", True), ("size_false", "data.input_size", False),
                             ("nodata", "data.root", str(ws / "gone")), ("roi_auto", "data.roi", "auto")):  # fmt: skip
        _ckpt_with(ck, c / f"{name}.ckpt", key, value)
    for name, key, value in (("clip_true", "trained_clip", True), ("size_true", "input.size", True),
                             ("avg_true", "decoding.averaging", True)):  # fmt: skip
        _onnx_with_meta(model, c / f"{name}.onnx", _nested_set(key, value))
    (c / "text.ckpt").write_text("a checkpoint in name only\n")
    (c / "code.ckpt").write_bytes(pickle.dumps({"state_dict": Path("x")}))
    (c / "folder.ckpt").mkdir(exist_ok=True)
    os.mkfifo(c / "fifo.yaml")
    (c / "text.stl").write_text("these are not triangles\n")
    (c / "empty.obj").write_bytes(b"")
    box = trimesh.creation.box((0.04, 0.03, 0.02))
    box.export(c / "box.obj")
    trimesh.Trimesh(box.vertices, box.faces[:-2], process=False).export(c / "open.obj")
    read_only = ws / "readonly"
    no_ro = _mount_tmpfs(read_only, "ro")
    scene_camera = bop / "train_synt" / "000000" / "scene_camera.json"
    split = bop / "train_synt"
    mask_gone = _bop_edited(ws, bop, "cli_mask", lambda s: (s / "000000/mask_visib/000003_000001.png").unlink())
    duplicate = _bop_edited(ws, bop, "cli_dup", _duplicate_last_instance)
    no_rotation = _bop_edited(ws, bop, "cli_w2c", _camera_world(np.diag([2.0, 2.0, 2.0]).reshape(-1).tolist()))
    nothing = ws / "cases" / "nothing"  # empty_metric_cases' folders, made again if run alone
    gt, hyps = _scene_jsons(nothing / "empty_gt", lambda e: [], base["gt"]), _scene_jsons(nothing / "hyps", _as_results, base["gt"])
    empty_ds = ws / "cases" / "empty_dataset"
    shutil.copytree(data, empty_ds, ignore=shutil.ignore_patterns("cache_*"))
    for path in (empty_ds / "gt").rglob("*.csv"):  # every scene holds no part
        path.write_text(path.read_text().splitlines()[0] + "\n")

    predict = [py, "predict.py", f"ckpt={ckpt}", f"input={png}"]
    evaluate = [py, "eval.py", f"ckpt={ckpt}", "examples=0"]
    gen = [py, "generate.py", "cycles=1", "drops=1", "scene.resolution=64", "previews=0", "progress=false"]
    deploy = [py, "-m", "opnet.deploy", str(model)]
    check = [py, "-m", "opnet.datasets.check"]
    record = [py, "-m", "opnet.tools.record_trained_clip"]
    tune = [py, "-m", "opnet.tools.tune_decoding", "--rounds", "1"]
    export = [py, "export.py", "check=false"]
    obj = ["opnet-object"]
    cases: list[Case] = []
    numbers = iter(range(10_000))

    def add(family: str, name: str, valid: bool, argv: list[str], names: tuple[str, ...] = (), status: int = 2,
            out: Path | None = None, says: str = "", skip: str = "") -> None:  # fmt: skip
        """A command line; a refusal must exit with ``status`` and write nothing into ``out``."""
        after = nothing_written(out) if out is not None and not valid else None
        cases.append(Case(family, name, valid, argv=argv, names=names, status=status, says=says, skip=skip, after=after))

    def o(tag: str) -> Path:
        """A fresh output folder (and Hydra run directory name) of a case."""
        return c / f"{tag}{next(numbers)}"

    # 1. decoding overrides on the command line
    for override, key in (("+decoding.threshold=1.5", "decoding.threshold"), ("+decoding.threshold=nan", "decoding.threshold"),
                          ("+decoding.threshold=true", "decoding.threshold"), ("+decoding.threshold=abc", "decoding.threshold"),
                          ("+decoding.min_visibility=-0.1", "decoding.min_visibility"), ("+decoding.min_visibility=1", "decoding.min_visibility"),
                          ("+decoding.averaging=5", "decoding.averaging"), ("+decoding.score=magic", "decoding.score"),
                          ("+decoding.colour=red", "colour"), ("+decoding.averaging.eps=-1", "eps")):  # fmt: skip
        out = o("p")
        add("predict.py", override, False, [*predict, f"out={out}", override, h(out.name)], (key,), out=out)
    for override, key in (("+decoding.threshold=-1", "decoding.threshold"), ("+decoding.score=null", "decoding.score"),
                          ("+decoding.averaging.min_samples=0", "min_samples"), ("+decoding.averaging.foo=1", "foo")):  # fmt: skip
        out = o("e")
        add("eval.py", override, False, [*evaluate, f"out={out}", override, h(out.name)], (key,), out=out)
    out = o("p")
    add("predict.py", "+decoding.threshold=0.3 +decoding.averaging=false", True,
        [*predict, f"out={out}", "+decoding.threshold=0.3", "+decoding.averaging=false", h(out.name)])
    # 2. booleans read as numbers
    for name, key in (("clip_true", "trained_clip"), ("clip_pair", "trained_clip"), ("size_true", "input_size"),
                      ("size_false", "input_size")):  # fmt: skip
        out = o("p")
        add("predict.py", f"checkpoint {key} {name.split('_')[1]}", False,
            [py, "predict.py", f"ckpt={c / f'{name}.ckpt'}", f"input={png}", f"out={out}", h(out.name)], (key,), out=out)
    for name, key in (("clip_true", "trained_clip"), ("size_true", "input.size"), ("avg_true", "decoding.averaging")):
        out = o("d")
        add("python -m opnet.deploy", f"metadata {key} true", False,
            [py, "-m", "opnet.deploy", str(c / f"{name}.onnx"), str(c / "wall.npy"), "--out", str(out), *dcam], (key,), out=out)
    out = o("e")
    add("eval.py", "checkpoint trained_clip true", False, [py, "eval.py", f"ckpt={c / 'clip_true.ckpt'}", f"out={out}", h(out.name)],
        ("trained_clip",), out=out)
    # 3. ground truth integrity: the dataset check reports (exit 1), naming the file
    add("dataset check", "BOP split (valid)", True, [*check, str(split), "--object-id", "1"])
    add("dataset check", "BOP instance's mask_visib file deleted", False, [*check, str(mask_gone), "--object-id", "1"],
        ("000003_000001.png",), status=1)
    add("dataset check", "BOP instance's mask_visib file deleted (--fast)", False,
        [*check, str(mask_gone), "--object-id", "1", "--fast"], ("000003_000001.png",), status=1)
    add("dataset check", "BOP duplicate instance", False, [*check, str(duplicate), "--object-id", "1"], ("duplicates",), status=1)
    add("dataset check", "BOP cam_R_w2c not a rotation", False, [*check, str(no_rotation), "--object-id", "1"], ("cam_R_w2c",), status=1)
    out = o("e")
    add("eval.py", "BOP instance's mask_visib file deleted", False,
        [*evaluate, f"out={out}", f"data.test_root={mask_gone}", "+data.object_id=1", h(out.name)], ("000003_000001.png",), out=out)
    # 4. the metric's empty case
    add("opnet-evaluate", "every scene with nothing to find", True,
        ["opnet-evaluate", "--gt", str(gt), "--results", str(hyps), "--object", "zbracket"],
        says="nothing to find in this split: AP is reported as 1.0 by convention, 6 false positives")
    out = o("e")
    add("eval.py", "a test split with nothing to find", True, [*evaluate, f"out={out}", f"data.test_root={empty_ds}", h(out.name)],
        says="nothing to find in this split: AP is reported as 1.0 by convention")
    # 6. the checkpoint tools
    skip_ro = no_ro
    add("record_trained_clip.py", "valid (a copy)", True, [*record, str(ckpt), "--write", str(c / "recorded.ckpt")])
    add("record_trained_clip.py", "not a checkpoint", False, [*record, str(c / "text.ckpt"), "--write", str(c / "r1.ckpt")],
        ("text.ckpt",), out=c / "r1.ckpt")
    add("record_trained_clip.py", "a pickle holding code", False, [*record, str(c / "code.ckpt"), "--write", str(c / "r2.ckpt")],
        ("code.ckpt",), out=c / "r2.ckpt")
    add("record_trained_clip.py", "training dataset missing", False, [*record, str(c / "nodata.ckpt"), "--write", str(c / "r3.ckpt")],
        ("gone",), out=c / "r3.ckpt")
    add("record_trained_clip.py", "--write a folder", False, [*record, str(ckpt), "--write", str(c / "folder.ckpt")], ("folder.ckpt",),
        out=c / "folder.ckpt")
    add("record_trained_clip.py", "--write into a read-only folder", False, [*record, str(ckpt), "--write", str(read_only / "r.ckpt")],
        ("readonly",), out=read_only, skip=skip_ro)
    add("tune_decoding.py", "not a checkpoint", False, [*tune, "--ckpt", str(c / "text.ckpt"), "--out", str(c / "t1")], ("text.ckpt",),
        out=c / "t1")
    add("tune_decoding.py", "training dataset missing", False, [*tune, "--ckpt", str(c / "nodata.ckpt"), "--out", str(c / "t2")],
        ("gone",), out=c / "t2")
    add("tune_decoding.py", "--write a folder", False, [*tune, "--ckpt", str(ckpt), "--out", str(c / "t3"), "--write",
                                                         str(c / "folder.ckpt")], ("folder.ckpt",), out=c / "t3")
    add("tune_decoding.py", "--out a read-only folder", False, [*tune, "--ckpt", str(ckpt), "--out", str(read_only / "t")],
        ("readonly",), out=read_only, skip=skip_ro)
    add("tune_decoding.py", "--write into a read-only folder", False, [*tune, "--ckpt", str(ckpt), "--out", str(c / "t4"), "--write",
                                                                      str(read_only / "t.ckpt")], ("readonly",), out=c / "t4", skip=skip_ro)
    add("export.py", "not a checkpoint", False, [*export, f"ckpt={c / 'text.ckpt'}", f"out={c / 'x1.onnx'}", h("x1")], ("text.ckpt",))
    add("export.py", "a pickle holding code", False, [*export, f"ckpt={c / 'code.ckpt'}", f"out={c / 'x2.onnx'}", h("x2")], ("code.ckpt",))
    add("export.py", "training dataset missing (not needed)", True, [*export, f"ckpt={c / 'nodata.ckpt'}", f"out={c / 'x3.onnx'}", h("x3")])
    add("export.py", "out= a folder", False, [*export, f"ckpt={ckpt}", f"out={c / 'folder.ckpt'}", h("x4")], ("folder.ckpt",),
        out=c / "folder.ckpt")
    add("export.py", "out= a read-only folder", False, [*export, f"ckpt={ckpt}", f"out={read_only / 'm.onnx'}", h("x5")], ("readonly",),
        out=read_only, skip=skip_ro)
    # 7. generation settings out of bounds: one line naming the key, nothing written
    for override, key in (("scene.bin_hole_size=-0.01", "bin_hole_size"), ("scene.bin_hole_size=true", "bin_hole_size"),
                          ("scene.bin_clearance=-1", "bin_clearance"), ("scene.bin_clearance=true", "bin_clearance"),
                          ("scene.bin_clearance=1000", "bin_clearance"), ("scene.bin_inner_y=0", "bin_inner_y"),
                          ("scene.bin_inner_y=true", "bin_inner_y"), ("scene.bin_inner_y=abc", "bin_inner_y"),
                          ("scene.camera_tilt_deg=90", "camera_tilt_deg"), ("scene.camera_tilt_deg=true", "camera_tilt_deg"),
                          ("scene.bin_area=[]", "bin_area"), ("scene.bin_area=[0.1,0.1,-0.1,-0.1]", "bin_area"),
                          ("scene.bin_area=[-100,-100,100,100]", "bin_area"), ("scene.bin_yaw_deg=[]", "bin_yaw_deg"),
                          ("scene.bin_yaw_deg=[30,-30]", "bin_yaw_deg"), ("scene.resolution=64.5", "resolution")):  # fmt: skip
        out = o("g")
        add("generate.py", override, False, [*gen, override, f"out={out}", h(out.name)], (key,), out=out)
    out = o("g")
    add("generate.py", "a working area outside the camera's view", False,
        [*gen, "scene.camera_height=0.4", "scene.bin_area=[0,0,1,1]", f"out={out}", h(out.name)], ("bin_area",), out=out)
    # 8. input foreign to the model (predict.py: a failed image is named on its line, exit 1)
    for name, why in (("far", "beyond clip_end"), ("near", "before clip_start")):
        out = o("p")
        add("predict.py", f"depth frame wholly {why}", False, [py, "predict.py", f"ckpt={ckpt}", f"input={c / f'{name}.npy'}",
                                                               f"out={out}", *cam, h(out.name)], (f"{name}.npy",), status=1, out=out)
    out = o("d")
    add("python -m opnet.deploy", "depth frame wholly beyond clip_end", False, [*deploy, str(c / "far.npy"), "--out", str(out), *dcam],
        ("far.npy",), status=1, out=out)
    out = o("p")
    add("predict.py", "roi=[0,0,2,2] (a 2 x 2 box)", False, [*predict, f"out={out}", "roi=[0,0,2,2]", h(out.name)], ("2 x 2",), out=out)
    out = o("d")
    add("python -m opnet.deploy", "--roi 0,0,2,2", False, [*deploy, str(c / "wall.npy"), "--out", str(out), *dcam, "--roi", "0,0,2,2"],
        ("2 x 2",), out=out)
    out = o("p")
    add("predict.py", "roi=auto on a frame with no bin", False, [py, "predict.py", f"ckpt={ckpt}", f"input={c / 'wall.npy'}",
                                                                f"out={out}", *cam, "roi=auto", h(out.name)], ("wall.npy", "roi"), status=1, out=out)
    out = o("p")
    # the config edited alone: its settings entry (what runs) records no region of interest
    add("predict.py", "checkpoint data.roi=auto in its config alone", False,
        [py, "predict.py", f"ckpt={c / 'roi_auto.ckpt'}", f"input={c / 'wall.npy'}", f"out={out}", *cam, h(out.name)],
        ("roi_auto.ckpt", "data.roi"), out=out)
    add("export.py", "out= a new .ckpt", False, [*export, f"ckpt={ckpt}", f"out={c / 'model.ckpt'}", h("x6")], (".ckpt",),
        out=c / "model.ckpt")
    # 9. messages that mislead
    for roi, why in (("[-10,0,50,50]", "starts at pixel"), ("[50,50,10,10]", "corners are reversed")):
        out = o("p")
        add("predict.py", f"roi={roi}", False, [*predict, f"out={out}", f"roi={roi}", h(out.name)], (why,), out=out)
    out = o("d")
    add("python -m opnet.deploy", "--roi -10,0,50,50", False, [*deploy, str(c / "wall.npy"), "--out", str(out), *dcam, "--roi=-10,0,50,50"],
        ("starts at pixel",), out=out)
    add("dataset check", "--clip reversed (BOP split)", False, [*check, str(split), "--object-id", "1", "--clip", "1.5", "0.5"], ("--clip",))
    add("dataset check", "--clip reversed (IPA dataset)", False, [*check, str(data), "--clip", "1.5", "0.5"], ("--clip",))
    out = o("p")
    add("predict.py", "camera.file= a BOP scene_camera.json", False, [py, "predict.py", f"ckpt={ckpt}", f"input={c / 'wall.npy'}",
                                                                      f"out={out}", f"camera.file={scene_camera}", h(out.name)],
        ("a BOP scene_camera.json",), out=out)
    out = o("g")
    add("generate.py", "scene.camera_file= a BOP scene_camera.json", False, [*gen, f"scene.camera_file={scene_camera}", f"out={out}",
                                                                             h(out.name)], ("a BOP scene_camera.json",), out=out)
    out = o("d")
    add("python -m opnet.deploy", "--camera a BOP scene_camera.json", False, [*deploy, str(c / "wall.npy"), "--out", str(out), "--camera",
                                                                            str(scene_camera)], ("a BOP scene_camera.json",), out=out)
    out = o("t")
    add("train.py", "data.input_size=256 without model.in_size", False,
        [py, "train.py", "model=tiny", "object=zbracket", f"data.root={data}", "data.generate=null", "data.input_size=256",
         f"hydra.run.dir={out}"], ("model.in_size",))  # fmt: skip
    # the refinement's newer options
    for group, override, key in (("icp", "refine.icp.association=closest", "association"),
                                 ("search", "refine.icp.polish_association=5", "polish_association"),
                                 ("icp", "refine.icp.stride=0", "stride"), ("search", "refine.search.coarse=0", "coarse")):  # fmt: skip
        out = o("p")
        add("predict.py", f"refine={group} {override}", False, [*predict, f"out={out}", f"refine={group}", override, h(out.name)],
            (key,), out=out)
    out = o("e")
    add("eval.py", "refine=icp refine.icp.association=closest", False,
        [*evaluate, f"out={out}", "refine=icp", "refine.icp.association=closest", h(out.name)], ("association",), out=out)
    out = o("p")
    add("predict.py", "refine=icp refine.icp.association=projective", True,
        [*predict, f"out={out}", "refine=icp", "refine.icp.association=projective", h(out.name)])
    # opnet-object
    add("opnet-object", "a box", True, [*obj, str(c / "box.obj"), "--out", str(c / "box.yaml")])
    add("opnet-object", "not watertight (read as a surface)", True, [*obj, str(c / "open.obj"), "--out", str(c / "open.yaml")],
        says="not watertight")
    for name, why in (("text.stl", "not a mesh"), ("empty.obj", "not a mesh"), ("gone.obj", "file not found")):
        out = o("y")
        add("opnet-object", f"{name} ({why})", False, [*obj, str(c / name), "--out", str(out / "x.yaml")], (name,), out=out)
    for name, target in (("--out a folder", c / "folder.ckpt"), ("--out a FIFO", c / "fifo.yaml")):
        add("opnet-object", name, False, [*obj, str(c / "box.obj"), "--out", str(target), "--force"], (target.name,))
    add("opnet-object", "--out into a read-only folder", False, [*obj, str(c / "box.obj"), "--out", str(read_only / "x.yaml")],
        ("readonly",), out=read_only, skip=skip_ro)
    # 5. two writers into one folder: the second stops at once, exit 2, naming the folder; nothing lost
    conc = ws / "concurrent"
    train = [py, "train.py", "model=tiny", "object=zbracket", f"data.root={data}", "data.generate=null", "data.batch_size=4",
             "trainer.max_epochs=1", "+trainer.limit_train_batches=2", "+trainer.limit_val_batches=1", "test=false",
             "trainer.enable_progress_bar=false", "example_predictions=0", f"hydra.run.dir={conc / 'c6'}"]  # fmt: skip
    cases.append(Case("generate.py", "two runs into one out at once", False, names=("c4",), status=2,
                      concurrent=[[*gen, "cycles=2", f"out={conc / 'c4'}", h(f"c4{x}")] for x in "ab"],
                      after=present(conc / "c4", "gt/*/*.csv", 4)))
    slow = ["refine=search", "+decoding.threshold=0", "+decoding.averaging=false"]  # every cell searched: seconds, not one
    cases.append(Case("eval.py", "two runs into one out at once", False, names=("c5",), status=2,
                      concurrent=[[*evaluate, f"out={conc / 'c5'}", *slow, h(f"c5{x}")] for x in "ab"],
                      after=present(conc / "c5", "summary.json", 1)))
    cases.append(Case("train.py", "two runs into one run directory at once", False, names=("c6",), status=2,
                      concurrent=[train, train], after=present(conc / "c6", "checkpoints/last.ckpt", 1)))
    return cases


# ------------------------------------------------------------------------------------------ running


# --------------------------------------------------------------- the newer tools, in-process


def _as_command(call: Callable[[], Any], status: int) -> str:
    """Run a command's entry (a console tool's ``main``, a script as ``__main__``) in this forked child as
    its command line would run, and classify it as :func:`run_cli` does: an exit of 0 returns the text it
    printed; a refusal must exit with ``status`` and print its error on one line (``error: ...``), raised as
    a ValueError of that line; a traceback, another exit status or an error on several lines is a
    RuntimeError (a bug)."""
    import contextlib
    import io

    out, err, code = io.StringIO(), io.StringIO(), 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = call() or 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    text = out.getvalue() + err.getvalue()
    if "Traceback" in text:
        raise RuntimeError(text.strip().splitlines()[-1][:200])
    errors = [line for line in text.splitlines() if line.lower().startswith("error") and "HYDRA_FULL_ERROR" not in line]
    if code == 0 and not errors:
        return text
    if code != status:
        raise RuntimeError(f"exit status {code}, expected {status}: {(errors or text.strip().splitlines() or [''])[-1][:200]}")
    if not errors or (status == 2 and len(errors) > 1):
        raise RuntimeError(f"exit status {code} with {len(errors)} error lines: {text.strip()[-300:]}")
    raise ValueError(errors[-1])


def _tool(module: str, argv: list[str]) -> Callable[[], Callable[[], Any]]:
    """A console tool (``opnet.tools.oracle`` ...) called as its entry point calls it."""
    def call() -> Any:
        import importlib

        return importlib.import_module(module).main(argv)

    return call


def _script(script: str, argv: list[str]) -> Callable[[], Any]:
    """``python <script> <argv>`` (``-m <module>`` for a module name) in this process."""
    def call() -> Any:
        import runpy

        sys.argv = [script, *argv]
        if script.endswith(".py"):
            runpy.run_path(str(REPO_ROOT / script), run_name="__main__")
        else:
            runpy.run_module(script, run_name="__main__", alter_sys=True)

    return call


def new_surface_cases(ws: Path, base: dict[str, Path], extra: dict[str, Path]) -> list[Case]:
    """The surfaces new since the last pass, each entry run in a forked child as its command would run
    (:func:`_as_command`): the object tool's paths and numbers, the console tools' arguments (opnet-oracle,
    opnet-diagnose-sources, opnet-tune-decoding, opnet-record-trained-clip, opnet-compare-runs, opnet-cell),
    training's overrides (train.py, refused before it trains) and the bin finder's crop ``roi=auto:S``
    (predict.py, eval.py, the ONNX runtime). A refusal exits 2 (1 for predict.py's failed image), names the
    option, key or file on one line and writes nothing."""
    import pickle

    import trimesh

    data, ckpt, model = base["data"], base["ckpt"], extra["onnx"]
    c = ws / "cases" / "new"
    c.mkdir(parents=True, exist_ok=True)
    cases: list[Case] = []
    numbers = iter(range(10_000))

    def o(tag: str) -> Path:
        return c / f"{tag}{next(numbers)}"

    def add(family: str, name: str, valid: bool, call: Callable[[], Any], names: tuple[str, ...] = (), status: int = 2,
            out: Path | None = None, says: str = "", timeout: float = 60.0) -> None:  # fmt: skip
        after = nothing_written(out) if out is not None and not valid else None
        cases.append(Case(family, name, valid, run=lambda: _as_command(call, status), names=names, after=after,
                          says=says, timeout=timeout))

    # files the cases hand over
    box = trimesh.creation.box((0.04, 0.03, 0.02))
    box.export(c / "box.stl")
    (c / "box_link.stl").symlink_to(c / "box.stl")
    trimesh.Trimesh(box.vertices * 1e-9, box.faces, process=False).export(c / "nano.stl")
    trimesh.Trimesh(np.zeros_like(box.vertices) + 0.01, box.faces, process=False).export(c / "point.stl")
    trimesh.Trimesh(box.vertices * 1e6, box.faces, process=False).export(c / "huge.stl")
    (c / "kept.yaml").write_text("kept: true\n")
    (c / "replaced.yaml").write_text("replaced: true\n")
    (c / "a_file").write_text("kept\n")
    (c / "folder.stl").mkdir()
    os.mkfifo(c / "fifo.stl")
    (c / "text.ckpt").write_text("a checkpoint in name only\n")
    (c / "code.ckpt").write_bytes(pickle.dumps({"state_dict": Path("x")}))
    (c / "empty").mkdir()
    shutil.copy(ckpt, c / "copy.ckpt")
    png = data / "p_depth" / "cycle_0000" / "002_depth_uint16.png"
    camera = c / "camera.yaml"
    camera.write_text("fx: 100\nfy: 100\ncx: 47.5\ncy: 47.5\nwidth: 96\nheight: 96\nclip_start: 0.5\nclip_end: 1.5\n")

    # 1. opnet-object: where it writes, and the numbers it takes
    def obj(name: str, valid: bool, argv: list[str], names: tuple[str, ...] = (), out: Path | None = None) -> None:
        add("opnet-object", name, valid, _tool("opnet.cli.object", argv), names, out=out, timeout=120.0)

    mesh = str(c / "box.stl")
    for name in ("../x", "../../../../elsewhere/x", "a/b", "/tmp/x", "..", ".", "x/../../y", "x\\..\\y", "-", " "):
        out = o("name")
        obj(f"--name {name!r}", False, [mesh, "--name", name], ("--name",), out=out)
    for name, argv, named in (
        ("--out the input mesh", ["--out", mesh], "box.stl"),
        ("--out the input mesh --force", ["--out", mesh, "--force"], "box.stl"),
        ("--out a link to the mesh --force", ["--out", str(c / "box_link.stl"), "--force"], "box_link.stl"),
        ("--out a .stl", ["--out", str(c / "new.stl")], "new.stl"),
        ("--out an existing file, no --force", ["--out", str(c / "kept.yaml")], "kept.yaml"),
        ("--out a folder", ["--out", str(c / "empty")], "empty"),
        ("--out a FIFO", ["--out", str(c / "fifo.stl")], "fifo.stl"),
        ("--out below a file", ["--out", str(c / "a_file" / "x.yaml")], "a_file"),
        ("--tolerance-mm 0", ["--out", str(c / "t0.yaml"), "--tolerance-mm", "0"], "--tolerance-mm"),
        ("--tolerance-mm -1", ["--out", str(c / "t1.yaml"), "--tolerance-mm", "-1"], "--tolerance-mm"),
        ("--tolerance-mm nan", ["--out", str(c / "t2.yaml"), "--tolerance-mm", "nan"], "--tolerance-mm"),
        ("--tolerance-mm inf", ["--out", str(c / "t3.yaml"), "--tolerance-mm", "inf"], "--tolerance-mm"),
        ("--tolerance-mm 1e9", ["--out", str(c / "t4.yaml"), "--tolerance-mm", "1e9"], "--tolerance-mm"),
        ("--tolerance-mm abc", ["--out", str(c / "t5.yaml"), "--tolerance-mm", "abc"], "--tolerance-mm"),
        ("--units furlong", ["--out", str(c / "u.yaml"), "--units", "furlong"], "--units"),
    ):  # fmt: skip
        obj(name, False, [mesh, *argv], (named,))
    for name, file, named in (("a part of nanometres", "nano.stl", "nano.stl"), ("every vertex in one point", "point.stl", "point.stl"),
                              ("a mesh path that is a folder", "folder.stl", "folder.stl"), ("a FIFO named .stl", "fifo.stl", "fifo.stl"),
                              ("a missing mesh", "gone.stl", "gone.stl")):  # fmt: skip
        out = o("mesh")
        obj(name, False, [str(c / file), "--out", str(out / "x.yaml")], (named,), out=out)
    obj("a box, --out a new YAML", True, [mesh, "--out", str(c / "ok1.yaml")])
    obj("a box, --units m --tolerance-mm 0.5", True, [mesh, "--out", str(c / "ok2.yaml"), "--units", "m", "--tolerance-mm", "0.5"])
    obj("a box, --out an existing file --force", True, [mesh, "--out", str(c / "replaced.yaml"), "--force"])

    # 2. the console tools' arguments
    def tool(family: str, module: str, name: str, valid: bool, argv: list[str], names: tuple[str, ...] = (),
             out: Path | None = None) -> None:  # fmt: skip
        add(family, name, valid, _tool(module, argv), names, out=out, timeout=120.0)

    oracle = lambda out, *a: ["--data", str(data), "--out", str(out), "--max-scenes", "2", *a]  # noqa: E731
    for variant, named in (("vanilla:_target_=builtins.dict", "_target_"), ("vanilla:_target_=os.system", "_target_"),
                           ("vanilla:_convert_=all", "_convert_"), ("vanilla:bogus_key=1", "bogus_key"),
                           ("vanilla:threshold=7", "threshold"), ("vanilla:threshold=nan", "threshold"),
                           ("vanilla:threshold=abc", "threshold"), ("vanilla:grid=${oc.env:HOME}", "grid"),
                           ("ap:points={_target_: os.system}", "points"), ("vanilla:threshold", "threshold"),
                           ("nosuch", "nosuch"), ("nosuch:threshold=0.2", "nosuch"), (":threshold=0.2", "--variant"),
                           ("vanilla:threshold=0.2,threshold=0.3", "threshold")):  # fmt: skip
        out = o("oracle")
        tool("opnet-oracle", "opnet.tools.oracle", f"--variant {variant}", False, oracle(out, "--variant", variant),
             ("--variant",) if named == "--variant" else (named,), out=out)
    for name, argv, named in (
        ("--max-scenes 0", ["--max-scenes", "0"], "--max-scenes"), ("--max-scenes -1", ["--max-scenes", "-1"], "--max-scenes"),
        ("--max-scenes abc", ["--max-scenes", "abc"], "--max-scenes"), ("--max-scenes 1.5", ["--max-scenes", "1.5"], "--max-scenes"),
        ("--min-objects -2", ["--min-objects", "-2"], "--min-objects"), ("--min-objects x", ["--min-objects", "x"], "--min-objects"),
        ("--data a missing folder", ["--data", str(c / "gone")], "gone"), ("--data a file", ["--data", str(c / "a_file")], "a_file"),
        ("--data an empty folder", ["--data", str(c / "empty")], "empty"),
        ("--data a FIFO", ["--data", str(c / "fifo.stl")], "fifo.stl"),
    ):  # fmt: skip
        out = o("oracle")
        tool("opnet-oracle", "opnet.tools.oracle", name, False, [*oracle(out), *argv], (named,), out=out)
    tool("opnet-oracle", "opnet.tools.oracle", "--out a file", False, oracle(c / "a_file"), ("a_file",))
    tool("opnet-oracle", "opnet.tools.oracle", "a documented setting (vanilla:threshold=0.2)", True,
         oracle(o("oracle"), "--variant", "vanilla:threshold=0.2"))
    tool("opnet-oracle", "opnet.tools.oracle", "--variant vanilla: (no settings: the config as it is)", True,
         oracle(o("oracle"), "--variant", "vanilla:"))
    add("opnet-oracle", "--object beside a dataset's object.json (the dataset's, said)", True,
        _tool("opnet.tools.oracle", oracle(o("oracle"), "--object", "nosuch")), says="object zbracket", timeout=120.0)

    diag = "opnet.tools.diagnose_sources"
    for name, ck, named in (("--ckpt not a checkpoint", "text.ckpt", "text.ckpt"), ("--ckpt a pickle holding code", "code.ckpt", "code.ckpt"),
                            ("--ckpt missing", "gone.ckpt", "gone.ckpt"), ("--ckpt a folder", "empty", "empty"),
                            ("--ckpt a FIFO", "fifo.stl", "fifo.stl")):  # fmt: skip
        out = o("diag")
        tool("opnet-diagnose-sources", diag, name, False, ["--ckpt", str(c / ck), "--out", str(out)], (named,), out=out)
    tool("opnet-diagnose-sources", diag, "--out a file", False, ["--ckpt", str(ckpt), "--out", str(c / "a_file")], ("a_file",))
    out = o("diag")
    tool("opnet-diagnose-sources", diag, "--split bogus", False, ["--ckpt", str(ckpt), "--split", "bogus", "--out", str(out)],
         ("--split",), out=out)

    tune = "opnet.tools.tune_decoding"
    for name, argv, named in (
        ("--rounds 0", ["--rounds", "0"], "--rounds"), ("--rounds -3", ["--rounds", "-3"], "--rounds"),
        ("--rounds abc", ["--rounds", "abc"], "--rounds"), ("--rounds 1e9", ["--rounds", "1000000000"], "--rounds"),
        ("--stride 0", ["--stride", "0"], "--stride"), ("--stride -1", ["--stride", "-1"], "--stride"),
        ("--split bogus", ["--split", "bogus"], "--split"), ("--ckpt missing", ["--ckpt", str(c / "gone.ckpt")], "gone.ckpt"),
        ("--ckpt not a checkpoint", ["--ckpt", str(c / "text.ckpt")], "text.ckpt"),
        ("--write an existing file, no --force", ["--write", str(c / "kept.yaml")], "kept.yaml"),
        ("--write a folder", ["--write", str(c / "empty")], "empty"),
    ):  # fmt: skip
        out = o("tune")
        tool("opnet-tune-decoding", tune, name, False, ["--ckpt", str(ckpt), "--out", str(out), *argv], (named,), out=out)
    tool("opnet-tune-decoding", tune, "--out a file", False, ["--ckpt", str(ckpt), "--out", str(c / "a_file")], ("a_file",))

    record = "opnet.tools.record_trained_clip"
    for name, argv, named in (
        ("--write an existing file, no --force", [str(ckpt), "--write", str(c / "kept.yaml")], "kept.yaml"),
        ("--write the checkpoint itself", [str(c / "copy.ckpt"), "--write", str(c / "copy.ckpt")], "copy.ckpt"),
        ("--write and --in-place", [str(c / "copy.ckpt"), "--write", str(c / "r1.ckpt"), "--in-place"], "--in-place"),
        ("neither --write nor --in-place", [str(c / "copy.ckpt")], "--write"),
        ("--data a missing folder", [str(ckpt), "--data", str(c / "gone"), "--write", str(c / "r2.ckpt")], "gone"),
        ("--data a file", [str(ckpt), "--data", str(c / "a_file"), "--write", str(c / "r3.ckpt")], "a_file"),
        ("a missing checkpoint", [str(c / "gone.ckpt"), "--write", str(c / "r4.ckpt")], "gone.ckpt"),
        ("a FIFO checkpoint", [str(c / "fifo.stl"), "--write", str(c / "r5.ckpt")], "fifo.stl"),
    ):  # fmt: skip
        tool("opnet-record-trained-clip", record, name, False, argv, (named,))

    compare = "opnet.tools.compare_runs"
    for name, argv, named in (("a missing multirun folder", [str(c / "gone")], "gone"), ("a file", [str(c / "a_file")], "a_file"),
                              ("an empty folder", [str(c / "empty")], "empty"),
                              ("--out a file", [str(c / "empty"), "--out", str(c / "a_file")], "a_file")):  # fmt: skip
        tool("opnet-compare-runs", compare, name, False, argv, (named,))

    cell = "opnet.cli.cell"
    frames = str(data / "p_depth" / "cycle_0000")
    for name, argv, named in (
        ("frames missing", [str(c / "gone"), "--camera", str(camera)], "gone"),
        ("--camera missing", [frames, "--camera", str(c / "gone.yaml")], "gone.yaml"),
        ("--camera a FIFO", [frames, "--camera", str(c / "fifo.stl")], "fifo.stl"),
        ("--camera not YAML", [frames, "--camera", str(c / "text.ckpt")], "text.ckpt"),
        ("--depth-scale -1", [frames, "--camera", str(camera), "--depth-scale", "-1"], "--depth-scale"),
        ("--depth-scale nan", [frames, "--camera", str(camera), "--depth-scale", "nan"], "--depth-scale"),
        ("--area 1,2,3", [frames, "--camera", str(camera), "--area", "1,2,3"], "--area"),
        ("--area a,b,c,d", [frames, "--camera", str(camera), "--area", "a,b,c,d"], "--area"),
        ("--area reversed", [frames, "--camera", str(camera), "--area", "0.5,0.5,-0.5,-0.5"], "--area"),
        ("--area-margin -1", [frames, "--camera", str(camera), "--area-margin", "-1"], "--area-margin"),
        ("--volume-margin nan", [frames, "--camera", str(camera), "--volume-margin", "nan"], "--volume-margin"),
        ("--sensor nosuch", [frames, "--camera", str(camera), "--sensor", "nosuch"], "nosuch"),
        ("--extrinsics missing", [frames, "--camera", str(camera), "--extrinsics", str(c / "gone_x.yaml")], "gone_x.yaml"),
        ("--name ../x", [frames, "--camera", str(camera), "--name", "../x"], "--name"),
        ("--out an existing file, no --force", [frames, "--camera", str(camera), "--out", str(c / "kept.yaml")], "kept.yaml"),
        ("--out a folder", [frames, "--camera", str(camera), "--out", str(c / "empty")], "empty"),
    ):  # fmt: skip
        if "--out" not in argv:
            argv = [*argv, "--out", str(o("cell") / "cell.yaml")]
        tool("opnet-cell", cell, name, False, argv, (named,))

    # 3. training's overrides: refused before it trains (a wrong acceptance trains 2 steps of the tiny network)
    train = ["model=tiny", "object=zbracket", f"data.root={data}", "data.generate=null", "data.batch_size=4",
             "trainer.max_epochs=1", "+trainer.limit_train_batches=2", "+trainer.limit_val_batches=1", "test=false",
             "trainer.enable_progress_bar=false", "example_predictions=0"]  # fmt: skip
    for override, key in (
        ("+decoding.threshold=7", "decoding"), ("+decoding.averaging=false", "decoding"), ("+decoding.bogus=1", "decoding"),
        ("+data.bogus_key=1", "bogus_key"), ("+model.bogus_key=1", "bogus_key"), ("+loss.bogus_key=1", "bogus_key"),
        ("+augmentation.bogus_key=1", "bogus_key"), ("+parameterization.bogus_key=1", "bogus_key"),
        ("loss.lambda_xy=-1", "lambda_xy"), ("loss.lambda_xy=nan", "lambda_xy"), ("loss.lambda_xy=abc", "lambda_xy"),
        ("loss.lambda_z=-1", "lambda_z"), ("data.batch_size=0", "batch_size"), ("data.batch_size=-4", "batch_size"),
        ("data.batch_size=abc", "batch_size"), ("data.val_fraction=1.5", "val_fraction"),
        ("data.val_fraction=-0.1", "val_fraction"), ("data.input_size=7", "input_size"), ("data.input_size=0", "input_size"),
        ("data.root=" + str(c / "gone"), "gone"), ("data.root=" + str(c / "a_file"), "a_file"),
        ("data.roi=auto:1e-9", "roi"), ("data.roi=auto:0.001", "roi"), ("data.roi=auto:abc", "roi"),
        ("data.roi=[1,2]", "roi"), ("part_pixels=0", "part_pixels"), ("part_pixels=-5", "part_pixels"),
        ("part_pixels=abc", "part_pixels"), ("part_cells=0", "part_cells"), ("part_cells=abc", "part_cells"),
        ("seed=abc", "seed"), ("seed=1.5", "seed"), ("model.in_size=100", "in_size"),
        ("data.test_fraction=1", "test_fraction"), ("data.val_fraction=0.95", "val_fraction"),
        ("data.num_workers=-1", "num_workers"), ("data.batch_size=2.5", "batch_size"),
    ):  # fmt: skip
        run = o("train")  # Hydra's own record of the run goes there first
        add("train.py overrides", override, False, _script("train.py", [*train, override, f"hydra.run.dir={run}"]), (key,),
            timeout=120.0)

    # 4. the bin finder's crop: roi=auto:S (S in metres, from 0.01; the square must span 16 pixels)
    for value in ("auto:1e-9", "auto:0.001", "auto:0", "auto:-1", "auto:nan", "auto:inf", "auto:abc", "auto:", "auto:1e9",
                  "auto:0.005", "auto:1e-300", "auto:0x10"):  # fmt: skip
        out = o("roi")
        add("roi=auto:S", f"predict.py roi={value}", False,
            _script("predict.py", [f"ckpt={ckpt}", f"input={png}", f"out={out}", f"roi={value}", f"hydra.run.dir={out}_h"]),
            ("roi",), out=out, timeout=120.0)
    for value in ("auto:1e-9", "auto:0", "auto:nan", "auto:abc", "auto:1e9"):
        out = o("roi")
        add("roi=auto:S", f"python -m opnet.deploy --roi {value}", False,
            _script("opnet.deploy", [str(model), str(png), "--out", str(out), "--roi", value]), ("roi",), out=out, timeout=120.0)
    for value in ("auto:1e-9", "auto:nan", "auto:abc"):
        out = o("roi")
        add("roi=auto:S", f"eval.py +data.roi={value}", False,
            _script("eval.py", [f"ckpt={ckpt}", "examples=0", f"out={out}", f"+data.roi={value}", f"hydra.run.dir={out}_h"]),
            ("roi",), out=out, timeout=120.0)
    out = o("roi")
    add("roi=auto:S", "predict.py roi=auto:0.3 (a bin of the dataset)", True,
        _script("predict.py", [f"ckpt={ckpt}", f"input={png}", f"out={out}", "roi=auto:0.3", f"hydra.run.dir={out}_h"]),
        timeout=120.0)
    return cases


def _child(fn: Callable[[], Any], conn: Any) -> None:
    try:
        result = fn()
        conn.send(("returned", result if isinstance(result, str) else ""))  # a text for ``says``
    except USER_ERRORS as e:
        conn.send(("user_error", str(e)))
    except BaseException as e:  # noqa: BLE001 - classifying every outcome is the point
        conn.send(("other", f"{type(e).__name__}: {e}"))


def _serve(known: dict[int, Case], conn: Any) -> None:
    """The reader process: runs the cases named by their ``id`` in the parent (the same objects here, forked) one
    after another until the parent closes the pipe."""
    while True:
        try:
            key = conn.recv()
        except EOFError:
            return
        _child(known[key].run, conn)


class _ReaderProcess:
    """One forked process that runs the reader cases one after another (a fork of the parent per case cost more
    than most reads). A case that hangs is killed with its process, one that kills it is reported, and the next
    case gets a fresh process, forked again; so does a case the process does not know (made after its fork)."""

    def __init__(self) -> None:
        self.proc: Any = None
        self.conn: Any = None
        self.known: dict[int, Case] = {}

    def expect(self, cases: list[Case]) -> None:
        """The cases to come: a process forked from now on knows them."""
        self.known.update({id(c): c for c in cases if c.run is not None})

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.join()
            self.conn.close()
        self.proc = None

    def run(self, case: Case) -> tuple[str, str] | None:
        """(outcome, message), or None when the case did not answer in its time."""
        if id(case) not in self.known or (self.proc is not None and not self.proc.is_alive()):
            self.stop()  # a fresh fork: one that knows this case, or after one that died
            self.known[id(case)] = case
        if self.proc is None:
            self.conn, child = mp.Pipe()
            self.proc = mp.get_context("fork").Process(target=_serve, args=(self.known, child))
            self.proc.start()
            child.close()
        self.conn.send(id(case))
        if not self.conn.poll(case.timeout):
            self.stop()
            return None
        try:
            return self.conn.recv()
        except EOFError:
            self.stop()
            return "other", "the reader's process died"


_READER = _ReaderProcess()


def run_reader(case: Case) -> tuple[str, str]:
    answer = _READER.run(case)
    if answer is None:
        return "HANG", f"no answer in {case.timeout:g} s"
    outcome, message = answer
    return _verdict(case, outcome == "returned", outcome == "user_error", message)


#: the environment of every command line a case runs
CLI_ENV = {"PYOPENGL_PLATFORM": "egl", "OPNET_VHACD_TIMEOUT": "30"}


def _entry(argv: list[str]) -> Callable[[], Any] | None:
    """What ``argv`` runs, to be called in a forked child: ``python <script>.py ...``, ``python -m <module> ...``
    or a console script of the package; None for another command line (run as a subprocess)."""
    import runpy
    from importlib.metadata import entry_points

    if argv[0] == sys.executable and len(argv) > 1 and argv[1].endswith(".py"):
        return lambda: runpy.run_path(str(REPO_ROOT / argv[1]), run_name="__main__") and None
    if argv[0] == sys.executable and len(argv) > 2 and argv[1] == "-m":
        return lambda: runpy.run_module(argv[2], run_name="__main__", alter_sys=True) and None
    found = [e for e in entry_points(group="console_scripts") if e.name == argv[0] and e.value.startswith("opnet.")]
    return (lambda: found[0].load()()) if found else None


def _run_forked(argv: list[str], entry: Callable[[], Any], log: Path) -> None:
    """In the forked child: ``argv`` as its own process would run it, its stdout and stderr (file
    descriptors 1 and 2) into ``log``, its exit status as Python gives it (an uncaught exception: the
    traceback and 1; ``sys.exit("text")``: the text and 1)."""
    import traceback

    fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.environ.update(CLI_ENV)
    os.chdir(REPO_ROOT)
    sys.argv = argv[2:] if argv[0] == sys.executable and argv[1] == "-m" else argv[1:] if argv[0] == sys.executable else argv
    code = 0
    try:
        result = entry()
        code = result if isinstance(result, int) else 0
    except SystemExit as e:
        if isinstance(e.code, int) or e.code is None:
            code = e.code or 0
        else:
            print(e.code, file=sys.stderr)
            code = 1
    except BaseException:  # noqa: BLE001 - as the interpreter would: the traceback, then exit 1
        traceback.print_exc()
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def run_cli(case: Case) -> tuple[str, str]:
    """Run ``case.argv``: a command of this package in a forked child of this process (its imports done
    once: the same entry, arguments, environment, folder, output and exit status as its own process,
    seconds less of start-up), generate.py and any other command line as a subprocess (generation's
    physics and renderer are made in this process and are not forked)."""
    entry = _entry(case.argv) if "generate.py" not in case.argv[1:2] else None
    if entry is None:
        try:
            proc = subprocess.run(case.argv, cwd=REPO_ROOT, capture_output=True, text=True, timeout=CLI_TIMEOUT_S,
                                  env={**os.environ, **CLI_ENV})
        except subprocess.TimeoutExpired:
            return "HANG", f"no answer in {CLI_TIMEOUT_S:g} s"
        return _cli_verdict(case, proc.returncode, proc.stdout + proc.stderr)
    with tempfile.TemporaryDirectory(prefix="fuzz_cli_") as tmp:
        log = Path(tmp) / "output.txt"
        sys.stdout.flush()
        sys.stderr.flush()
        child = mp.get_context("fork").Process(target=_run_forked, args=(case.argv, entry, log))
        child.start()
        child.join(CLI_TIMEOUT_S)
        if child.is_alive():
            child.kill()
            child.join()
            return "HANG", f"no answer in {CLI_TIMEOUT_S:g} s"
        text = log.read_text(errors="replace") if log.is_file() else ""
    return _cli_verdict(case, child.exitcode, text)


def _cli_verdict(case: Case, returncode: int, text: str) -> tuple[str, str]:
    """The verdict of a command line from its exit status and output."""
    if "Traceback" in text:
        return "TRACEBACK", text.strip().splitlines()[-1][:200]
    # Hydra's hint line ("Set the environment variable HYDRA_FULL_ERROR=1 ...") is not a message
    errors = [line for line in text.splitlines() if "error" in line.lower() and "HYDRA_FULL_ERROR" not in line]
    accepted = returncode == 0 and not errors
    verdict, message = _verdict(case, accepted, returncode != 0 or bool(errors),
                                text if accepted else (errors[-1] if errors else text.strip().splitlines()[-1] if text.strip() else "")[:300])
    return _exit_status(case, verdict, message, [returncode])


def run_concurrent(case: Case) -> tuple[str, str]:
    """Start every command line of the case at once; one of them must stop with a clear error."""
    assert case.concurrent is not None
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl"}
    procs = [subprocess.Popen(argv, cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
             for argv in case.concurrent]
    deadline, texts = time.monotonic() + CLI_TIMEOUT_S, []
    try:
        for proc in procs:
            texts.append(proc.communicate(timeout=max(1.0, deadline - time.monotonic()))[0])
    except subprocess.TimeoutExpired:
        for proc in procs:
            proc.kill()
            proc.wait()
        return "HANG", f"no answer in {CLI_TIMEOUT_S:g} s"
    if any("Traceback" in t for t in texts):
        return "TRACEBACK", next(t for t in texts if "Traceback" in t).strip().splitlines()[-1][:200]
    failed = [t for t, proc in zip(texts, procs) if proc.returncode != 0]
    errors = [line for t in failed for line in t.splitlines() if "error" in line.lower()]
    verdict, message = _verdict(case, not failed, bool(failed), (errors[-1] if errors else "")[:300])
    return _exit_status(case, verdict, message, [proc.returncode for proc in procs if proc.returncode != 0])


def _exit_status(case: Case, verdict: str, message: str, statuses: list[int]) -> tuple[str, str]:
    """An ``error`` verdict becomes ``EXIT`` when the refusal's exit status is not the documented one."""
    wrong = [s for s in statuses if s != case.status]
    if verdict != "error" or case.status is None or not wrong:
        return verdict, message
    return "EXIT", f"exit status {wrong[0]}, expected {case.status}: {message}"


def run_case(case: Case) -> tuple[str, str]:
    if case.skip:
        return "skipped", case.skip
    if case.run is not None:
        verdict, message = run_reader(case)
    elif case.concurrent is not None:
        verdict, message = run_concurrent(case)
    else:
        verdict, message = run_cli(case)
    problem = case.after() if case.after is not None and verdict in ("ok", "error") else ""
    return ("DIRTY", f"{problem}; {message}") if problem else (verdict, message)


def _verdict(case: Case, accepted: bool, user_error: bool, message: str) -> tuple[str, str]:
    """The verdict of a case from its outcome; ``message``: the error, or what an accepted input printed."""
    if case.valid:
        if accepted and case.says and case.says not in message:
            return "WRONG", f"does not say {case.says!r}: {' / '.join(message.strip().splitlines()[:3])[:200]}"
        return ("ok", "") if accepted else ("TRACEBACK" if not user_error else "REFUSED", message)
    if accepted:
        return "SILENT", "accepted"
    if not user_error:
        return "TRACEBACK", message
    if case.names and not any(n in message for n in case.names):
        return "VAGUE", message
    return "error", message


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, help="also write the table (markdown) here")
    parser.add_argument("--no-cli", action="store_true", help="readers only (seconds instead of minutes)")
    parser.add_argument("--keep", type=Path, help="work in this folder and keep it")
    parser.add_argument("--only", nargs="+", metavar="FAMILY", help="run only these families (the table's first "
                        "column), e.g. while adding cases; with --out onto a full pass's table, their rows there are "
                        "replaced and the rest kept")
    args = parser.parse_args(argv)
    ws = args.keep or Path(tempfile.mkdtemp(prefix="opnet_fuzz_"))
    ws.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    rows = []
    try:
        base = make_base(ws)
        extra = make_extra(ws, base)
        cases = (reader_cases(ws, base) + bop_cases(ws, extra) + mesh_cases(ws) + camera_yaml_cases(ws)
                 + onnx_cases(ws, extra) + checkpoint_cases(ws, base) + decoding_cases(base)
                 + boolean_cases(ws, base, extra) + ground_truth_cases(ws, extra) + empty_metric_cases(ws, base)
                 + scene_cases() + input_cases(ws, extra)
                 + ([] if args.no_cli else cli_cases(ws, base) + cli_more_cases(ws, base, extra)
                    + cli_defect_cases(ws, base, extra) + new_surface_cases(ws, base, extra)))
        if args.only:
            cases = [case for case in cases if case.family in args.only]
        _READER.expect(cases)
        for case in cases:
            verdict, message = run_case(case)
            message = re.sub(r"\(pid \d+\)", "(pid <n>)", message.replace(str(ws), "<ws>"))  # the same table each run
            rows.append((case.family, case.name, "valid" if case.valid else "bad", verdict, message))
            print(f"{verdict:9s} {case.family} / {case.name}: {message[:150]}", flush=True)
    finally:
        _READER.stop()
        unmount_all()
    seconds = time.perf_counter() - start
    if args.only and args.out and args.out.is_file():  # re-score these families in the full pass's table
        rows, seconds = merged_rows(args.out, rows, set(args.only)), None
    counts: dict[str, int] = {}
    for row in rows:
        counts[row[3]] = counts.get(row[3], 0) + 1
    bugs = sum(v for k, v in counts.items() if k.isupper())
    lines = ["| input | case | kind | verdict | message |", "|---|---|---|---|---|"]
    lines += [f"| {f} | {n} | {k} | {v} | {m.replace('|', '/')[:160]} |" for f, n, k, v, m in rows]
    took = f"{seconds:.0f} s" if seconds is not None else f"a full pass, {', '.join(args.only)} re-run"
    summary = (f"{len(rows)} cases in {took}: "
               + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + f"; bugs: {bugs}")
    print("\n" + "\n".join(lines) + "\n\n" + summary)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text("# Fuzz pass over the readers and command lines\n\n`python scripts/dev/fuzz_inputs.py "
                            f"--out {args.out}`\n\n" + "\n".join(lines) + "\n\n" + summary + "\n")
    if not args.keep:
        shutil.rmtree(ws, ignore_errors=True)
    return 1 if bugs else 0


def merged_rows(table: Path, rows: list[tuple[str, ...]], families: set[str]) -> list[tuple[str, ...]]:
    """The rows of ``table`` (a pass's Markdown) with those of ``families`` replaced by ``rows``, in the
    table's order (a family's new cases after its old place)."""
    old = [tuple(c.strip() for c in line.strip().strip("|").split("|")) for line in table.read_text().splitlines()
           if line.startswith("| ") and not line.startswith("| input |")]  # fmt: skip
    merged, placed = [], set()
    for row in old:
        if row[0] not in families:
            merged.append(row)
        elif row[0] not in placed:
            placed.add(row[0])
            merged += [r for r in rows if r[0] == row[0]]
    return merged + [r for r in rows if r[0] not in placed]


if __name__ == "__main__":
    sys.exit(main())
