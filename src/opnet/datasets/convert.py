"""Command line: a dataset folder's ground truth as Siléane JSON files, one per scene.

``python -m opnet.datasets.convert <dataset dir> <out dir> [--frame camera|world]`` works for IPA
and Siléane folders (detected by :func:`open_dataset`) and reads only the annotation files. Camera
frame by default, the frame our pose hypotheses are in; ``world`` keeps a Siléane folder's poses as
stored (for hypotheses in its world frame, e.g. the official evaluation sample).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

from opnet.datasets.autodetect import open_dataset
from opnet.datasets.ground_truth import (
    dataset_ground_truth,
    record_to_ground_truth,
    write_ground_truth_files,
    write_sileane_ground_truth,
)

__all__ = [
    "convert_dataset",
    "main",
    "open_dataset",
    "record_to_ground_truth",
    "write_sileane_ground_truth",
]


def convert_dataset(
    dataset_dir: str | Path, out_dir: str | Path, frame: Literal["camera", "world"] = "camera"
) -> list[Path]:
    """Write ``<out_dir>/<scene>.json`` for every scene of ``dataset_dir``; returns the files."""
    dataset = open_dataset(dataset_dir)
    if frame not in ("camera", "world"):
        raise ValueError(f"frame must be 'camera' or 'world', got {frame!r}")
    return write_ground_truth_files(dataset_ground_truth(dataset, frame), Path(out_dir))


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point; returns the exit status (2 with a one-line message for bad input)."""
    parser = argparse.ArgumentParser(
        prog="python -m opnet.datasets.convert", description=__doc__.splitlines()[0]
    )
    parser.add_argument("dataset_dir", type=Path, help="IPA or Siléane dataset folder")
    parser.add_argument("out_dir", type=Path, help="folder for the <scene>.json ground-truth files")
    parser.add_argument(
        "--frame", choices=("camera", "world"), default="camera", help="pose frame (default camera)"
    )
    args = parser.parse_args(argv)
    try:
        files = convert_dataset(args.dataset_dir, args.out_dir, args.frame)
    except (OSError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {len(files)} ground-truth files to {args.out_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
