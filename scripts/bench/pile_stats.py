"""Statistics of the piles of generated datasets, side by side: do two generator settings make the
same piles?

    python scripts/bench/pile_stats.py outputs/bench/bunny_v1 outputs/bench/bunny_v8 [--out results/dense/piles.md]

Per dataset: scenes, parts per scene, the visibility histogram of every part of every scene, and
for the full piles (the last scene of every cycle): the pile height (highest part origin above
the bin floor, and the mean) beside the height of the bin's walls and the fill (the parts' convex
hulls over the volume inside the walls; a generated dataset's rig), the share of parts lying flat
(the model's thinnest bounding-box axis within 20 degrees of the bin's vertical), the share
fully hidden and the share clipped (crossing the near clip plane: the part's top is cut off).
Poses are taken to the bin frame with the ground truth's bin pose, so camera differences between
datasets do not enter.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from opnet.studies.scenes import VIS_LABELS, pile_stats


def table(rows: list[tuple[str, dict]]) -> str:
    """The datasets' statistics side by side, a row each."""
    head = ("| dataset | scenes | parts / scene | full piles | " + " | ".join(f"vis {v}" for v in VIS_LABELS)
            + " | pile top mm (sd) | walls mm | fill | mean part height mm | lying flat | fully hidden (full piles) | clipped |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for name, s in rows:
        hist = " | ".join(f"{100 * h:.1f} %" for h in s["vis_hist"])
        lines.append(f"| {name} | {s['scenes']} | {s['parts_per_scene']:.1f} | {s['full_piles']} | {hist} | "
                     f"{s['height_max_mm']:.0f} ({s['height_max_sd_mm']:.0f}) | {s['walls_mm']:.0f} | {s['fill']:.2f} | "
                     f"{s['height_mean_mm']:.0f} | "
                     f"{100 * s['flat']:.1f} % | {100 * s['hidden']:.1f} % | {100 * s['clipped']:.1f} % |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("datasets", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, default=None,
                    help="also write the table (markdown) here, under --title and the command that made it")
    ap.add_argument("--title", default="Pile statistics", help="the written page's heading")
    args = ap.parse_args()
    text = table([(d.name, pile_stats(d)) for d in args.datasets])
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        command = shlex.join(["python", "scripts/bench/pile_stats.py", *sys.argv[1:]])
        args.out.write_text(f"# {args.title}\n\n    {command}\n\n{text}\n")


if __name__ == "__main__":
    main()
