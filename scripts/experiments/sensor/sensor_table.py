"""Missing depth of the sensor presets next to the real Siléane frame: fraction and hole pattern.

    python scripts/experiments/sensor/sensor_table.py [--presets ideal structured_light tof] [--object bunny]
        [--cycles 2] [--drops 20] [--work outputs/sensor_table] [--out results/sensor]

Generates ``--cycles`` cycles of ``--drops`` parts per preset (``generate.py sensor=<preset>``),
with the real frame's own camera (``scene.camera_file=<its camera_params.txt>``: 1296 x 1024,
fx 4507, principal point (399.6, 556.6)) at its distance (``--camera-height 0.92``: the frame's
99th depth percentile, the camera sees the middle of the pile as in the real frame) when
../shared is present, else the built-in camera at 512 px, and measures on the scenes holding at least half the parts:

- ``missing``: share of pixels without depth;
- ``missing_lit``: the same without image columns that have no depth at all (the real frame's
  left 198 columns lie outside its projector's field; no preset models that border);
- ``edge_runs``: of the horizontal runs of missing pixels bounded by depth on both sides (at most
  200 px long), the share whose two sides differ by more than 1 cm: holes at depth edges;
- ``right_nearer``: of those, the share whose right side is nearer: shadows of a projector to the
  camera's +x lie left of the nearer surface (0.5 = no side preferred);
- ``run_px``: median length of those runs, pixels, and ``run_permille``: as 1/1000 of the width;
- ``speckle``: share of missing pixels in 4-connected holes of at most 4 pixels.

Writes holes.csv, holes.md and holes.png (the real frame, then one scene per preset; missing depth
in red) to ``--out`` and prints the table.
"""

from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import warnings
from pathlib import Path

import cv2
import numpy as np

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from opnet.datasets.depth_inputs import load_depth_image  # noqa: E402
from opnet.datasets.ipa import IPADataset  # noqa: E402
from opnet.paths import REPO_ROOT, shared_dir  # noqa: E402

EDGE_JUMP_M = 0.01
MAX_RUN = 200


def hole_stats(depth: np.ndarray) -> dict[str, float]:
    """The hole-pattern figures of one depth image ((H, W) metres, NaN = missing)."""
    missing = ~np.isfinite(depth)
    dark_cols = missing.all(axis=0)
    lit = missing[:, ~dark_cols]
    runs, right_nearer, lengths = 0, 0, []
    edge = 0
    for row, miss in zip(depth, missing):
        change = np.flatnonzero(np.diff(np.r_[0, miss.astype(np.int8), 0]))
        for s, e in zip(change[::2], change[1::2]):
            if s == 0 or e >= len(row) or e - s > MAX_RUN:
                continue
            runs += 1
            left, right = row[s - 1], row[e]
            if abs(left - right) > EDGE_JUMP_M:
                edge += 1
                right_nearer += int(right < left)
                lengths.append(e - s)
    n, _, stats, _ = cv2.connectedComponentsWithStats(missing.astype(np.uint8), connectivity=4)
    areas = stats[1:, cv2.CC_STAT_AREA]
    W = depth.shape[1]
    return {
        "missing": float(missing.mean()),
        "missing_lit": float(lit.mean()) if lit.size else 0.0,
        "edge_runs": edge / runs if runs else float("nan"),
        "right_nearer": right_nearer / edge if edge else float("nan"),
        "run_px": float(np.median(lengths)) if lengths else float("nan"),
        "run_permille": 1000.0 * float(np.median(lengths)) / W if lengths else float("nan"),
        "speckle": float(areas[areas <= 4].sum() / max(missing.sum(), 1)),
    }


def picture(depth: np.ndarray, width: int = 432) -> np.ndarray:
    """Grey depth (near = light), missing in red, scaled to ``width`` pixels."""
    lo, hi = np.nanpercentile(depth, [1, 99]) if np.isfinite(depth).any() else (0.0, 1.0)
    g = np.nan_to_num(np.clip((depth - lo) / max(hi - lo, 1e-9), 0, 1), nan=0.0)
    img = cv2.cvtColor((255 * (1 - g)).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    img[~np.isfinite(depth)] = (0, 0, 255)
    scale = width / depth.shape[1]
    return cv2.resize(img, (width, round(depth.shape[0] * scale)), interpolation=cv2.INTER_AREA)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--presets", nargs="+", default=["ideal", "structured_light", "tof"])
    ap.add_argument("--object", default=None, help="default: bunny with ../shared, else shaft")
    ap.add_argument("--cycles", type=int, default=2)
    ap.add_argument("--drops", type=int, default=20)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--camera-height", type=float, default=0.92, help="metres above the bin floor (real-frame camera)")
    ap.add_argument("--work", type=Path, default=REPO_ROOT / "outputs" / "sensor_table")
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "sensor")
    args = ap.parse_args()

    shared = shared_dir() if shared_dir().is_dir() else None
    frame = shared / "data" / "sileane_real_frame" if shared is not None else None
    real = None
    camera_args: list[str] = ["scene.resolution=512"]
    if frame is not None and (frame / "camera_params.txt").is_file():
        real = load_depth_image(frame / "depth.PNG", None).depth  # predict.py's reader: its camera_params.txt
        # the real frame's geometry: its camera, 0.92 m above the floor (its 99th depth percentile)
        camera_args = [f"scene.camera_file={frame / 'camera_params.txt'}", f"scene.camera_height={args.camera_height}"]
    obj = args.object or ("bunny" if shared is not None else "shaft")

    rows, pictures = [], []
    if real is not None:
        rows.append({"source": "real Siléane frame", "scenes": 1, **hole_stats(real)})
        pictures.append(picture(real))
    for preset in args.presets:
        out = args.work / f"{obj}_{preset}"
        cmd = [sys.executable, str(REPO_ROOT / "generate.py"), f"object={obj}", f"cycles={args.cycles}",
               f"drops={args.drops}", f"workers={args.workers}", f"sensor={preset}", f"out={out}", "progress=false",
               "previews=0", *camera_args]
        proc = subprocess.run(cmd, cwd=REPO_ROOT, capture_output=True, text=True)
        if proc.returncode:
            raise SystemExit(f"generation failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")
        ds = IPADataset(out)
        picks = [i for i in range(len(ds)) if int(ds.scene_name(i)[-3:]) >= args.drops // 2]
        stats = [hole_stats(ds[i].depth) for i in picks]
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # ideal: no holes, so no run figures (nan)
            mean = {k: float(np.nanmean([s[k] for s in stats])) for k in stats[0]}
        rows.append({"source": f"sensor={preset}", "scenes": len(picks), **mean})
        pictures.append(picture(ds[picks[-1]].depth))

    args.out.mkdir(parents=True, exist_ok=True)
    keys = list(rows[0])
    with open(args.out / "holes.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        w.writerows({k: (round(v, 4) if isinstance(v, float) else v) for k, v in r.items()} for r in rows)
    head = "| source | scenes | missing | missing (lit columns) | holes at depth edges | right side nearer | median hole run | speckle |"
    lines = [head, "|---|---|---|---|---|---|---|---|"]

    def pct(x: float) -> str:
        return "–" if np.isnan(x) else f"{100 * x:.0f} %"

    for r in rows:
        run = "–" if np.isnan(r["run_px"]) else f"{r['run_px']:.0f} px ({r['run_permille']:.1f} ‰ of the width)"
        lines.append(f"| {r['source']} | {r['scenes']} | {100 * r['missing']:.1f} % | {100 * r['missing_lit']:.1f} % | "
                     f"{pct(r['edge_runs'])} | {pct(r['right_nearer'])} | {run} | {pct(r['speckle'])} |")
    setup = (f"{obj}, {args.cycles} cycles x {args.drops} drops, scenes with >= {args.drops // 2} parts; camera: "
             + (f"the real frame's camera_params.txt, {args.camera_height} m above the floor" if real is not None else "built-in, 512 px"))
    (args.out / "holes.md").write_text("\n".join(lines) + f"\n\n{setup}. `python scripts/experiments/sensor/sensor_table.py`\n")
    h = max(p.shape[0] for p in pictures)
    strip = np.hstack([cv2.copyMakeBorder(p, 0, h - p.shape[0], 0, 8, cv2.BORDER_CONSTANT, value=(255, 255, 255))
                       for p in pictures])
    cv2.imwrite(str(args.out / "holes.png"), strip)
    print("\n".join(lines))
    print(setup)


if __name__ == "__main__":
    main()
