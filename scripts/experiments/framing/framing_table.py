"""Framing of an off-centre, non-square camera into the square network input: pixels used and AP.

    python scripts/experiments/framing/framing_table.py [--fits pad crop image image_crop] [--work outputs/framing]
        [--object shaft] [--out results/framing]

A Siléane-like camera (506 x 474 pixels, principal point (139.5, 236.5): far left of centre, as
in the Siléane datasets; fx = fy = 600) generates the quickstart's data (150 cycles x 10 drops,
``scene.camera_file``) and a held-out test set (15 cycles, seed 1). For each framing
(``data.fit``) the quickstart recipe trains a model (same data, seed and epochs) and ``eval.py``
scores it on the test set. Columns: the share of the network input that shows image pixels, the
share of the image that reaches the input, the image pixels per input pixel side (resolution),
and the test AP. Finished steps are skipped on a re-run. Writes framing.csv and framing.md.
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
from pathlib import Path

from opnet.data.preprocess import framing_coverage, square_canvas
from opnet.datasets.camera_file import read_camera_file
from opnet.paths import REPO_ROOT
from opnet.studies import read_summary, run_logged, run_train

CAMERA = "fx: 600.0\nfy: 600.0\ncx: 139.5\ncy: 236.5\nwidth: 506\nheight: 474\nclip_start: 0.3\nclip_end: 2.0\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fits", nargs="+", default=["pad", "crop", "image", "image_crop"])
    ap.add_argument("--work", type=Path, default=REPO_ROOT / "outputs" / "framing")
    ap.add_argument("--object", default="shaft")
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "framing")
    args, overrides = ap.parse_known_args()
    work = args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    cam_file = work / "camera.yaml"
    cam_file.write_text(CAMERA)
    camera = read_camera_file(cam_file)
    env = {**os.environ, "OPNET_ROOT": str(work), "PYOPENGL_PLATFORM": "egl"}
    test = work / "test"
    print("held-out test set ...", flush=True)
    run_logged([sys.executable, "generate.py", f"object={args.object}", "cycles=15", "drops=10", "workers=2", "seed=1",
                f"scene.camera_file={cam_file}", f"out={test}", "progress=false"], work / "logs" / "generate_test.log",
               env=env)
    rows = []
    for fit in args.fits:
        run_dir = work / f"run_{fit}"
        if not (run_dir / "test" / "summary.json").exists():
            print(f"training with data.fit={fit} ...", flush=True)
            run_train(["experiment=quickstart", f"object={args.object}", f"data.fit={fit}", f"scene.camera_file={cam_file}",
                       "example_predictions=0", *overrides], run_dir, work / "logs" / f"train_{fit}.log", env=env)
        ckpt = sorted((run_dir / "checkpoints").glob("epoch*.ckpt"))[-1]
        out = work / f"eval_{fit}"
        if not (out / "summary.json").exists():
            run_logged([sys.executable, "eval.py", f"ckpt={ckpt}", f"data.test_root={test}", f"out={out}", "examples=0"],
                       work / "logs" / f"eval_{fit}.log", env=env)
        summary = read_summary(out, ".")
        input_share, image_share = framing_coverage(camera, fit)
        side = square_canvas(camera, fit)[2]
        rows.append({"fit": fit, "input_share": round(input_share, 4), "image_share": round(image_share, 4),
                     "image_px_per_input_px": round(side / 128, 3), "ap": round(summary["ap"], 4),
                     "scenes": summary["scenes"], "object": args.object})
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "framing.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    lines = ["| data.fit | input showing image | image reaching the input | image px per input px | test AP |",
             "|---|---|---|---|---|"]
    lines += [f"| {r['fit']} | {100 * r['input_share']:.0f} % | {100 * r['image_share']:.0f} % | "
              f"{r['image_px_per_input_px']:.2f} | {r['ap']:.4f} |" for r in rows]
    note = (f"{args.object}, camera 506 x 474, principal point (139.5, 236.5); quickstart recipe per row "
            f"(`python train.py experiment=quickstart data.fit=<fit> scene.camera_file=<camera.yaml>`), "
            f"AP on {rows[0]['scenes']} held-out scenes (seed 1). `python scripts/experiments/framing/framing_table.py`")
    (args.out / "framing.md").write_text("\n".join(lines) + "\n\n" + note + "\n")
    print("\n".join(lines))
    print(note)


if __name__ == "__main__":
    main()
