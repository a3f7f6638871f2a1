"""Pose estimation with an exported model, without PyTorch.

    python -m opnet.deploy <model.onnx> <depth png, .npy or folder> --out <dir>
        [--camera <camera.yaml>] [--fx PX --fy PX --cx PX --cy PX --clip-start M --clip-end M]
        [--depth-scale 0.001] [--threads N] [--overwrite]

The inputs and cameras are predict.py's (:mod:`opnet.datasets.depth_inputs`: a dataset PNG takes
the camera file above it, other images the intrinsics given here), and so are the outputs
``<out>/<name>.json`` (poses, camera frame, and world frame when known) and
``<out>/results/<scene>.json`` (Siléane results format). Only numpy, OpenCV, SciPy, PyYAML and
onnxruntime are imported. Exit status: 0, 1 when some images failed, 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from opnet.datasets.depth_inputs import check_outputs, given_camera, list_inputs, load_depth_image, scene_names, write_pose_files


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m opnet.deploy", description=__doc__.split("\n\n")[0])
    ap.add_argument("model", type=Path)
    ap.add_argument("input", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--camera", dest="file", help="camera YAML (fx fy cx cy clip_start clip_end [depth_scale])")
    for key in ("fx", "fy", "cx", "cy", "clip-start", "clip-end", "depth-scale"):
        ap.add_argument(f"--{key}", dest=key.replace("-", "_"), type=float)
    ap.add_argument("--threads", type=int, default=None, help="ONNX Runtime threads (default: one per core)")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args(argv)
    try:
        from opnet.deploy.runtime import OnnxPoseEstimator

        camera_cfg = {k: getattr(args, k) for k in ("file", "fx", "fy", "cx", "cy", "clip_start", "clip_end", "depth_scale")}
        given = given_camera(camera_cfg)
        estimator = OnnxPoseEstimator(args.model, threads=args.threads)
        inputs = list_inputs(args.input)
        check_outputs(args.out, inputs, args.overwrite)
    except (ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    scenes = scene_names(inputs)
    failed = 0
    for path, name in inputs:
        try:
            image = load_depth_image(path, given)
            hyps = estimator.predict(image.depth, image.camera)
            (args.out / name).parent.mkdir(parents=True, exist_ok=True)
            write_pose_files(args.out, name, image, hyps, str(estimator.meta.get("object", "")), scenes[name])
            print(f"{path}: {len(hyps.above(0.5))} objects (score >= 0.5), {len(hyps)} hypotheses")
        except (ValueError, FileNotFoundError) as e:
            failed += 1
            print(f"error: {e}")
    print(f"{len(inputs) - failed} of {len(inputs)} predictions written to {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
