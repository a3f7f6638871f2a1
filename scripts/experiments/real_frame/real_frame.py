"""predict.py on the real Siléane frame, recorded for the README: overlay, counts, scores.

    python scripts/experiments/real_frame/real_frame.py --ckpt <bunny model> [--out results/real_frame] [--min-score 0.5]

Runs ``python predict.py ckpt=<ckpt> input=../shared/data/sileane_real_frame`` (the frame's own
camera_params.txt: 1296 x 1024, fx 4507, off-centre principal point, 30 % missing depth) into a
temporary folder and writes ``overlay.png`` (the prediction overlay, 648 px wide) and
``summary.json`` (checkpoint, hypotheses, how many above ``--min-score``, their scores, depths and
world-frame positions) to ``--out``. The frame has no ground truth: the figures say what the model
reports, not whether it is right.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2

from opnet.paths import REPO_ROOT, shared_dir


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", type=Path, required=True)
    ap.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "real_frame")
    ap.add_argument("--min-score", type=float, default=0.5)
    args = ap.parse_args()
    frame = shared_dir() / "data" / "sileane_real_frame"
    if not (frame / "depth.PNG").is_file():
        raise SystemExit(f"{frame}: the real frame is not there (../shared or OPNET_SHARED)")
    work = Path(tempfile.mkdtemp(prefix="opnet_real_frame_"))
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl"}
    proc = subprocess.run([sys.executable, str(REPO_ROOT / "predict.py"), f"ckpt={args.ckpt}", f"input={frame}",
                           f"out={work}", f"min_score={args.min_score}"], cwd=REPO_ROOT, env=env, capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(f"predict.py failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")
    doc = json.loads((work / "depth.json").read_text())
    scores = sorted((p["score"] for p in doc["poses"]), reverse=True)
    above = [p for p in doc["poses"] if p["score"] >= args.min_score]
    summary = {
        "command": f"python predict.py ckpt=<bunny model> input=../shared/data/sileane_real_frame min_score={args.min_score}",
        "checkpoint": str(args.ckpt), "object": doc["object"], "camera": doc["camera"],
        "hypotheses": len(scores), "above_min_score": len(above), "min_score": args.min_score,
        "top_scores": [round(s, 3) for s in scores[:10]],
        "depths_above_m": [round(p["t"][2], 3) for p in above],
        "console": [line for line in proc.stdout.splitlines() if line.startswith(("camera:", "inference:", str(frame)))],
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    img = cv2.imread(str(work / "depth.png"))
    scale = 648 / img.shape[1]
    cv2.imwrite(str(args.out / "overlay.png"), cv2.resize(img, (648, round(img.shape[0] * scale)), interpolation=cv2.INTER_AREA))
    print(json.dumps({k: summary[k] for k in ("hypotheses", "above_min_score", "top_scores", "depths_above_m")}))


if __name__ == "__main__":
    main()
