"""Pose estimation with an exported model, without PyTorch.

    python -m opnet.deploy <model.onnx> <depth png, .npy or folder> --out <dir>
        [--camera <camera.yaml>] [--fx PX --fy PX --cx PX --cy PX --clip-start M --clip-end M]
        [--depth-scale 0.001] [--threads N] [--overwrite] [--clip NEAR FAR | --camera-clip]
        [--icp | --search | --search-fast | --no-refine] [--no-averaging]

The inputs and cameras are predict.py's (:mod:`opnet.datasets.depth_inputs`: a dataset PNG takes
the camera file above it, other images the intrinsics given here), and so are the outputs
``<out>/<name>.json`` (poses, camera frame, world frame when known, and the robot's base frame as
``poses_base`` when the camera YAML or the model gives ``T_base_cam``) and
``<out>/results/<scene>.json`` (Siléane results format); an image with no camera file above it and no
intrinsics given takes the training camera the export records, when it is of its size. Only numpy, OpenCV, SciPy, PyYAML and
onnxruntime are imported. Without ``--icp``, ``--search`` or ``--search-fast`` the model refines as its
export records (train.py's ``deploy_refine``; ``--no-refine``: the poses as decoded). An input's depth is normalized with the training scenes' clip planes
the export records (``--clip`` other planes, ``--camera-clip`` the camera's own). Outputs are never
overwritten without ``--overwrite``; a second run into a folder another run is writing into stops at
once. Exit status: 0, 1 when some images failed, 2 on bad arguments.
"""

from __future__ import annotations

import sys
from pathlib import Path

from opnet.arguments import ArgumentParser

from opnet.datasets.depth_inputs import (
    POSE_SUFFIXES,
    base_pose,
    claimed_outputs,
    given_camera,
    list_inputs,
    predict_inputs,
    write_pose_files,
)
from opnet.fileio.atomic import DiskFullError
from opnet.geometry.camera import describe_clip, parse_clip
from opnet.refine import ICPSettings


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(prog="python -m opnet.deploy", description=__doc__.split("\n\n")[0])
    ap.add_argument("model", type=Path)
    ap.add_argument("input", type=Path)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--camera", dest="file", help="camera YAML (fx fy cx cy clip_start clip_end [depth_scale] [T_base_cam: 4 x 4, camera to robot "
                         "base, for poses_base])")
    for key in ("fx", "fy", "cx", "cy", "clip-start", "clip-end", "depth-scale"):
        ap.add_argument(f"--{key}", dest=key.replace("-", "_"), type=float)
    ap.add_argument("--threads", type=int, default=None, help="ONNX Runtime threads (default: one per core)")
    ap.add_argument("--overwrite", action="store_true")
    ap.add_argument("--roi", default="model", help="region of interest: x0,y0,x1,y1 pixels, auto, or null (default: the model's)")
    planes = ap.add_mutually_exclusive_group()
    planes.add_argument("--clip", type=float, nargs=2, metavar=("NEAR", "FAR"), default=None,
                        help="clip planes (metres) the input's depth is normalized with, in place of the model's "
                             "training planes (default: those the export records, else the camera's)")
    planes.add_argument("--camera-clip", action="store_true",
                        help="normalize with each camera's own clip planes, not the model's training planes")
    ap.add_argument("--no-averaging", action="store_true",
                    help="decode without the exported DBSCAN averaging (with --search: every hypothesis a start)")
    refine = ap.add_mutually_exclusive_group()  # one refinement, or none
    refine.add_argument("--icp", action="store_true",
                        help="refine each pose by ICP against the depth (conf/refine/icp.yaml's defaults)")
    refine.add_argument("--search", action="store_true",
                        help="ICP, then the depth-agreement search of each pose (turns about the part's axis, shifts "
                             "across it; conf/refine/search.yaml's defaults): for flat parts; ranks poses by agreement")
    refine.add_argument("--search-fast", action="store_true",
                        help="--search in about half the time, a little less AP (conf/refine/search_fast.yaml's "
                             "defaults)")
    refine.add_argument("--no-refine", action="store_true",
                        help="the poses as decoded, whatever refinement the model records (its default otherwise)")
    ap.add_argument("--icp-budget-ms", type=float, default=None,
                    help="with --icp or --search: milliseconds per image (default 100 with --icp, none with --search; "
                         "0 = none refined)")
    args = ap.parse_args(argv)
    try:
        from opnet.deploy.runtime import OnnxPoseEstimator, recorded_refinement

        camera_cfg = {k: getattr(args, k) for k in ("file", "fx", "fy", "cx", "cy", "clip_start", "clip_end", "depth_scale")}
        given = given_camera(camera_cfg)
        searched = args.search or args.search_fast
        if args.icp_budget_ms is not None and not (args.icp or searched):
            raise ValueError("--icp-budget-ms is a setting of --icp, --search or --search-fast, none is given")
        named = "search_fast" if args.search_fast else "search" if args.search else "icp" if args.icp else None
        icp: ICPSettings | str | None = None if args.no_refine else "model"  # the model's own, by default
        if named is not None:
            icp = recorded_refinement(named, args.icp_budget_ms)
        roi = None if args.roi in ("null", "none") else args.roi
        clip = "camera" if args.camera_clip else parse_clip(args.clip, "--clip") or "model"
        estimator = OnnxPoseEstimator(args.model, threads=args.threads, icp=icp, roi=roi,
                                      averaging=False if args.no_averaging else None, clip=clip)
        print(describe_clip(estimator.clip, estimator.trained_clip))
        T_base_cam = base_pose(given, estimator.T_base_cam, str(args.model))
        given = given.with_default(estimator.camera, str(args.model))
        inputs = list_inputs(args.input)
        with claimed_outputs(args.out, inputs, args.overwrite, POSE_SUFFIXES, (args.model,), "--out") as scenes:
            obj = str(estimator.meta.get("object", ""))
            failed = predict_inputs(
                inputs, given, args.out, scenes, lambda image: estimator.predict(image.depth, image.camera),
                lambda name, image, hyps, scene: write_pose_files(args.out, name, image, hyps, obj, scene, T_base_cam))
    except (ValueError, FileNotFoundError, DiskFullError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{len(inputs) - failed} of {len(inputs)} predictions written to {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
