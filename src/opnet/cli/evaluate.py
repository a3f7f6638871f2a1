"""``opnet-evaluate``: the Brégier evaluation of pose hypotheses against Siléane-format ground truth.

    opnet-evaluate --gt <dir> --results <dir> (--poseutils <json> | --object <name>)
                   [--max-occlusion 0.5] [--out summary.json] [--plot pr.png] [--skip-missing] [--diagnose]

Reads ``<gt>/*.json`` (or ``.JSON``) and the results file of the same name in ``<results>``
(docs/formats.md#siléane-layout). A scene without a results file counts as a scene with no
hypotheses (with a warning); ``--skip-missing`` drops it as the official tool does. Prints the
metrics table (with ``--diagnose`` also where the misses went and the turns of the orientation misses,
:mod:`opnet.metrics.diagnostics`, as eval.py prints them), optionally writes the summary JSON (atomically) and a PR plot. Bad input exits with
status 2 and a one-line message naming the file.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from opnet.datasets.sileane_json import SceneFileWarning, read_scene_pairs, write_json_atomic
from opnet.metrics.bregier import evaluate_scenes
from opnet.metrics.diagnostics import diagnose, orientation_misses
from opnet.metrics.report import NonMonotoneRecallWarning
from opnet.objects import ObjectModel, builtin_names, builtin_object, object_from_config
from opnet.paths import config_dir, shared_dir

PROG = "opnet-evaluate"


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=PROG, description="Brégier et al. pose-recovery evaluation.")
    p.add_argument("--gt", required=True, type=Path, help="folder of ground-truth <scene>.json")
    p.add_argument("--results", required=True, type=Path, help="folder of results <scene>.json")
    obj = p.add_mutually_exclusive_group(required=True)
    obj.add_argument("--poseutils", type=Path, help="the object's official poseutils.json")
    obj.add_argument("--object", help="a built-in object or a conf/object/<name>.yaml config")
    p.add_argument("--max-occlusion", type=float, default=0.5,
                   help="instances more occluded need not be found (default 0.5)")
    p.add_argument("--max-nb-results", type=int, default=-1,
                   help="keep the k best hypotheses per scene (default -1: all)")
    p.add_argument("--out", type=Path, help="write the summary JSON here")
    p.add_argument("--plot", type=Path, help="save the mean PR curve here (.png, .pdf, .svg)")
    p.add_argument("--skip-missing", action="store_true",
                   help="drop scenes without a results file, as the official tool does")
    p.add_argument("--quiet", action="store_true", help="headline metrics only, no per-scene lines")
    p.add_argument("--diagnose", action="store_true",
                   help="also where the misses went and the turns of the orientation misses (in --out too)")
    return p


def object_names() -> list[str]:
    """Names ``--object`` accepts: the built-ins and every ``conf/object/*.yaml``."""
    configs = {p.stem for p in config_dir().joinpath("object").glob("*.yaml")}
    return sorted(configs | set(builtin_names()))


def resolve_object(name: str) -> ObjectModel:
    """An object model from a ``conf/object/<name>.yaml`` config, else from the built-in library.

    ``${paths.shared_dir}`` in a config resolves to :func:`opnet.paths.shared_dir`.
    """
    from omegaconf import OmegaConf  # only this path needs it

    if not re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.-]*", name) or ".." in name:
        raise ValueError(f"--object {name!r}: a name of conf/object/ or a built-in, not a path "
                         f"(available: {', '.join(object_names())}); for another file give --poseutils")
    config = config_dir() / "object" / f"{name}.yaml"
    if config.is_file():
        paths = {"shared_dir": str(shared_dir())}
        try:
            root = OmegaConf.create({"paths": paths, "object": OmegaConf.load(config)})
            cfg: Any = OmegaConf.to_container(root.object, resolve=True)
        except Exception as e:  # yaml and interpolation errors have many types
            raise ValueError(f"{config}: cannot read object config ({type(e).__name__}: {e})") from e
        if not isinstance(cfg, dict):
            raise ValueError(f"{config}: expected a mapping of object settings")
        try:
            return object_from_config(cfg)
        except ValueError as e:
            raise ValueError(f"{config}: {e}") from e
    if name in builtin_names():
        return builtin_object(name)
    available = ", ".join(object_names())
    raise ValueError(f"unknown object {name!r}; available: {available} (or give --poseutils)")


def object_from_args(args: argparse.Namespace) -> ObjectModel:
    """The object of ``--poseutils`` (its metric side: Λ, δ, D = 10 δ) or ``--object``."""
    if args.poseutils is not None:
        return ObjectModel.from_poseutils(args.poseutils)
    return resolve_object(args.object)


def run(args: argparse.Namespace) -> int:
    """Evaluate as ``args`` say; raises ValueError / OSError on bad input."""
    if not 0.0 <= args.max_occlusion <= 1.0:
        raise ValueError(f"--max-occlusion must be in [0, 1], got {args.max_occlusion}")
    obj = object_from_args(args)
    space = obj.pose_space
    scenes = read_scene_pairs(args.gt, args.results, skip_missing=args.skip_missing)
    if not scenes:
        raise ValueError(f"{args.gt}: no scenes to evaluate (no ground-truth .json files, or all skipped)")
    summary = evaluate_scenes(
        scenes, space, max_occlusion=args.max_occlusion, max_nb_results=args.max_nb_results
    )
    print(summary.table(per_scene=not args.quiet))
    result = summary.to_dict(curve=True)
    if args.diagnose:  # of the hypotheses the AP counts
        kept = {name: (gt, h.best(args.max_nb_results)) for name, (gt, h) in scenes.items()}
        diagnostics = diagnose(kept, space, obj.diameter, max_occlusion=args.max_occlusion)
        misses = orientation_misses(kept, space, obj.diameter, max_occlusion=args.max_occlusion)
        print(f"\n{diagnostics.table()}\n{misses.table()}")
        no_nan = {k: None if isinstance(v, float) and not math.isfinite(v) else v  # JSON has no NaN: null
                  for k, v in diagnostics.to_dict().items()}
        result |= {"diagnostics": no_nan, "orientation_misses": misses.to_dict()}
    if args.out is not None:
        write_json_atomic(args.out, result)
        print(f"summary written to {args.out}")
    if args.plot is not None:
        from opnet.metrics.plot import plot_pr_curve  # matplotlib only when asked

        plot_pr_curve(summary, args.plot, title=str(args.results))
        print(f"PR curve written to {args.plot}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the exit status (0 ok, 2 bad input)."""
    args = build_parser().parse_args(argv)

    def show(message: Warning | str, category: type[Warning], *_: Any, **__: Any) -> None:
        print(f"{PROG}: warning: {message}", file=sys.stderr)

    with warnings.catch_warnings():
        for category in (SceneFileWarning, NonMonotoneRecallWarning):
            warnings.simplefilter("always", category)
        warnings.showwarning = show
        try:
            return run(args)
        except (ValueError, OSError) as e:
            print(f"{PROG}: error: {e}", file=sys.stderr)
            return 2


if __name__ == "__main__":
    sys.exit(main())
