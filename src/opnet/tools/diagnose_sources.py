"""Where the hypotheses of a trained model come from and what each source is worth.

    opnet-diagnose-sources --ckpt outputs/table1/ap_bunny_s0/checkpoints/last.ckpt \\
        --ckpt outputs/table1/vanilla_bunny_s0/checkpoints/last.ckpt [--split test] [--out DIR]

The network runs once over the split (held-out test scenes by default). Every cell of the
parameterization's target belongs to one instance and has a *source*: ``origin`` (the cell of the
projected origin, vanilla's only cell) or ``other`` (an EVE extension, an AP additional point's
cell, an SI mask cell). Printed and written per checkpoint:

1. **cells by source**, for the required instances (visibility >= 1 - max occlusion) and the others:
   how many, the mean presence p̂, the share that fires (p̂ > τ), and the error of the pose decoded
   from the cell itself against its instance: translation p50/p90 mm, rotation p50 °, the share
   within δ (a correct pose by the metric), the mean predicted score of those cells, and the share
   of the cell's input pixels that show its own part (``shows_part``: what the network can see);
2. **fired cells outside the target** (no instance there: the source of false positives);
3. **decoding variants** scored with the Brégier AP and the miss diagnostics
   (:func:`opnet.metrics.diagnostics.diagnose`): as configured; without averaging; and two oracle
   ablations that use the ground truth to drop cells (never a deployable decoding, a measurement):
   only origin-source and untargeted cells, and only other-source and untargeted cells. The
   difference between "as configured" and "origin cells only" is what the additional cells add or
   cost after averaging;
4. with several checkpoints scored on the same scenes, each after the first gets a **cross table**
   of the required instances: its outcome (matched or the miss reason) against the first's, e.g.
   ``--ckpt vanilla... --ckpt ap...``: which parts AP misses that vanilla finds, and why.

Writes ``sources_<run>.md`` per checkpoint and ``sources.csv`` (one row per checkpoint × table row)
into ``--out`` (default ``results/table1/diagnostics``).
"""

from __future__ import annotations

import argparse
import csv
import io
import os
import sys
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from opnet.arguments import ArgumentParser  # noqa: E402
from opnet.cli.build import build_datamodule, load_checkpoint, require_checkpoint_file  # noqa: E402
from opnet.cli.tools import require_folder, tool_main  # noqa: E402
from opnet.fileio.atomic import write_errors_named, write_text_atomic  # noqa: E402
from opnet.metrics.bregier import evaluate_scenes  # noqa: E402
from opnet.metrics.diagnostics import MISS_REASONS, diagnose, rotation_errors_deg, scene_outcomes  # noqa: E402
from opnet.parameterizations.positions import CameraBatch  # noqa: E402
from opnet.paths import REPO_ROOT


def run_name(ckpt: Path) -> str:
    """``outputs/table1/ap_bunny_s0/checkpoints/last.ckpt`` -> ``table1/ap_bunny_s0`` (the runs
    folder too: arms of two tables may share a name)."""
    run = ckpt.resolve().parent.parent
    return f"{run.parent.name}/{run.name}"


@torch.no_grad()
def record(ckpt: Path, split: str) -> dict[str, Any]:
    """Network outputs, cameras, ground truth and the target cells of every batch of a split (the image's own
    pass: a decoding that pools the input's turns is diagnosed as one pass, ``turns`` 1, each cell its own)."""
    system, cfg = load_checkpoint(str(ckpt))
    system.eval()
    param = system.parameterization.with_decoding(turns=1)
    dm = build_datamodule(cfg, param.obj, train=False)
    dm.setup("test")
    batches = []
    for batch in getattr(dm, f"{split}_dataloader")():
        out = system(batch.images).float()
        index, cell, origin = param.target_cells(batch.gt, batch.cameras)
        batches.append({"out": out, "cams": batch.cameras, "gt": batch.gt, "gt_sets": batch.gt_sets,
                        "index": index, "cell": cell, "origin": origin, "names": batch.names})  # fmt: skip
    return {"param": param, "batches": batches, "max_occlusion": system.max_occlusion}


def cell_hypotheses(param: Any, out: torch.Tensor, cams: list[Any], cell: torch.Tensor) -> dict[str, torch.Tensor]:
    """The pose each flat cell (W,) decodes to on its own: p̂, v̂, t (W, 3), R (W, 3, 3)."""
    S, L = param.grid_size, param.slots
    b, slot, row, col = cell // (L * S * S), (cell // (S * S)) % L, (cell // S) % S, cell % S
    feat = param.split_slots(out).permute(0, 1, 3, 4, 2)[b, slot, row, col].double()
    batch_cams = CameraBatch.of(cams, out.shape[0], out.device).take(b)
    t, R = param.decode_poses(feat, (slot, row, col), batch_cams)
    score, _ = param.hypothesis_scores(feat)
    return {"p": feat[:, param.layout.presence], "score": score, "t": t, "R": R}


def shows_instance(gt: Any, index: torch.Tensor, cell: torch.Tensor, grid: int, slots: int) -> np.ndarray:
    """(W,) share of each target cell's input pixels that show its own instance (NaN without a
    segmentation): low where the target asks for a part the cell cannot see."""
    if gt.segmentation is None:
        return np.full(len(index), np.nan)
    seg = gt.segmentation  # (B, H, W)
    B, H, W = seg.shape
    blocks = seg.reshape(B, grid, H // grid, grid, W // grid).permute(0, 1, 3, 2, 4).reshape(B, grid, grid, -1)
    b, row, col = cell // (slots * grid * grid), (cell // grid) % grid, cell % grid
    return (blocks[b, row, col] == gt.instance_id[index][:, None]).double().mean(-1).numpy()


def cell_table(rec: dict[str, Any]) -> list[dict[str, Any]]:
    """Rows of table 1 (cells by source and required) and table 2 (fired untargeted cells)."""
    param = rec["param"]
    space, delta = param.obj.pose_space, param.obj.pose_space.delta
    keep = 1 - rec["max_occlusion"]
    cols: dict[str, list[np.ndarray]] = {
        k: [] for k in ("origin", "required", "p", "score", "t_mm", "r_deg", "within", "shows")
    }
    untargeted_fired, untargeted_p, images = 0, [], 0
    for bt in rec["batches"]:
        gt, index = bt["gt"], bt["index"]
        hyp = cell_hypotheses(param, bt["out"], bt["cams"], bt["cell"])
        R_gt, t_gt = gt.R_cam_obj[index].double(), gt.t_cam_obj[index].double()
        cols["origin"].append(bt["origin"].numpy())
        cols["required"].append((gt.visibility[index] >= keep).numpy())
        cols["p"].append(hyp["p"].numpy())
        cols["score"].append(hyp["score"].numpy())
        cols["t_mm"].append(1000 * (hyp["t"] - t_gt).norm(dim=-1).numpy())
        cols["r_deg"].append(rotation_errors_deg(hyp["R"].numpy(), R_gt.numpy(), space))
        cols["within"].append((space.distance(hyp["R"], hyp["t"], R_gt, t_gt) <= delta).numpy())
        cols["shows"].append(shows_instance(gt, index, bt["cell"], param.grid_size, param.slots))
        presence = param.split_slots(bt["out"])[:, :, param.layout.presence].reshape(-1)
        targeted = torch.zeros_like(presence, dtype=torch.bool)
        targeted[bt["cell"]] = True
        fired = (presence > param.threshold) & ~targeted
        untargeted_fired += int(fired.sum())
        untargeted_p.append(presence[fired].numpy())
        images += bt["out"].shape[0]
    c = {k: np.concatenate(v) for k, v in cols.items()}
    rows = []
    for required in (True, False):
        for origin in (True, False):
            sel = (c["origin"] == origin) & (c["required"] == required)
            fired = sel & (c["p"] > param.threshold)
            rows.append({
                "table": "cells", "source": "origin" if origin else "other",
                "instances": "required" if required else "hidden > max occlusion",
                "cells": int(sel.sum()), "p_mean": _mean(c["p"][sel]), "fired": _mean(fired[sel]),
                "t_mm_p50": _pct(c["t_mm"][fired], 50), "t_mm_p90": _pct(c["t_mm"][fired], 90),
                "r_deg_p50": _pct(c["r_deg"][fired], 50), "within_delta": _mean(c["within"][fired]),
                "score_mean": _mean(c["score"][fired]), "shows_part": _mean(c["shows"][sel]),
            })  # fmt: skip
    p_un = np.concatenate(untargeted_p) if untargeted_p else np.zeros(0)
    rows.append({"table": "untargeted", "source": "none", "instances": "-", "cells": untargeted_fired,
                 "per_image": untargeted_fired / max(images, 1), "p_mean": _mean(p_un)})  # fmt: skip
    return rows


def decode_variants(rec: dict[str, Any]) -> list[dict[str, Any]]:
    """AP and miss diagnostics of the decoding variants of the module docstring; keeps the
    per-instance outcomes of the configured decoding in ``rec["outcomes"]`` (scene name -> (N,))."""
    param = rec["param"]
    variants = {
        "as configured": (param, None),
        "no averaging": (param.with_decoding(averaging=False), None),
        "origin cells only (oracle)": (param, False),
        "other cells only (oracle)": (param, True),
    }
    rows = []
    for name, (decoder, drop_origin) in variants.items():
        scenes: dict[str, Any] = {}
        for bt in rec["batches"]:
            out = bt["out"]
            if drop_origin is not None:  # silence the target cells of one source
                grid5 = param.split_slots(out).clone()  # (B, L, C, S, S)
                p = param.layout.presence
                presence = grid5[:, :, p].reshape(-1)
                presence[bt["cell"][bt["origin"] == drop_origin]] = 0.0
                grid5[:, :, p] = presence.reshape(grid5[:, :, p].shape)
                out = grid5.reshape(out.shape)
            for h, g, scene in zip(decoder.decode(out, bt["cams"]), bt["gt_sets"], bt["names"], strict=True):
                scenes[scene] = (g, h)
        if name == "as configured":
            per_scene = scene_outcomes(scenes, param.obj.pose_space, param.obj.diameter, rec["max_occlusion"])
            rec["outcomes"] = {n: o.outcome[o.find] for n, o in zip(scenes, per_scene, strict=True)}
        result = evaluate_scenes(scenes, param.obj.pose_space, max_occlusion=rec["max_occlusion"])
        diag = diagnose(scenes, param.obj.pose_space, param.obj.diameter, max_occlusion=rec["max_occlusion"])
        n = max(diag.to_find, 1)
        rows.append({"table": "decoding", "source": name, "ap": result.ap, "found": diag.matched / n,
                     "no_hypothesis": diag.no_hypothesis / n, "position": diag.position / n,
                     "orientation": diag.orientation / n, "conflict": diag.conflict / n,
                     "hypotheses_per_image": diag.hypotheses / max(len(scenes), 1),
                     "confident_fp": diag.confident_false_positives, "duplicates": diag.duplicates,
                     "t_mm_p50": diag.t_err_mm_p50, "r_deg_p50": diag.r_err_deg_p50})  # fmt: skip
    return rows


def versus(ref: dict[str, Any], other: dict[str, Any], ref_name: str, other_name: str) -> str:
    """Markdown cross table of the required instances: outcome under ``other`` (rows) against
    outcome under ``ref`` (columns), same held-out scenes; e.g. why AP misses what vanilla finds."""
    if set(ref["outcomes"]) != set(other["outcomes"]):
        return f"({other_name} and {ref_name} were scored on different scenes: no cross table)\n"
    kinds = ["matched", *MISS_REASONS]
    counts = {(a, b): 0 for a in kinds for b in kinds}
    for scene, theirs in other["outcomes"].items():
        for a, b in zip(theirs, ref["outcomes"][scene], strict=True):
            counts[(a, b)] += 1
    lines = [f"Required instances: {other_name} (rows) against {ref_name} (columns), the same held-out scenes.", "",
             f"| {other_name} \\ {ref_name} | " + " | ".join(kinds) + " | total |", "|" + "---|" * (len(kinds) + 2)]
    for a in kinds:
        row = [counts[(a, b)] for b in kinds]
        lines.append(f"| {a} | " + " | ".join(map(str, row)) + f" | {sum(row)} |")
    return "\n".join(lines) + "\n"


def _mean(x: np.ndarray) -> float:
    return float(np.mean(x)) if len(x) else float("nan")


def _pct(x: np.ndarray, q: float) -> float:
    return float(np.percentile(x, q)) if len(x) else float("nan")


def markdown(run: str, rows: list[dict[str, Any]]) -> str:
    """The three tables of one checkpoint."""

    def fmt(v: Any) -> str:
        return f"{v:.3f}" if isinstance(v, float) else str(v)

    parts = [f"# Hypothesis sources: {run}\n"]
    for table, keys in (
        ("cells", ["source", "instances", "cells", "p_mean", "fired", "t_mm_p50", "t_mm_p90", "r_deg_p50",
                   "within_delta", "score_mean", "shows_part"]),
        ("untargeted", ["cells", "per_image", "p_mean"]),
        ("decoding", ["source", "ap", "found", "no_hypothesis", "position", "orientation", "conflict",
                      "hypotheses_per_image", "confident_fp", "duplicates", "t_mm_p50", "r_deg_p50"]),
    ):  # fmt: skip
        sel = [r for r in rows if r["table"] == table]
        parts.append("| " + " | ".join(keys) + " |\n|" + "---|" * len(keys))
        parts += ["| " + " | ".join(fmt(r.get(k, "")) for k in keys) + " |" for r in sel]
        parts.append("")
    return "\n".join(parts) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--ckpt", action="append", required=True, type=Path, help="checkpoint (repeat)")
    parser.add_argument("--split", default="test", choices=("val", "test", "train"))
    parser.add_argument("--out", type=Path, default=REPO_ROOT / "results" / "table1" / "diagnostics")
    args = parser.parse_args(argv)
    return tool_main(lambda: diagnose(args))


def _write(path: Path, text: str) -> None:
    with write_errors_named(path):
        write_text_atomic(path, text)


@torch.no_grad()
def diagnose(args: argparse.Namespace) -> int:
    """The tables :func:`main` asks for: the checkpoints and ``--out`` checked, then each checkpoint recorded."""
    for ckpt in args.ckpt:
        require_checkpoint_file(ckpt, "--ckpt")
    require_folder(args.out, "--out")
    all_rows = []
    first: tuple[str, dict[str, Any]] | None = None
    for ckpt in args.ckpt:
        run = run_name(ckpt)
        print(f"recording the {args.split} outputs of {ckpt}", flush=True)
        rec = record(ckpt, args.split)
        rows = cell_table(rec) + decode_variants(rec)
        text = markdown(run, rows)
        if first is not None:
            text += "\n" + versus(first[1], rec, first[0], run)
        print(text, flush=True)
        _write(args.out / f"sources_{run.replace('/', '_')}.md", text)
        all_rows += [{"run": run, **r} for r in rows]
        if first is None:
            first = (run, {"outcomes": rec["outcomes"]})
        del rec
    fields = list(dict.fromkeys(k for r in all_rows for k in r))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields)
    writer.writeheader()
    writer.writerows(all_rows)
    _write(args.out / "sources.csv", buf.getvalue())
    print(f"written {args.out}/sources.csv")
    return 0


if __name__ == "__main__":
    sys.exit(main())
