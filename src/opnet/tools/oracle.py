"""Ceiling study: the AP every parameterization reaches with a perfect network, per dataset.

    opnet-oracle --data <dir> [--data <dir> ...] --out <dir>
                 [--max-scenes N] [--object name] [--variant NAME[:key=value,...] ...]

``--variant`` (repeatable) studies only the named parameterizations, each optionally with settings
of its config, e.g. ``--variant ap --variant ap:placement=extent`` (the row is named
``ap:placement=extent``); without it every ``conf/parameterization/`` config is studied.

Each dataset's object comes from its ``object.json`` (an object config), else from ``--object`` (a
built-in or a conf/object/<name>.yaml). Prints the table and writes ceiling.md and ceiling.csv to
--out. The logic lives in :mod:`opnet.analysis.ceiling`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from opnet.analysis.ceiling import dataset_object, parameterization_configs, run_ceiling_study
from opnet.arguments import ArgumentParser, folder, variant_settings, whole
from opnet.cli.tools import require_folder, tool_main
from opnet.datasets import IPADataset, open_dataset
from opnet.settings_schema import TRAINING, check_value

#: the schema's names of the parameterization settings it declares (threshold, grid, ...), by config key
SCHEMA_NAMES = {key.removeprefix("parameterization."): name for name, key in TRAINING.items()
                if key.startswith("parameterization.")}


def variant_configs(variants: list[str]) -> dict[str, DictConfig]:
    """``NAME[:key=value,...]`` -> {the text: NAME's config with those settings}; ValueError naming the
    variant for an unknown name, a key its config does not document (``_target_`` and Hydra's other
    keys are none), a value that is not plain or that the schema refuses."""
    known = parameterization_configs()
    out = {}
    for text in variants:
        name, _, settings = text.partition(":")
        if name not in known:
            raise ValueError(f"--variant {text}: unknown parameterization {name!r}; expected one of {sorted(known)}")
        cfg = known[name].copy()
        documented = [k for k in cfg if not str(k).startswith("_")]
        for key, value in variant_settings(text, settings, documented, "--variant").items():
            if key in SCHEMA_NAMES:
                value = check_value(SCHEMA_NAMES[key], value, f"--variant {text}: {key}")
            cfg[key] = value
        out[text] = cfg
    return out


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=folder, action="append", required=True, help="dataset folder (repeatable)")
    parser.add_argument("--out", type=Path, required=True, help="folder for ceiling.md and ceiling.csv")
    parser.add_argument("--max-scenes", type=whole(1), default=None,
                        help="at most this many scenes per dataset, evenly spread")
    parser.add_argument("--object", default=None, help="object of datasets without object.json")
    parser.add_argument("--min-objects", type=whole(0), default=0,
                        help="only scenes with at least this many objects (IPA layout)")
    parser.add_argument("--variant", action="append", default=None,
                        help="NAME[:key=value,...]: a parameterization config with settings (repeatable)")
    args = parser.parse_args(argv)
    return tool_main(lambda: study(args))


def study(args: argparse.Namespace) -> int:
    """The study :func:`main` asks for: variants and the output folder checked, then every dataset read."""
    configs = variant_configs(args.variant) if args.variant else None
    require_folder(args.out, "--out")
    datasets = []
    for root in args.data:
        dataset = open_dataset(root)
        if args.min_objects:
            dataset = IPADataset(root, min_objects=args.min_objects)
        n = len(dataset) if args.max_scenes is None else min(args.max_scenes, len(dataset))
        picks = np.unique(np.linspace(0, len(dataset) - 1, n).round().astype(int)) if n else []
        datasets.append((dataset_object(root, args.object), [dataset[int(i)] for i in picks]))
        print(f"{root}: {len(picks)} of {len(dataset)} scenes, object {datasets[-1][0].name}")
    report = run_ceiling_study(datasets, configs)
    print(report.markdown())
    report.write(args.out)
    print(f"wrote {args.out / 'ceiling.md'} and {args.out / 'ceiling.csv'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
