"""Statistics of the piles of generated datasets, side by side: do two generator settings make the
same piles?

    python scripts/pile_stats.py outputs/bench/bunny_v1 outputs/bench/bunny_v8 [--out results/dense/piles.md]

Per dataset: scenes, parts per scene, the visibility histogram of every part of every scene, and
for the full piles (the last scene of every cycle): the pile height (highest part origin above
the bin floor, and the mean), the share of parts lying flat (the model's thinnest bounding-box
axis within 20 degrees of the bin's vertical) and the share fully hidden. Poses are taken to the
bin frame with the ground truth's bin pose, so camera differences between datasets do not enter.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from opnet.datasets.ipa import IPADataset, read_ipa_csv, scene_paths
from opnet.objects import object_from_config
from opnet.synthesis.layout import homogeneous, inverse_pose

VIS_EDGES = (0.0, 1e-9, 0.25, 0.5, 0.75, 1.0 + 1e-9)
VIS_LABELS = ("0", "(0, .25)", "[.25, .5)", "[.5, .75)", "[.75, 1]")
FLAT_DEG = 20.0


def pile_stats(root: Path) -> dict[str, float | list[float]]:
    """The statistics of one IPA dataset folder (module docstring)."""
    ds = IPADataset(root)
    obj = object_from_config(json.loads((root / "object.json").read_text()))
    thin_axis = np.eye(3)[int(np.argmin(obj.mesh.extents))]
    scenes = ds.scenes()
    last = max(n for _, n in scenes)
    vis_all, counts, heights, mean_heights, flat, hidden = [], [], [], [], [], []
    for cycle, n in scenes:
        gt = read_ipa_csv(scene_paths(root, cycle, n)["csv"])
        vis_all.append(gt.visibility_o)
        counts.append(n)
        if n != last or n == 0:
            continue
        T_bin_cam = inverse_pose(homogeneous(gt.R_cam_bin, gt.t_cam_bin))
        R_bin_obj = T_bin_cam[:3, :3] @ gt.R_cam_obj
        z = gt.t_cam_obj @ T_bin_cam[:3, :3].T[:, 2] + T_bin_cam[2, 3]
        heights.append(z.max())
        mean_heights.append(z.mean())
        up = np.abs((R_bin_obj @ thin_axis)[:, 2])
        flat.append(np.mean(up >= np.cos(np.radians(FLAT_DEG))))
        hidden.append(np.mean(gt.visibility_o == 0))
    vis = np.concatenate(vis_all)
    hist, _ = np.histogram(vis, bins=VIS_EDGES)
    return {
        "scenes": len(scenes), "parts_per_scene": float(np.mean(counts)), "full_piles": len(heights),
        "vis_hist": (hist / max(len(vis), 1)).tolist(),
        "height_max_mm": 1e3 * float(np.mean(heights)), "height_max_sd_mm": 1e3 * float(np.std(heights)),
        "height_mean_mm": 1e3 * float(np.mean(mean_heights)),
        "flat": float(np.mean(flat)), "hidden": float(np.mean(hidden)),
    }


def table(rows: list[tuple[str, dict]]) -> str:
    head = ("| dataset | scenes | parts / scene | full piles | " + " | ".join(f"vis {v}" for v in VIS_LABELS)
            + " | pile top mm (sd) | mean part height mm | lying flat | fully hidden (full piles) |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for name, s in rows:
        hist = " | ".join(f"{100 * h:.1f} %" for h in s["vis_hist"])
        lines.append(f"| {name} | {s['scenes']} | {s['parts_per_scene']:.1f} | {s['full_piles']} | {hist} | "
                     f"{s['height_max_mm']:.0f} ({s['height_max_sd_mm']:.0f}) | {s['height_mean_mm']:.0f} | "
                     f"{100 * s['flat']:.1f} % | {100 * s['hidden']:.1f} % |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("datasets", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, default=None, help="also write the table (markdown) here")
    args = ap.parse_args()
    text = table([(d.name, pile_stats(d)) for d in args.datasets])
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")


if __name__ == "__main__":
    main()
