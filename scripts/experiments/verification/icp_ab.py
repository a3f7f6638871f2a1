"""ICP refinement A/B: the same network outputs scored without and with ICP.

    python scripts/experiments/verification/icp_ab.py --ckpt outputs/table1/ap_bunny_s0/checkpoints/<best>.ckpt \\
        [--ckpt ...] [--split test] [--budget-ms 100 none] [--search] [--decoding averaging=false] \\
        [--data test_root=<dataset> --data cache=false] [--out results/icp]

Per checkpoint the network runs once over the split (held-out scenes); the hypotheses are then
scored as decoded and refined with ``conf/refine/icp.yaml``'s settings at each time budget per
image (``none``: every hypothesis), and with ``--search`` by ``conf/refine/search.yaml`` (ICP and
the depth-agreement search, no budget). ``--decoding KEY=VALUE`` adds the same rows with the
checkpoint's decoding overridden as ``eval.py decoding=`` does, ``--data KEY=VALUE`` sets its data section (another test set,
the scene cache off: refinement at the dataset's own resolution). Printed and written to
``--out``/``ab.md`` and ``ab.csv``: AP (Brégier, max occlusion 0.5), parts found, matched
translation / rotation error p50 and p90, refinement milliseconds per image and how many
hypotheses were refined, searched, dropped as duplicates, rejected by the guard, skipped for want
of depth, or left by the budget.
"""

from __future__ import annotations

import argparse
import copy
import csv
import io
import os
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import torch
from omegaconf import OmegaConf

from opnet.cli.build import build_datamodule, load_checkpoint
from opnet.cli.eval import refine_scenes, with_decoding_overrides
from opnet.evaluation import predict_scenes
from opnet.paths import REPO_ROOT
from opnet.refine import ICPSettings, settings_from_config
from opnet.studies.refinement import key_values, refine_variant, score_refined


def budgets(values: list[str]) -> list[float | None]:
    """``["100", "none"]`` -> [100.0, None]; ValueError naming a bad one."""
    out: list[float | None] = []
    for v in values:
        if v.lower() in ("none", "null"):
            out.append(None)
            continue
        try:
            out.append(float(v))
        except ValueError:
            raise ValueError(f"--budget-ms {v!r}: expected milliseconds or none") from None
    return out


def search_variant(text: str) -> tuple[str, ICPSettings]:
    """``LABEL:KEY=VALUE[,KEY=VALUE...]`` -> (label, conf/refine/search.yaml with ``icp.KEY`` / ``search.KEY``
    overridden); ValueError naming the option for anything else."""
    base = OmegaConf.to_container(OmegaConf.load(REPO_ROOT / "conf" / "refine" / "search.yaml"))
    return refine_variant(text, base, "--search-variant")


def run(ckpt: Path, split: str, budget_list: list[float | None], search: bool = False,
        decoding: dict[str, Any] | None = None, data: dict[str, Any] | None = None,
        variants: list[tuple[str, ICPSettings]] = (), as_trained: bool = True) -> list[dict[str, Any]]:  # fmt: skip
    """The rows of one checkpoint: its decoding as trained (unless not ``as_trained``), then (``decoding``) as
    overridden."""
    rows = run_decoding(ckpt, split, budget_list, search, None, data, variants) if as_trained or not decoding else []
    return rows + (run_decoding(ckpt, split, budget_list, search, decoding, data, variants) if decoding else [])


def run_decoding(ckpt: Path, split: str, budget_list: list[float | None], search: bool,
                 decoding: dict[str, Any] | None, data: dict[str, Any] | None,
                 variants: list[tuple[str, ICPSettings]] = ()) -> list[dict[str, Any]]:  # fmt: skip
    system, cfg = load_checkpoint(str(ckpt))
    system.parameterization = with_decoding_overrides(system.parameterization, decoding)
    if data:
        cfg = OmegaConf.merge(cfg, {"data": {**data, **({"generate": None} if cfg.data.get("generate") else {})}})
    obj = system.parameterization.obj
    dm = build_datamodule(cfg, obj, train=False)
    dm.setup("test")
    scenes = predict_scenes(system, getattr(dm, f"{split}_dataloader")())
    max_occ = system.max_occlusion
    name = ckpt.resolve().parent.parent.name
    shown = ",".join(f"{k}={v}" for k, v in (decoding or {}).items()) or "as trained"
    rows = [{"run": name, "object": obj.name, "decoding": shown, "refine": "none", "scenes": len(scenes),
             **score_refined(scenes, obj, max_occ)}]  # fmt: skip
    base = dict(OmegaConf.to_container(OmegaConf.load(REPO_ROOT / "conf" / "refine" / "icp.yaml"))["icp"])
    arms: list[tuple[str, ICPSettings]] = [
        ("icp, no budget" if b is None else f"icp, {b:g} ms budget", ICPSettings.from_config({**base, "budget_ms": b}))
        for b in budget_list]  # fmt: skip
    if search:
        arms.append(("icp + search", settings_from_config(OmegaConf.load(REPO_ROOT / "conf" / "refine" / "search.yaml"))))
    arms += [(f"icp + search, {label}", settings) for label, settings in variants]
    for label, settings in arms:
        refined = copy.deepcopy(scenes)
        start = time.perf_counter()
        report = refine_scenes(refined, dm.splits[split], obj, settings)
        wall = time.perf_counter() - start
        rows.append({"run": name, "object": obj.name, "decoding": shown, "refine": label, "scenes": len(scenes),
                     **score_refined(refined, obj, max_occ), "icp_ms_per_image": report["ms_per_image"],
                     "wall_s": wall, **report["statuses"]})  # fmt: skip
        print(f"{name}: {label}: AP {rows[-1]['ap']:.4f}", flush=True)
    return rows


def markdown(rows: list[dict[str, Any]]) -> str:
    keys = ["run", "object", "decoding", "refine", "scenes", "ap", "found", "t_mm_p50", "t_mm_p90", "r_deg_p50",
            "r_deg_p90", "icp_ms_per_image", "refined", "searched", "suppressed", "rejected", "no_depth", "budget"]

    def fmt(v: Any) -> str:
        return "–" if v is None else f"{v:.3f}" if isinstance(v, float) else str(v)

    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(fmt(r.get(k)) for k in keys) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ckpt", action="append", required=True, type=Path)
    parser.add_argument("--split", default="test", choices=("val", "test"))
    parser.add_argument("--budget-ms", nargs="+", default=["100", "none"])
    parser.add_argument("--search", action="store_true", help="also ICP + the depth-agreement search (refine=search)")
    parser.add_argument("--decoding", action="append", default=[], metavar="KEY=VALUE",
                        help="decoding override (eval.py decoding=), e.g. averaging=false")
    parser.add_argument("--data", action="append", default=[], metavar="KEY=VALUE",
                        help="data-section override, e.g. test_root=<dataset> or cache=false")
    parser.add_argument("--search-variant", action="append", default=[], metavar="LABEL:KEY=VALUE,...",
                        help="also the search with conf/refine/search.yaml's icp.KEY / search.KEY overridden")
    parser.add_argument("--overridden-only", action="store_true",
                        help="with --decoding: only the rows of the overridden decoding")
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "icp")
    args = parser.parse_args(argv)
    try:
        budget_list = budgets(args.budget_ms)
        decoding, data = key_values(args.decoding, "--decoding"), key_values(args.data, "--data")
        variants = [search_variant(v) for v in args.search_variant]
    except ValueError as e:
        parser.error(str(e))
    for ckpt in args.ckpt:
        if not ckpt.is_file():
            parser.error(f"--ckpt {ckpt}: no such file")
    torch.set_grad_enabled(False)
    rows = [row for ckpt in args.ckpt for row in run(ckpt, args.split, budget_list, args.search, decoding, data, variants,
                                                       not args.overridden_only)]
    text = markdown(rows)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "ab.md").write_text(text)
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
    writer.writeheader()
    writer.writerows(rows)
    (args.out / "ab.csv").write_text(buf.getvalue())
    (args.out / "command.txt").write_text("python scripts/experiments/verification/icp_ab.py " + " ".join(sys.argv[1:] if argv is None else argv) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
