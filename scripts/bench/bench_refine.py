"""Refinement speed and AP per frame: one checkpoint's hypotheses over a split, refined by each variant.

The network runs once over the split (its hypotheses and the scenes' depth images are kept in
``--cache``, so further variants skip it); each variant of ``conf/refine/search.yaml`` (``--variant
LABEL:icp.KEY=VALUE,search.KEY=VALUE``, or another group of ``conf/refine/``: ``--refine NAME``) then
refines every frame, timed per frame and per stage
(:data:`opnet.refine.STAGES`). Printed: AP (Brégier, max occlusion 0.5), found share,
milliseconds per frame (mean, median, worst) and by stage, and the wall time's CPU share (a
loaded machine shows there). Target for the plate frames: at most 300 ms per frame on 2 cores.

    python scripts/bench/bench_refine.py --ckpt models/cell_ipd_plate.ckpt \\
        --data root=outputs/data/cells/val_c6 --data test_root=outputs/data/cells/val_c6 --data cache=false \\
        --decoding averaging=false [--scenes 20] [--refine search_fast] [--variant "LABEL:search.keep=2"] \\
        [--profile] [--out results/verification/speed.md]
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pickle
import pstats
import shlex
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np
from omegaconf import OmegaConf

from opnet.fileio.atomic import write_bytes_atomic, write_text_atomic
from opnet.paths import REPO_ROOT
from opnet.refine import STAGES, Refiner, settings_from_config
from opnet.studies.refinement import key_values, refine_variant, score_refined
from opnet.studies.results import cpu_model


def frames(ckpt: str, data: dict[str, Any], decoding: dict[str, Any], scenes: int, cache: Path) -> tuple[Any, list]:
    """The object and [(name, gt, hypotheses, depth, camera)] of the first ``scenes`` test scenes, from ``cache``
    when it was made by the same arguments."""
    key = {"ckpt": str(Path(ckpt).resolve()), "mtime": Path(ckpt).stat().st_mtime, "data": data,
           "decoding": decoding, "scenes": scenes}  # fmt: skip
    from opnet.cli.build import build_datamodule, load_checkpoint
    from opnet.cli.eval import with_decoding_overrides
    from opnet.evaluation import predict_scenes

    system, cfg = load_checkpoint(ckpt)
    obj = system.parameterization.obj
    if cache.is_file():
        saved = pickle.loads(cache.read_bytes())
        if saved["key"] == key:
            return obj, saved["frames"]
    system.parameterization = with_decoding_overrides(system.parameterization, decoding or None)
    if data:
        cfg = OmegaConf.merge(cfg, {"data": {**data, **({"generate": None} if cfg.data.get("generate") else {})}})
    dm = build_datamodule(cfg, obj, train=False)
    dm.setup("test")
    split = dm.splits["test"]
    predicted = predict_scenes(system, dm.test_dataloader())
    out = []
    for i in range(len(split)):
        record = split.record(i)
        if record.name in predicted:
            gt, hyps = predicted[record.name]
            out.append((record.name, gt, hyps, np.asarray(record.depth, np.float64), record.camera))
        if len(out) >= scenes:
            break
    cache.parent.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(cache, pickle.dumps({"key": key, "frames": out}))
    return obj, out


def refine_group(name: str) -> dict[str, Any]:
    """The composed ``refine=<name>`` group (its defaults list resolved), as a plain dict."""
    from hydra import compose, initialize_config_dir

    from opnet.paths import config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose(config_name="eval", overrides=[f"refine={name}"])
    return OmegaConf.to_container(cfg.refine, resolve=True)


def run_variant(obj: Any, data: list, settings: Any, profile: bool) -> dict[str, Any]:
    """Refine every frame with ``settings``: AP, found share, ms per frame, by stage."""
    refiner = Refiner.for_object(obj, settings)
    scenes, ms, stages = {}, [], {}
    cpu0 = time.process_time()
    wall0 = time.perf_counter()
    prof = cProfile.Profile() if profile else None
    for name, gt, hyps, depth, camera in data:
        start = time.perf_counter()
        if prof is not None:
            prof.enable()
        refined, _ = refiner(hyps, depth, camera, stages)
        if prof is not None:
            prof.disable()
        ms.append(1000 * (time.perf_counter() - start))
        scenes[name] = (gt, refined)
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    if prof is not None:
        pstats.Stats(prof).sort_stats("cumulative").print_stats(25)
    scored = score_refined(scenes, obj, 0.5)
    n = max(len(data), 1)
    return {"ap": scored["ap"], "found": scored["found"], "ms_mean": float(np.mean(ms)), "ms_p50": float(np.median(ms)),
            "ms_max": float(np.max(ms)), "cpu_share": cpu / max(wall, 1e-9),
            **{f"{k}_ms": 1000 * stages.get(k, 0.0) / n for k in STAGES}}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--ckpt", default="models/cell_ipd_plate.ckpt")
    ap.add_argument("--data", action="append", default=[], help="KEY=VALUE of the checkpoint's data section")
    ap.add_argument("--decoding", action="append", default=[], help="KEY=VALUE as eval.py's +decoding.KEY")
    ap.add_argument("--scenes", type=int, default=20)
    ap.add_argument("--variant", action="append", default=[], help="LABEL:icp.KEY=VALUE,search.KEY=VALUE")
    ap.add_argument("--refine", action="append", default=[], help="another group of conf/refine/ (NAME)")
    ap.add_argument("--no-base", action="store_true", help="only the variants, not conf/refine/search.yaml itself")
    ap.add_argument("--out", type=Path, help="also write the table here (markdown, with the command)")
    ap.add_argument("--cache", type=Path, default=REPO_ROOT / "outputs" / "bench_refine" / "frames.pkl")
    ap.add_argument("--profile", action="store_true", help="print the cProfile of each variant")
    args = ap.parse_args(argv)
    data, decoding = key_values(args.data, "--data"), key_values(args.decoding, "--decoding")
    obj, frames_ = frames(args.ckpt, data, decoding, args.scenes, args.cache)
    base = OmegaConf.to_container(OmegaConf.load(REPO_ROOT / "conf" / "refine" / "search.yaml"))
    arms = ([] if args.no_base else [("search.yaml", settings_from_config(base))]) + \
        [refine_variant(v, base, "--variant") for v in args.variant]  # fmt: skip
    arms += [(f"refine={name}", settings_from_config(refine_group(name))) for name in args.refine]
    hyps = sum(len(f[2].score) for f in frames_)
    lines = [f"{len(frames_)} frames, {hyps / max(len(frames_), 1):.1f} hypotheses per frame", ""]
    cols = ["ap", "found", "ms_mean", "ms_p50", "ms_max", "cpu_share", *(f"{k}_ms" for k in STAGES)]
    lines += ["| variant | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    print("\n".join(lines), flush=True)
    for label, settings in arms:
        row = run_variant(obj, frames_, settings, args.profile)
        lines.append(f"| {label} | " + " | ".join(f"{row[c]:.3f}" if c in ("ap", "found", "cpu_share") else f"{row[c]:.0f}"
                                                  for c in cols) + " |")  # fmt: skip
        print(lines[-1], flush=True)
    if args.out:
        command = "python scripts/bench/bench_refine.py " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
        explained = ("`ap`: Brégier AP (max occlusion 0.5) of the refined hypotheses; `found`: share of the parts to find "
                     "that were matched; `ms_*`: wall milliseconds of the refinement per frame (mean, median, worst); "
                     "`cpu_share`: process CPU time over wall time (above 1: both cores at work); `<stage>_ms`: mean "
                     "milliseconds per frame of each stage (the slowest thread's where they ran side by side): scene "
                     "(the depth as points), icp, search, polish (ICP of the searched poses), rank. Checkpoint: "
                     f"`{os.path.relpath(Path(args.ckpt).resolve(), REPO_ROOT)}`; nothing else ran on the machine.")
        write_text_atomic(args.out, f"# Refinement speed\n\nMade by `{command}` on {cpu_model()} ({os.cpu_count()} "
                          "cores).\n\n" + "\n".join(lines) + "\n\n" + explained + "\n")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
