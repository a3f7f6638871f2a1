"""Re-render the official Siléane bunny piles as a held-out dense-pile test set of another generator.

The Siléane sample (``../shared/data/sileane_bunny_sample``) holds the ground truth of 11 real
benchmark piles (70-80 bunnies, world frame, metres, z up, the floor at z = 0) but no images, and
the pose of their camera is unknown. This script

1. fits the camera pose to the official occlusion rates (:mod:`sileane_fit`): the camera looks
   straight down, ``R_world_cam = Rz(yaw) @ diag(1, -1, -1)`` (yaw 0: camera x = world x, camera
   y = -world y), at ``(x, y, height)``; every pile is rendered with opnet's ``SceneRenderer``
   over a floor at z = 0 and the modelled occlusion compared with the official one;
2. renders every pile at that pose and writes a Siléane-layout folder that ``data=sileane`` reads:
   ``depth/<scene>.PNG`` (uint16 clip code, 65535 = none), ``segmentation/<scene>.PNG`` (uint16,
   the official ``segmentation_id`` of each part, 0 elsewhere), ``gt/<scene>.json`` (the official
   files, byte for byte, occlusion rates included), ``camera_params.txt`` (the fitted pose,
   camera -> world) and the official ``poseutils.json``;
3. checks what it wrote: every scene read back with opnet's Siléane reader, depth within the clip
   planes, the ground truth projecting onto its own segment.

    PYOPENGL_PLATFORM=egl python scripts/experiments/sileane/sileane_rerender.py [--out outputs/data/sileane_rerender]
    PYOPENGL_PLATFORM=egl python scripts/experiments/sileane/sileane_rerender.py --fitted                 # the recorded fit
    PYOPENGL_PLATFORM=egl python scripts/experiments/sileane/sileane_rerender.py --pose 0 -0.1 0.0 1.5    # any pose

Exit status: 0 written and checked, 1 a check failed, 2 bad arguments or input files.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402

from opnet.analysis.sileane_fit import (  # noqa: E402
    FITTED_POSE,
    FITTED_RADIUS,
    CameraPose,
    Pile,
    PileRenderer,
    evaluate,
    load_piles,
    mesh_frame_variants,
    search_pose,
)
from opnet.datasets.png import encode_depth, write_png  # noqa: E402
from opnet.datasets.record import SceneRecord  # noqa: E402
from opnet.datasets.sileane import CAMERA_FILE, SileaneDataset  # noqa: E402
from opnet.fileio.atomic import write_text_atomic  # noqa: E402
from opnet.geometry.camera import Camera  # noqa: E402
from opnet.paths import REPO_ROOT, shared_dir  # noqa: E402

DEFAULT_OUT = REPO_ROOT / "outputs" / "data" / "sileane_rerender"
CAMERA_YAML = REPO_ROOT / "conf" / "cameras" / "sileane_bunny.yaml"
POSEUTILS_FILE = "poseutils.json"
#: a visible model point lies on the rendered surface within this depth (metres)
FRONT_TOL_M = 0.003


def camera_params_text(camera: Camera, pose: CameraPose, note: str = "") -> str:
    """The ``camera_params.txt`` of the Siléane layout (read back by ``read_camera_params``):
    intrinsics in pixels, clip planes in metres, ``location`` the camera centre in the world
    (metres) and ``rotation`` the quaternion (w x y z) of ``R_world_cam`` (camera -> world)."""
    q = pose.quaternion()
    lines = [f"# {line}" for line in note.splitlines()] + [
        f"width\t{camera.width}", f"height\t{camera.height}",
        f"fu\t{camera.fx!r}", f"fv\t{camera.fy!r}", f"cu\t{camera.cx!r}", f"cv\t{camera.cy!r}",
        f"clip_start\t{camera.clip_start!r}", f"clip_end\t{camera.clip_end!r}",
        "location\t" + "\t".join(f"{v:.6f}" for v in pose.t_world_cam()),
        "rotation\t" + "\t".join(f"{v:.9f}" for v in q),
    ]  # fmt: skip
    return "\n".join(lines) + "\n"


def write_dataset(out: Path, renderer: PileRenderer, piles: list[Pile], pose: CameraPose,
                  poseutils: Path | None, note: str = "") -> None:
    """Render every pile at ``pose`` and write the Siléane-layout folder ``out`` (module docstring).

    Raises:
        ValueError: a segmentation id outside 1..65535 (the official files hold uint16 ids).
    """
    camera = renderer.camera
    for sub in ("depth", "segmentation", "gt"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    for pile in piles:
        ids = pile.gt.segmentation_id
        if ids.min() < 1 or ids.max() > 65535:
            raise ValueError(f"{pile.path}: segmentation ids must lie in 1..65535 to fit a uint16 "
                             f"segmentation image, got {ids.min()}..{ids.max()}")
        scene = renderer.render(pile, pose)
        lut = np.concatenate([[0], ids]).astype(np.uint16)  # drop order k (1-based) -> official id
        write_png(out / "depth" / f"{pile.name}.PNG",
                  encode_depth(scene.depth, camera.clip_start, camera.clip_end))
        write_png(out / "segmentation" / f"{pile.name}.PNG", lut[scene.segmentation])
        shutil.copyfile(pile.path, out / "gt" / pile.path.name)
    write_text_atomic(out / CAMERA_FILE, camera_params_text(camera, pose, note))
    if poseutils is not None and poseutils.is_file():
        shutil.copyfile(poseutils, out / POSEUTILS_FILE)


def own_segment_fraction(record: SceneRecord, points_model: np.ndarray, max_occlusion: float = 0.5
                         ) -> tuple[float, float]:
    """How well the ground truth of ``record`` lies on its own segmentation.

    Args:
        record: a scene read back by the Siléane reader (camera-frame poses, metres).
        points_model: (P, 3) model points (mesh vertices), metres.
        max_occlusion: only the parts the benchmark requires (official occlusion <= this) count.
    Returns:
        (front, all): mean over those parts of the fraction of their projected points on their own
        segment id, among the points that lie on the rendered surface (within ``FRONT_TOL_M`` of
        the depth: should be ~1), and among all points inside the image (~ their visibility).
    """
    cam, depth, seg = record.camera, record.depth, record.segmentation
    assert seg is not None
    front, every = [], []
    for k in np.flatnonzero(1.0 - record.visibility <= max_occlusion):
        p = points_model @ record.R_cam_obj[k].T + record.t_cam_obj[k]
        uv = np.rint(cam.project(p)).astype(int)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        if not inside.any():
            continue
        u, v, z = uv[inside, 0], uv[inside, 1], p[inside, 2]
        own = seg[v, u] == record.instance_id[k]
        on_surface = np.abs(depth[v, u] - z) < FRONT_TOL_M
        every.append(own.mean())
        if on_surface.any():
            front.append(own[on_surface].mean())
    return float(np.mean(front)) if front else 0.0, float(np.mean(every)) if every else 0.0


def verify(out: Path, points_model: np.ndarray) -> list[str]:
    """Read every scene of ``out`` back with opnet's Siléane reader; the problems found (one line
    each, naming the scene), and a summary line printed."""
    ds = SileaneDataset(out)
    problems, fronts, alls = [], [], []
    for name in ds.scenes():
        record = ds.read(name)
        valid = np.isfinite(record.depth)
        if not valid.all():
            problems.append(f"{out}/depth/{name}.PNG: {int((~valid).sum())} pixels without depth")
        lo, hi = np.nanmin(record.depth), np.nanmax(record.depth)
        if lo < record.camera.clip_start or hi > record.camera.clip_end:
            problems.append(f"{out}/depth/{name}.PNG: depth {lo:.3f}..{hi:.3f} m outside the clip planes")
        front, every = own_segment_fraction(record, points_model)
        fronts.append(front)
        alls.append(every)
        if front < 0.95:
            problems.append(f"{out}/gt/{name}.json: only {front:.1%} of the visible model points "
                            "of the required parts fall on their own segment")
    print(f"read back {len(ds)} scenes: visible model points of the required parts on their own "
          f"segment {np.mean(fronts):.2%} (all projected points: {np.mean(alls):.2%})")
    return problems


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="scripts/experiments/sileane/sileane_rerender.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("--sample", type=Path, default=shared_dir() / "data" / "sileane_bunny_sample",
                        help="the official sample folder (gt/*.json, poseutils.json)")
    parser.add_argument("--mesh", type=Path, default=shared_dir() / "data" / "meshes" / "SileaneBunny.obj")
    parser.add_argument("--camera", type=Path, default=CAMERA_YAML, help="the Siléane bunny camera")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    parser.add_argument("--scenes", nargs="+", help="scene names (default: every gt/*.json)")
    pose = parser.add_mutually_exclusive_group()
    pose.add_argument("--pose", type=float, nargs=4, metavar=("YAW_DEG", "X", "Y", "HEIGHT"),
                      help="use this camera pose (degrees, metres), no search")
    pose.add_argument("--fitted", action="store_true", help=f"use the recorded fit ({FITTED_POSE}), no search")
    parser.add_argument("--radius", type=float, default=None,
                        help="clearance radius (px) of the occlusion model, with --pose (default: fitted)")
    parser.add_argument("--no-frames", action="store_true", help="skip the mesh-frame check")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        from opnet.datasets.camera_file import read_camera_file
        from opnet.objects.io import load_mesh

        camera = read_camera_file(args.camera)
        mesh = load_mesh(args.mesh)
        piles = load_piles(args.sample / "gt", args.scenes)
    except (FileNotFoundError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    renderer = PileRenderer(mesh, camera)
    if args.fitted:
        pose, radius = FITTED_POSE, FITTED_RADIUS if args.radius is None else args.radius
    elif args.pose is not None:
        pose, radius = CameraPose(*args.pose), args.radius
    else:
        pose, radius = search_pose(renderer, piles, log=print)
    table = evaluate(renderer, piles, pose)
    radius = table.best_radius() if radius is None else radius
    exact, modelled = table.agreement(0.0), table.agreement(radius)
    print(f"pose {pose}: {len(table.official)} parts in {len(piles)} piles")
    print(f"  renderer visibility (exact):       {exact.line()}")
    print(f"  clearance model r = {radius:g} px:       {modelled.line()}")
    if not args.no_frames:
        for name, variant in mesh_frame_variants(mesh, args.sample / POSEUTILS_FILE).items():
            other = evaluate(PileRenderer(variant, camera), piles, pose)
            print(f"  model frame {name:>6}, r = {radius:g} px:  {other.agreement(radius).line()}")
    note = (f"written by scripts/experiments/sileane/sileane_rerender.py: camera pose fitted to the official occlusion rates\n"
            f"{pose}; mean |d occlusion| {exact.mad:.4f} (renderer), {modelled.mad:.4f} (r = {radius:g} px)")
    write_dataset(args.out, renderer, piles, pose, args.sample / POSEUTILS_FILE, note)
    problems = verify(args.out, np.asarray(mesh.vertices))
    print(f"wrote {args.out} ({len(piles)} scenes) in {time.perf_counter() - start:.0f} s")
    for line in problems:
        print(f"problem: {line}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
