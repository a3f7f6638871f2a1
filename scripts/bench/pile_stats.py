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

``--keep``: the ``--out`` page's rows of the datasets not given stay on the page, above the new ones
(datasets are large and come and go; their rows were measured), and its command names them all.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from collections.abc import Sequence
from pathlib import Path

from opnet.studies.scenes import VIS_LABELS, pile_stats


def table(rows: list[tuple[str, dict]], kept: Sequence[str] = ()) -> str:
    """The datasets' statistics side by side, a row each, after the ``kept`` rows of an earlier page."""
    head = ("| dataset | scenes | parts / scene | full piles | " + " | ".join(f"vis {v}" for v in VIS_LABELS)
            + " | pile top mm (sd) | walls mm | fill | mean part height mm | lying flat | fully hidden (full piles) | clipped |")
    lines = [head, "|" + "---|" * (head.count("|") - 1), *kept]
    for name, s in rows:
        hist = " | ".join(f"{100 * h:.1f} %" for h in s["vis_hist"])
        lines.append(f"| {name} | {s['scenes']} | {s['parts_per_scene']:.1f} | {s['full_piles']} | {hist} | "
                     f"{s['height_max_mm']:.0f} ({s['height_max_sd_mm']:.0f}) | {s['walls_mm']:.0f} | {s['fill']:.2f} | "
                     f"{s['height_mean_mm']:.0f} | "
                     f"{100 * s['flat']:.1f} % | {100 * s['hidden']:.1f} % | {100 * s['clipped']:.1f} % |")
    return "\n".join(lines)


PROG = "scripts/bench/pile_stats.py"


def kept_rows(page: Path, given: list[Path]) -> tuple[list[str], list[str]]:
    """The dataset arguments of ``page``'s command and its table rows for the datasets that are not ``given``
    (``--keep``), in the page's order."""
    lines = page.read_text().splitlines() if page.is_file() else []
    command = next((shlex.split(line) for line in lines if line.strip().startswith(f"python {PROG}")), [])
    names = {d.name for d in given}
    args, i = [], 2
    while i < len(command):
        if command[i].startswith("--"):  # an option and its value
            i += 1 if command[i] == "--keep" else 2
            continue
        if Path(command[i]).name not in names:
            args.append(command[i])
        i += 1
    kept = {Path(a).name for a in args}
    return args, [line for line in lines if line.startswith("| ") and line.split("|")[1].strip() in kept]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("datasets", nargs="+", type=Path)
    ap.add_argument("--out", type=Path, default=None,
                    help="also write the table (markdown) here, under --title and the command that made it")
    ap.add_argument("--title", default="Pile statistics", help="the written page's heading")
    ap.add_argument("--keep", action="store_true",
                    help="keep the --out page's rows of the datasets not given")
    args = ap.parse_args()
    old_args, old_rows = kept_rows(args.out, args.datasets) if args.keep and args.out else ([], [])
    text = table([(d.name, pile_stats(d)) for d in args.datasets], old_rows)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        command = shlex.join(["python", PROG, *old_args, *sys.argv[1:]])
        args.out.write_text(f"# {args.title}\n\n    {command}\n\n{text}\n")


if __name__ == "__main__":
    main()
