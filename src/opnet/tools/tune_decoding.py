"""Tune the decoding of a trained model on its validation split: score, minimum visibility, the input's turns
pooled and the pose-averaging settings (DBSCAN eps, min_samples, cluster score), measured, not guessed.

    opnet-tune-decoding --ckpt <run>/checkpoints/last.ckpt [--split val | --root <piles>] [--out <dir>]

The network runs once over the split and once over each quarter turn of it (``turns``, :mod:`opnet.parameterizations.turns`;
``--no-turns``: the configured turns kept, the network run only as they need); every setting then only re-decodes the stored outputs and
re-scores them with the Brégier AP. The search is coordinate-wise (each setting in turn over its
candidates, the others at their current best; two rounds). Prints a table and writes
``decoding_sweep.csv`` and ``decoding_sweep.md`` to ``--out`` (default: the run's
``tune_<split>/``). Several checkpoints (``--ckpt a --ckpt b``) are tuned jointly: the mean AP over
them decides, so that the chosen defaults hold for more than one model.

``--root <dataset>`` tunes on every scene of that dataset instead (those with at least the run's
``data.test_min_objects`` parts, as ``data.test_root`` scores them): validation piles of their own, more than a
run's validation share holds (a dense run's: two piles).

``--write <file.ckpt>`` saves a copy of the (first) checkpoint whose config decodes with the tuned
settings, so that eval.py, predict.py and export.py use them (an existing file only with ``--force``). ``--stride K`` tunes on every K-th
scene of the split (the scenes of one pile are much alike; dense piles decode slowly).

A refused checkpoint, a missing dataset or a target that cannot be written is one line
``error: <file>: <problem>`` with exit status 2; the targets are checked before the network runs,
and the files are written atomically (a failure leaves no temporary file and the old file as it was).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import torch  # noqa: E402

from opnet.arguments import ArgumentParser, whole  # noqa: E402
from opnet.cli.decoding_search import (  # noqa: E402  (the search itself; scripts read it through this tool too)
    AVERAGING_KEYS,
    CONFIG_KEYS,
    MAX_ROUNDS,
    SEARCH,
    TUNED_RECORD,
    Outputs,
    RecordedSplit,
    current_settings,
    decoder,
    decoding_arguments,
    decoding_overrides,
    every_kth,
    search,
    tune_in_place,
    tuned_line,
    write_table,
    write_tuned_checkpoint,
)
from opnet.cli.tools import require_folder, require_writable, tool_main  # noqa: E402

__all__ = ["AVERAGING_KEYS", "CONFIG_KEYS", "MAX_ROUNDS", "SEARCH", "TUNED_RECORD", "Outputs", "RecordedSplit",
           "current_settings", "decoder", "decoding_arguments", "decoding_overrides", "every_kth", "main", "search",
           "tune", "tune_in_place", "tuned_line", "write_table", "write_tuned_checkpoint"]


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ckpt", action="append", required=True, help="checkpoint (repeat to tune jointly)")
    parser.add_argument("--split", default="val", choices=("val", "test", "train"))
    parser.add_argument("--root", type=Path, default=None,
                        help="tune on every scene of this dataset instead of the run's --split")
    parser.add_argument("--rounds", type=whole(1, MAX_ROUNDS), default=2,
                        help=f"rounds of the coordinate-wise search (1 to {MAX_ROUNDS})")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--stride", type=whole(1), default=1, help="tune on every K-th scene of the split")
    parser.add_argument("--write", type=Path, default=None,
                        help="save a copy of the (first) checkpoint that decodes with the tuned settings")
    parser.add_argument("--force", action="store_true", help="replace an existing --write file")
    parser.add_argument("--no-turns", action="store_true",
                        help="keep the configured turns (the network run only on the turns they pool)")
    args = parser.parse_args(argv)
    return tool_main(lambda: tune(args))


@torch.no_grad()
def tune(args: argparse.Namespace) -> int:
    """The tuning :func:`main` asks for: record, search, write."""
    where = args.split if args.root is None else args.root.name
    out = args.out or Path(args.ckpt[0]).resolve().parent.parent / f"tune_{where}"
    if args.root is not None and not args.root.is_dir():
        raise FileNotFoundError(f"{args.root}: dataset folder not found (--root)")
    require_folder(out, "--out")  # before the network runs, not after
    require_writable(out / "decoding_sweep.csv", "--out")
    if args.write is not None:
        require_writable(args.write, "--write", replace=args.force)
    splits = []
    for ckpt in args.ckpt:
        print(f"recording {where} outputs of {ckpt}", flush=True)
        splits.append(RecordedSplit.record(ckpt, args.split, args.stride, None if args.no_turns else (1, 2, 3),
                                           args.root))
    best, rows = search(splits, args.rounds)
    write_table(rows, out)
    print(f"written {out}/decoding_sweep.csv, {out}/decoding_sweep.md")
    if args.write is not None:
        write_tuned_checkpoint(args.ckpt[0], args.write, best)
        print(f"written {args.write}: {args.ckpt[0]} decoding with {best}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
