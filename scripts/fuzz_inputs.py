"""Fuzz every reader and command line with bad input; print the table of verdicts.

``python scripts/fuzz_inputs.py [--out results/fuzz.md] [--no-cli]``

Each case is a file (or argument) a careless or hostile user could hand us, derived from a valid
tiny dataset: truncated, garbled, impossible values, wrong units, special files. Every case runs in
its own process with a time limit. Verdicts:

- ``error``: refused with a one-line error that names the file (or the option / key);
- ``ok``: a valid input, accepted (the controls: each family has one);
- ``TRACEBACK``: a raw traceback or an exception other than the readers' ValueError /
  FileNotFoundError (a bug);
- ``HANG``: no answer within the limit (a bug);
- ``SILENT``: an impossible value accepted without a word (a bug);
- ``VAGUE``: an error that does not name the file or key (a bug).

Exit status 1 when any case is a bug.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
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

REPO = Path(__file__).resolve().parents[1]
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


# ---------------------------------------------------------------------------------------- fixtures


def make_base(ws: Path) -> dict[str, Path]:
    """A valid tiny dataset, a checkpoint trained for 2 steps on it, and evaluation folders."""
    from opnet.objects import builtin_object
    from opnet.synthesis import SceneConfig, generate_dataset

    data = ws / "data"
    generate_dataset(builtin_object("zbracket"), data, cycles=4, drops=3, workers=1, seed=0,
                     scene=SceneConfig(resolution=96), progress=False, previews=0,
                     object_config={"name": "zbracket", "builtin": "zbracket"})  # fmt: skip
    run = ws / "run"
    subprocess.run([sys.executable, str(REPO / "train.py"), "model=tiny", "object=zbracket", f"data.root={data}",
                    "data.generate=null", "data.batch_size=4", "data.val_fraction=0.25", "data.test_fraction=0.25",
                    "trainer.max_epochs=1", "+trainer.limit_train_batches=2", "+trainer.limit_val_batches=1",
                    "trainer.enable_progress_bar=false", "example_predictions=0", f"hydra.run.dir={run}"],
                   check=True, capture_output=True, cwd=REPO)  # fmt: skip
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
    from opnet.datasets.check import check_dataset
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

    def must_find(root: Path) -> Any:
        report = check_dataset(root, fast=True)
        if report.problems:
            raise ValueError(str(report.problems[0]))
        return report

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
        cases.append(Case("dataset check", name, valid, run=lambda r=root: must_find(r), names=(root.name,)))
    return cases


def cli_cases(ws: Path, base: dict[str, Path]) -> list[Case]:
    py = sys.executable
    data, ckpt = base["data"], base["ckpt"]
    png = data / "p_depth" / "cycle_0000" / "002_depth_uint16.png"
    out = ws / "cli_out"
    evil = ws / "cases" / "evil.ckpt"
    evil.parent.mkdir(parents=True, exist_ok=True)
    evil.write_bytes(b"PK\x03\x04" + os.urandom(200))
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
    return [Case(f, n, v, argv=a, names=names) for f, n, v, a, names in c]


# ------------------------------------------------------------------------------------------ running


def _child(fn: Callable[[], Any], conn: Any) -> None:
    try:
        fn()
        conn.send(("returned", ""))
    except USER_ERRORS as e:
        conn.send(("user_error", str(e)))
    except BaseException as e:  # noqa: BLE001 - classifying every outcome is the point
        conn.send(("other", f"{type(e).__name__}: {e}"))


def run_reader(case: Case) -> tuple[str, str]:
    parent, child = mp.Pipe(duplex=False)
    proc = mp.get_context("fork").Process(target=_child, args=(case.run, child))
    proc.start()
    if not parent.poll(READER_TIMEOUT_S):
        proc.kill()
        proc.join()
        return "HANG", f"no answer in {READER_TIMEOUT_S:g} s"
    outcome, message = parent.recv()
    proc.join()
    return _verdict(case, outcome == "returned", outcome == "user_error", message)


def run_cli(case: Case) -> tuple[str, str]:
    try:
        proc = subprocess.run(case.argv, cwd=REPO, capture_output=True, text=True, timeout=CLI_TIMEOUT_S,
                              env={**os.environ, "PYOPENGL_PLATFORM": "egl", "OPNET_VHACD_TIMEOUT": "30"})
    except subprocess.TimeoutExpired:
        return "HANG", f"no answer in {CLI_TIMEOUT_S:g} s"
    text = proc.stdout + proc.stderr
    if "Traceback" in text:
        return "TRACEBACK", text.strip().splitlines()[-1][:200]
    errors = [line for line in text.splitlines() if "error" in line.lower()]
    return _verdict(case, proc.returncode == 0 and not errors, proc.returncode != 0 or bool(errors),
                    (errors[-1] if errors else text.strip().splitlines()[-1] if text.strip() else "")[:300])


def _verdict(case: Case, accepted: bool, user_error: bool, message: str) -> tuple[str, str]:
    if case.valid:
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
    args = parser.parse_args(argv)
    ws = args.keep or Path(tempfile.mkdtemp(prefix="opnet_fuzz_"))
    ws.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    base = make_base(ws)
    cases = reader_cases(ws, base) + ([] if args.no_cli else cli_cases(ws, base))
    rows = []
    for case in cases:
        verdict, message = run_reader(case) if case.run is not None else run_cli(case)
        message = message.replace(str(ws), "<ws>")
        rows.append((case.family, case.name, "valid" if case.valid else "bad", verdict, message))
        print(f"{verdict:9s} {case.family} / {case.name}: {message[:150]}", flush=True)
    counts: dict[str, int] = {}
    for row in rows:
        counts[row[3]] = counts.get(row[3], 0) + 1
    bugs = sum(v for k, v in counts.items() if k.isupper())
    lines = ["| input | case | kind | verdict | message |", "|---|---|---|---|---|"]
    lines += [f"| {f} | {n} | {k} | {v} | {m.replace('|', '/')[:160]} |" for f, n, k, v, m in rows]
    summary = (f"{len(rows)} cases in {time.perf_counter() - start:.0f} s: "
               + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())) + f"; bugs: {bugs}")
    print("\n" + "\n".join(lines) + "\n\n" + summary)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text("# Fuzz pass over the readers and command lines\n\n`python scripts/fuzz_inputs.py "
                            f"--out {args.out}`\n\n" + "\n".join(lines) + "\n\n" + summary + "\n")
    if not args.keep:
        shutil.rmtree(ws, ignore_errors=True)
    return 1 if bugs else 0


if __name__ == "__main__":
    sys.exit(main())
