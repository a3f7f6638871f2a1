"""The whole pipeline of a full camera frame, timed stage by stage: what a cell's robot waits for per frame.

    python scripts/bench/bench_frame.py --ckpt models/real_ipd_plate.ckpt --data <IPA-layout folder of full frames>
        [--frames 40] [--refine model|none|icp|search|search_fast] [--set KEY=VALUE ...] [--decoding KEY=VALUE ...]
        [--out results/.../frame_speed.md]

Per frame, as ``predict.py`` runs it (the checkpoint's framing, region of interest and clip planes; its recorded
refinement unless ``--refine`` says otherwise; ``--set`` changes its keys, e.g. ``search.merge=0``, ``--decoding``
the checkpoint's decoding, e.g. ``threshold=0.05``): *crop* (the bin finder's region of interest and the input's
preprocessing: crop, resize, fill), *network* (the fused fp32 forward), *decode* (hypotheses from the grid),
*refine* (the refinement; its own stages below it: *scene* the depth image's point cloud, *icp*, *search*,
*polish*, *rank*), *total*. Prints a table of the mean, median and worst milliseconds per stage (the
frames are read before the clock starts; the first frame warms up and is not counted).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import cv2
import numpy as np
import torch

from opnet.refine.pipeline import STAGES as REFINE_STAGES

STAGES = ("crop", "network", "decode", "refine", "total")
#: the refinement's own stages, rows of their own under *refine*
REFINE_ROWS = tuple(f"refine: {s}" for s in REFINE_STAGES)


def frames(root: Path, count: int) -> list:
    """The first ``count`` frames (depth and camera) of an IPA-layout folder."""
    from opnet.datasets.ipa import IPADataset

    dataset = IPADataset(root)
    return [dataset[i] for i in range(min(count, len(dataset)))]


@torch.no_grad()
def time_frames(ckpt: Path, records: list, refine: str, changes: tuple[list[str], list[str]] = ([], []),
                ) -> dict[str, np.ndarray]:  # fmt: skip
    """Milliseconds per stage (each (N,)) of every frame but the first; ``changes``: the refinement's and the
    decoding's ``KEY=VALUE`` overrides."""
    from opnet.cli.build import load_checkpoint
    from opnet.cli.eval import model_settings
    from opnet.data.preprocess import to_network_input
    from opnet.data.roi import crop_image
    from opnet.geometry.camera import with_clip, working_clip
    from opnet.refine import Refiner, refine_config

    system, _ = load_checkpoint(ckpt)
    system.configure_inference(None)
    # the search refines every hypothesis on its own: decoded without pose averaging (as eval.py and predict.py do)
    from omegaconf import OmegaConf

    group = {"method": refine} if refine in ("model", "none") else refine_config(refine)
    group = OmegaConf.to_container(OmegaConf.merge(group, OmegaConf.from_dotlist(changes[0])))
    decoding = {"averaging": False} if group.get("method") == "search" else {}
    decoding.update(OmegaConf.to_container(OmegaConf.from_dotlist(changes[1])))
    icp = model_settings(system, group, decoding or None)
    refiner = Refiner.for_object(system.parameterization.obj, icp) if icp is not None else None
    framing = system.settings.input
    clip = working_clip(None, framing.trained_clip)
    times: dict[str, list[float]] = {s: [] for s in (*STAGES, *REFINE_ROWS)}
    for k, record in enumerate(records):
        camera = with_clip(record.camera, clip) if clip is not None else record.camera
        t0 = time.perf_counter()
        depth, cam = crop_image(record.depth, camera, framing.roi, f"{record.name}: roi")
        net_in, net_cam = to_network_input(depth, cam, size=framing.size, interpolation=cv2.INTER_AREA, fit=framing.fit)
        t1 = time.perf_counter()
        x = torch.from_numpy(net_in)[None, None]
        output = system.infer(x)
        t2 = time.perf_counter()
        hyps = system.decode(output, [net_cam], x)[0]  # with the decoding's turns, their passes count here
        t3 = time.perf_counter()
        inside: dict[str, float] = {}
        if refiner is not None:
            hyps = refiner(hyps, record.depth, camera, inside)[0]
        t4 = time.perf_counter()
        if k == 0:
            continue  # warm-up
        for stage, ms in zip(STAGES, (t1 - t0, t2 - t1, t3 - t2, t4 - t3, t4 - t0), strict=True):
            times[stage].append(1000 * ms)
        for row, stage in zip(REFINE_ROWS, REFINE_STAGES, strict=True):
            times[row].append(1000 * inside.get(stage, 0.0))
    return {s: np.asarray(v) for s, v in times.items()}


def table(times: dict[str, np.ndarray]) -> list[str]:
    lines = ["| stage | mean ms | median ms | worst ms |", "|---|---|---|---|"]
    for s in (*STAGES[:4], *(r for r in REFINE_ROWS if times[r].any()), STAGES[4]):
        v = times[s]
        lines.append(f"| {s} | {v.mean():.0f} | {np.median(v):.0f} | {v.max():.0f} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ckpt", type=Path, required=True)
    ap.add_argument("--data", type=Path, required=True, help="an IPA-layout folder of full camera frames")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--refine", default="model", help="model (the checkpoint's recorded refinement), none, or a conf/refine name")
    ap.add_argument("--set", nargs="+", default=[], metavar="KEY=VALUE", help="the refinement's keys changed")
    ap.add_argument("--decoding", nargs="+", default=[], metavar="KEY=VALUE", help="the checkpoint's decoding changed")
    ap.add_argument("--out", type=Path, default=None, help="also write the table (markdown) here")
    args = ap.parse_args(argv)
    for path, what in ((args.ckpt, "--ckpt"), (args.data, "--data")):
        if not path.exists():
            print(f"error: {what} {path}: not found", file=sys.stderr)
            return 2
    if args.frames < 2:
        print(f"error: --frames {args.frames}: at least 2 (the first warms up)", file=sys.stderr)
        return 2
    for option, values in (("--set", args.set), ("--decoding", args.decoding)):
        bad = [v for v in values if "=" not in v]
        if bad:
            print(f"error: {option} {bad[0]!r}: not KEY=VALUE", file=sys.stderr)
            return 2
    times = time_frames(args.ckpt, frames(args.data, args.frames), args.refine, (args.set, args.decoding))
    cpu = platform.processor() or platform.machine()
    head = [f"`python scripts/bench/bench_frame.py --ckpt {args.ckpt} --data {args.data} --frames {args.frames} "
            f"--refine {args.refine}" + "".join(f" --{o} {' '.join(v)}" for o, v in (("set", args.set),
                                                                               ("decoding", args.decoding)) if v)
            + f"` on {cpu} ({os.cpu_count()} cores), {len(times['total'])} frames timed:", ""]
    lines = head + table(times)
    print("\n".join(lines))
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
