"""How far the fast inference path is from the fp32 eager reference, on a trained model's scenes.

    python scripts/bench/check_inference.py --ckpt <run>/checkpoints/<best>.ckpt [--split test] [--out results/speed/inference_check.csv]

For each path (fp32 channels-last, bf16 autocast channels-last, the default: the fused fp32 form
on the CPU) it decodes
the split, pairs every hypothesis with the reference's (same scene, nearest pose), and reports:
hypotheses per path, the share paired within 0.1 mm and 0.05 deg, the largest and 99th-percentile
translation / rotation differences of the pairs, and the AP of both. Prints a table.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

from opnet.cli.build import build_datamodule, load_checkpoint
from opnet.fileio.atomic import append_csv_rows
from opnet.inference import InferenceSettings
from opnet.metrics.bregier import evaluate_scenes
from opnet.evaluation import predict_scenes

PATHS = {
    "fp32 eager (reference)": None,
    "fp32 channels-last": InferenceSettings("32", True, fused=False),
    "bf16 channels-last": InferenceSettings("bf16", True),
    "default": InferenceSettings(),  # named by what it resolves to for the checkpoint's network
}


def pair_differences(ref: dict, other: dict) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Translation (mm) and rotation (deg) differences of each reference hypothesis to the nearest
    hypothesis of the other path in the same scene; counts of hypotheses on both sides."""
    dt, dr, n_ref, n_other = [], [], 0, 0
    for name, (_, h_ref) in ref.items():
        h = other[name][1]
        n_ref, n_other = n_ref + len(h_ref), n_other + len(h)
        if len(h_ref) == 0 or len(h) == 0:
            continue
        d = np.linalg.norm(h_ref.t[:, None] - h.t[None], axis=-1)
        j = d.argmin(1)
        dt.append(1000 * d[np.arange(len(j)), j])
        rel = np.einsum("nij,nkj->nik", h_ref.R, h.R[j])
        cos = np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)
        dr.append(np.degrees(np.arccos(cos)))
    return (np.concatenate(dt) if dt else np.zeros(0)), (np.concatenate(dr) if dr else np.zeros(0)), n_ref, n_other


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", type=Path, required=True)
    ap.add_argument("--split", default="test")
    ap.add_argument("--out", type=Path, help="append the rows to this CSV")
    args = ap.parse_args(argv)
    system, run_cfg = load_checkpoint(args.ckpt)
    datamodule = build_datamodule(run_cfg, system.parameterization.obj, train=False)
    datamodule.setup("test")
    loader = getattr(datamodule, f"{args.split}_dataloader")()
    space, occ = system.parameterization.obj.pose_space, system.max_occlusion
    results, rows = {}, []
    for name, settings in PATHS.items():
        if name == "default":
            name = f"default ({settings.describe(system.device, system.backbone)})"
        if settings is None:
            system._fast = None
        else:
            system.configure_inference(settings)
        start = time.perf_counter()
        results[name] = predict_scenes(system, loader)
        seconds = time.perf_counter() - start
        ap_value = evaluate_scenes(results[name], space, max_occlusion=occ).ap
        dt, dr, n_ref, n = pair_differences(results["fp32 eager (reference)"], results[name])
        within = float(np.mean((dt <= 0.1) & (dr <= 0.05))) if len(dt) else 1.0
        rows.append([name, n, f"{within:.4f}", f"{dt.max(initial=0):.4f}", f"{np.percentile(dt, 99) if len(dt) else 0:.4f}",
                     f"{dr.max(initial=0):.4f}", f"{np.percentile(dr, 99) if len(dr) else 0:.4f}", f"{ap_value:.4f}",
                     f"{seconds:.1f}"])
        print(f"  {name}: {n} hypotheses (reference {n_ref}), AP {ap_value:.4f}, {seconds:.1f} s", flush=True)
    header = ["path", "hypotheses", "paired within 0.1 mm and 0.05 deg", "max dt mm", "p99 dt mm", "max dr deg",
              "p99 dr deg", "AP", "seconds"]
    print(f"\n{args.ckpt}, split {args.split} ({len(results['fp32 eager (reference)'])} scenes), torch threads "
          f"{torch.get_num_threads()}")
    print("| " + " | ".join(header) + " |\n|" + "---|" * len(header))
    for row in rows:
        print("| " + " | ".join(str(c) for c in row) + " |")
    if args.out:
        append_csv_rows(args.out, header, rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
