"""Print the backbone statistics table: parameters, measured GFLOPs, CPU forward and training speed.

FLOPs are measured with torch.utils.flop_counter.FlopCounterMode (a multiply-add counts as 2 FLOPs;
convolutions only). Times are the best of ``--repeats`` runs on this machine's CPU threads.

    python scripts/bench/model_stats.py                       # all presets, grids 16, 8, 32
    python scripts/bench/model_stats.py --presets paper --grids 16 --no-timing
    python scripts/bench/model_stats.py --presets small tiny --grids 16 --train --threads 1
"""

from __future__ import annotations

import argparse

import torch

from opnet.models.stats import ModelStats
from opnet.studies.presets import preset_stats


def format_table(rows: list[ModelStats]) -> str:
    """The rows as a Markdown table."""

    def num(value: float | None, fmt: str) -> str:
        return "-" if value is None else format(value, fmt)

    lines = [
        "| preset | grid | parameters | GFLOP/image | fwd ms/img b=1 | fwd ms/img b=8 | train img/s b=16 fp32 (before) "
        "| train img/s b=16 bf16 + channels-last |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r.preset} | {r.out_grid} | {r.parameters / 1e6:.3f} M | {r.gflops:.3f} | "
            f"{num(r.ms_batch1, '.1f')} | {num(r.ms_batch8, '.1f')} | {num(r.train_images_per_s, '.1f')} | "
            f"{num(r.train_fast_images_per_s, '.1f')} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["paper", "small", "tiny"])
    parser.add_argument("--grids", nargs="+", type=int, default=[16, 8, 32])
    parser.add_argument("--out-channels", type=int, default=8)
    parser.add_argument("--no-timing", action="store_true", help="skip the forward timings")
    parser.add_argument("--train", action="store_true", help="also measure training images/s")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    rows = preset_stats(
        args.presets, args.grids, args.out_channels, not args.no_timing, args.train, args.repeats
    )
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} CPU threads; FLOP = 2 per multiply-add"
    )
    print(format_table(rows))


if __name__ == "__main__":
    main()
