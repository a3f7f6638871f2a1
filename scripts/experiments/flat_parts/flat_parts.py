"""Flat, thin and spinning parts: where the network's poses go wrong, and what each lever is worth.

Three parts the network found badly: the IPD plate (a 127 mm T-plate 1.8 mm thick) in the IPD cell, whose
bin moves (the cell study's piles, ``scripts/experiments/cells/cells.py``), and two ITODD parts of the
new-parts benchmark, a rim (ITODD 08) and a flange (ITODD 27), in dense bulk piles (its recipe and budget,
``scripts/experiments/new_parts/new_parts.py``). Each *arm* is the part's recipe with one lever moved (input
pixels per part, output grid, training steps, data, the orientation's loss, the declared symmetry, ...),
trained and scored on the same piles: validation piles (the cell's ``val_c6``; the dense runs' validation
split) to choose on, held-out piles of another seed to report (the cell's basket in the working area's four
corners; the dense benchmark's 12 piles of seed 1), as decoded and with the part's recorded refinement.
Every score comes with the error breakdown along the part's main axis (:mod:`opnet.metrics.breakdown`):
no hypothesis, lateral, depth, tilt or spin.

    python scripts/experiments/flat_parts/flat_parts.py --part plate --arms base in256 --seeds 0   # train + score
    python scripts/experiments/flat_parts/flat_parts.py --report                                    # the page

Writes ``results/flat_parts/flat_parts.csv`` (a row per part, lever, arm and seed) and its ``README.md``.
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import json
import os
import sys
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from opnet.metrics.breakdown import view_shares
from opnet.paths import REPO_ROOT, best_checkpoint
from opnet.studies import mean_sd_text, merge_csv, run_logged, train_command


def _load(name: str, path: Path) -> Any:
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


CELLS = _load("cells", REPO_ROOT / "scripts" / "experiments" / "cells" / "cells.py")
OUT = REPO_ROOT / "results" / "flat_parts"
RUNS = REPO_ROOT / "outputs" / "flat"
CELL_DATA = REPO_ROOT / "outputs" / "data" / "cells"
CELL_RUNS = REPO_ROOT / "outputs" / "cells"  # cells.py's runs
DENSE_DATA = REPO_ROOT / "outputs" / "data" / "dense"
FIELDS = ("part", "lever", "arm", "seed", "steps", "split", "ap_decoded", "ap_refined", "ms_per_frame", "found",
          "found_refined", "no_hypothesis", "missed_lateral", "missed_depth", "missed_tilt", "missed_spin",
          "lateral_mm_p50", "depth_mm_p50", "tilt_deg_p50", "spin_deg_p50", "train_minutes", "train_val_ap",
          "overrides", "ap_decoded_own_group", "ap_refined_own_group", "found_end_on", "found_side_on",
          "side_on")  # fmt: skip

#: the cell recipe's training (cells.py's "auto" arm): EVE, small preset, 128-pixel input over a 0.8 m square
#: around the basket, 16 x 16 cells, 3000 steps
PLATE_STEPS = 3000
#: the new-parts budget (new_parts.py): 192 cycles (24 piles x 8 views), 10,696 steps of batch 16
DENSE_STEPS = 10696
DENSE_CYCLES = 192

#: the near-revolution declared on the command line (conf/object/<part>.yaml keeps the exact group)
NEAR_REVOLUTION = ["object.symmetry.kind=revolution"]


def _searched(*refined: str) -> dict[str, Any]:
    """An arm scored with the kept plate arm's network, ``refined`` added to its refined scoring only."""
    return {"from": "g32_s6000", "refined": list(refined)}


#: on top of the flat part's tolerance: more of the network's cells (threshold 0.05) and every hypothesis searched
WIDER = ("+decoding.threshold=0.05", "refine.search.merge=0")
#: what a flat part trains and records in the cell recipe (experiment=cell's flat_part): the threshold 0.05 and
#: refine=search_flat, i.e. search_fast with these keys
#: ... the duplicates the search made dropped before the polish, the coarse grid on every second model point
EARLY = (*WIDER, "refine.search.suppress_searched=true")
CS2 = (*EARLY, "refine.search.coarse_stride=2")
FLAT = (*CS2, "refine.search.polish_share=0.5")
FLAT_REFINE = FLAT[1:]  # without the threshold
#: ... what the sensor sees through the part weighing twice, and the ranking on 2000 model points of its own
STW2 = (*FLAT, "refine.search.see_through_weight=2")
RANK = (*STW2, "refine.search.rank_points=2000")


def _before(*refined: str) -> dict[str, Any]:
    """:func:`_searched` against the search as it was before a flat part had its own tolerance (the arms measured
    then, so that they still reproduce)."""
    return _searched("refine.search.turn_tolerance=null", *refined)


#: the decoding's turns (the network also run on the input's half turn, or on its four quarter turns, every turn's
#: hypotheses pooled before the averaging) on the recipe's network of a dense part
TURN_ARMS = {**{f"turns{n}": {"from": "exact", "eval": [f"+decoding.turns={n}"]} for n in (2, 4)},
             # ... and on the networks of two other arms: does the gain hold for another network?
             **{f"{arm}_turns4": {"from": arm, "eval": ["+decoding.turns=4"]} for arm in ("g32", "lori3")},
             # the recipe's decoding (four turns) tuned after training on every 8th validation scene, as
             # experiment=dense does (tune_decoding: 8)
             "turns4_tuned": {"from": "exact", "start": {"turns": 4}, "tune": 8}}

#: the network also learns how right each cell's orientation is (a quality channel q, its target 2^-(d/δ)²), and the
#: score multiplies it in; the recipe's tuning (tune_decoding: 8) then chooses among p, p*v, p*q and p*v*q on
#: validation. Its A/B: turns4_tuned, the same recipe's network without the channel, tuned the same way
QUALITY_ARMS = {"quality": {"train": ["parameterization.quality=true", "parameterization.score=p*q"]}}

#: the training piles' views each turn every part about its own axis by a fresh spin (scene.view_spin: a part whose
#: convex hull is a body of revolution, as both ITODD parts'), so that 24 piles show 8 x their spins; the recipe
#: otherwise unchanged (its tuning too). Its A/B: the recipe's own run (new_parts.py), the same piles' physics
DATA_ARMS = {"view_spin": {"scene": ["view_spin=true"]}}
#: both levers that helped ITODD 08 a little, together: fresh spins per view and the quality channel. Its A/B: the
#: view_spin arm run at the same seed on the same machine
BOTH_ARMS = {"view_spin_quality": {"scene": DATA_ARMS["view_spin"]["scene"], "train": QUALITY_ARMS["quality"]["train"]},
             # fresh spins per view and the plate's grid (the part's D over twice the cells), which lifted ITODD 08
             # with the four turns (g32_turns4); its A/B: the view_spin arm at the same seed on the same machine
             "view_spin_g32": {"scene": DATA_ARMS["view_spin"]["scene"], "train": ["parameterization.grid=32"]},
             # fresh spins per view, and the spin not asked for where the depth hardly shows it: the axis more than
             # 55 degrees from the line of sight (loss.spin_unseen_deg; from the spin study's rendering, where a
             # 36-degree turn changes 6 of the wheel's input pixels by over 1 mm at 55 degrees, 20 at 50); its A/B:
             # the view_spin arm at the same seed on the same machine
             "view_spin_blind55": {"scene": DATA_ARMS["view_spin"]["scene"], "train": ["loss.spin_unseen_deg=55"]},
             # fresh spins and fresh flips per view (scene.view_flip: half the parts of each view turned end over
             # end about their hull's middle, which a wheel's hull allows): the side-on wheels' axes pointed the
             # wrong way for 35 % on validation against 6 % on the training piles; the same piles' physics and
             # spins, its A/B: the view_spin arm at the same seed on the same machine
             "view_spin_flip": {"scene": [*DATA_ARMS["view_spin"]["scene"], "view_flip=true"]},
             # the view_spin arm's seed 0 trained again on the machine kind of the arms below it (the same command,
             # piles and budget): the A/B partner of each of them, beside the record's runs
             "view_spin_again": DATA_ARMS["view_spin"],
             # the same command once more where the physics made other piles than view_spin_again's (another
             # machine of the same kind): the A/B partner of the arms trained on those piles
             "view_spin_again2": DATA_ARMS["view_spin"],
             # fresh spins per view, trained on the depth as rendered: no elastic warp, blur, noise or dropout (the
             # recipe's noise reaches 2.5 mm at ITODD 08's rig, more than the 1 mm a 36-degree turn changes at the
             # 71 input pixels where an oblique wheel shows its spokes); the random resize and quarter turns stay.
             # Its A/B: view_spin_again at the same seed
             "view_spin_clean": {"scene": DATA_ARMS["view_spin"]["scene"],
                                 "train": [f"augmentation.{p}=0" for p in ("p_elastic", "p_blur", "p_motion_blur",
                                                                           "p_noise", "p_dropout")]},
             # fresh spins per view, the stem reading the depth in float32 (model.fp32_stem): under the training's
             # bf16 autocast the stem read it rounded to 1/256 of its value, 0.5-1 mm at ITODD 08's rig, as much as
             # the relief by which an oblique wheel shows its spin. Its A/B: view_spin_again2 at the same seed
             "view_spin_fp32stem": {"scene": DATA_ARMS["view_spin"]["scene"], "train": ["model.fp32_stem=true"]},
             # the view_spin command on a CPU without native bf16 (its training runs in float32 throughout): the A/B
             # partner of the arms trained on such a machine
             "view_spin_f32": DATA_ARMS["view_spin"]}

#: fresh spins per view, the turn about a cyclic part's axis as its N-th harmonic (rotation=r6d_spin: the axis and
#: cos N theta, sin N theta; docs/method.md#cyclic-parts-the-turn-as-its-harmonic): the 6-D channels' nearest-of-N
#: column has a seam that no continuous network can avoid, the harmonic none. A part without a cyclic group keeps
#: r6d exactly. Its A/B: view_spin_f32 at the same seed on the same machine
SPIN_CODEC_ARMS = {"view_spin_r6d_spin": {"scene": DATA_ARMS["view_spin"]["scene"], "train": ["rotation=r6d_spin"]}}

#: the new-parts recipe frames a part at about 45 pixels of the 128-pixel input, a spoke or a tooth at 2-3; at the
#: 256-pixel input a stride-8 stem hands the same network (its blocks at 32 x 32, the same grid) twice the pixels
#: per part. The scenes are cached at the input's own 256 pixels (the recipe caches at twice the input: 512 would
#: be four times the disk) and read back without the random resize
DENSE_PIXEL_ARMS = {"in256_st8": {"train": ["data.input_size=256", "model.in_size=256", "model.stem_stride=8",
                                            "data.cache_size=256"]}}

#: part -> lever -> arm -> the overrides of train.py it adds to the part's recipe ("steps": its step count; "scene":
#: settings of its own training piles' scene, generated for it;
#: "from": scored with another arm's network (and trained its steps), "eval" adding eval.py overrides, "refined" only
#: to the refined scoring, "tune": a copy of the network's checkpoint decoding as tuned after training on every
#: such-th validation scene (train.py's tune_decoding), from its decoding with "start" changed)
ARMS: dict[str, dict[str, dict[str, dict[str, Any]]]] = {
    "plate": {
        "recipe": {"base": {}},
        # the part's D over the 0.8 m square: 28 pixels at 128, 42 at 192, 56 at 256
        "pixels": {"in192_g24": {"train": ["data.input_size=192", "model.in_size=192", "parameterization.grid=24"]},
                   "in256_g32": {"train": ["data.input_size=256", "model.in_size=256", "parameterization.grid=32"]},
                   # a stride-8 stem: the 128-pixel network's blocks fed twice the pixels
                   "in256_st8": {"train": ["data.input_size=256", "model.in_size=256", "model.stem_stride=8"]},
                   "in256_st8_g32": {"train": ["data.input_size=256", "model.in_size=256", "model.stem_stride=8",
                                               "parameterization.grid=32"]}},
        "grid": {"g32": {"train": ["parameterization.grid=32"]}},
        "steps": {"s9000": {"steps": 9000},
                  "g32_s6000": {"train": ["parameterization.grid=32"], "steps": 6000}},
        "orientation": {"lori3": {"train": ["loss.lambda_ori=3"]},
                        "sym_rotation": {"train": ["loss.orientation=sym_rotation"]}},
        "position": {"lz10": {"train": ["loss.lambda_z=10"]},
                     "lxy10": {"train": ["loss.lambda_xy=10"]},
                     "lxy10_lz10": {"train": ["loss.lambda_xy=10", "loss.lambda_z=10"]},
                     "metric01": {"train": ["loss.position=metric", "loss.lambda_pos=0.1"]}},
        "decoding": {"no_averaging": {"from": "base", "eval": ["+decoding.averaging=false"]},
                     "eps05": {"from": "base", "eval": ["+decoding.averaging_eps=0.5"]},
                     # the shipped model (the one command for the cell: experiment=cell) decoding the input's turns;
                     # val: its own training piles' validation cycles
                     **{f"cell_turns{n}": {"model": "cell", "eval": [f"+decoding.turns={n}"]} for n in (1, 2, 4)},
                     # ... its decoding tuned on every validation scene of its training piles (they hold few)
                     "cell_tuned": {"model": "cell", "tune": 1}},
        # the one command's recipe (experiment=cell, as cells.py --stage cell runs it: tune_decoding 1 included) with
        # the quality channel; its A/B: cell_tuned, the shipped model the same recipe made without it
        "quality": {"cell_quality": {"recipe": "cell", "train": QUALITY_ARMS["quality"]["train"]}},
        # each the kept arm's network (g32_s6000) with the recorded search changed, in its refined scoring only
        "refinement": {
            # the searched poses polished by projective ICP instead of nearest-point ICP
            "g32_s6000_ppolish": _before("refine.icp.polish_association=projective"),
            # the searched poses ranked by agreement x the network's score, not agreement alone
            "g32_s6000_product": _before("refine.search.score=product"),
            # a searched pose within 2 delta of a better one dropped (1 delta: the recorded search)
            "g32_s6000_suppress2": _before("refine.search.suppress=2.0"),
            # more of the network's cells searched: presence threshold 0.05 (recorded: 0.1)
            "g32_s6000_thr05": _before("+decoding.threshold=0.05"),
            "g32_s6000_thr02": _before("+decoding.threshold=0.02"),
            # shifts across the axis twice as far (0.2 D each way; recorded: 0.1): at the same number of shifts
            # (step 0.04), and at the recorded step (0.02: four times the shifts)
            "g32_s6000_shift20": _before("refine.search.shift=0.2", "refine.search.shift_step=0.04"),
            "g32_s6000_shift20f": _before("refine.search.shift=0.2"),
            # every hypothesis searched (recorded: one within 0.1 D of a better one's origin is dropped first)
            "g32_s6000_merge0": _before("refine.search.merge=0"),
            # the three together: every hypothesis, more cells, twice as far
            "g32_s6000_wide": _before("refine.search.merge=0", "+decoding.threshold=0.05", "refine.search.shift=0.2"),
            # the search started from the averaged poses (the recorded search decodes without averaging)
            "g32_s6000_avg": _before("~decoding.averaging"),
            # shifts half as far (0.05 D each way) at the same count (step 0.01): a searched pose drifting onto
            # its neighbours' surfaces (a pile of plates agrees with a pose across two)
            "g32_s6000_shift05": _before("refine.search.shift=0.05", "refine.search.shift_step=0.01"),
            # a flat part's agreement tolerance (turn_tolerance, 0.02 D since it was chosen here; 0.04 D before: null,
            # the search's tolerance): a pose across two plates a plate's thickness apart agrees with both at a loose one
            "g32_s6000_tol04": _searched("refine.search.turn_tolerance=null"),
            "g32_s6000_tol03": _searched("refine.search.turn_tolerance=0.03"),
            "g32_s6000_tol02": _searched("refine.search.turn_tolerance=0.02"),
            "g32_s6000_tol01": _searched("refine.search.turn_tolerance=0.01"),
            # the fine search a grid around the coarse grid's best turns (recorded: a pattern search, which walks
            # as far as the agreement keeps rising)
            "g32_s6000_finegrid": _before("refine.search.fine=grid"),
            # a candidate charged for sliding away from the network's position (agreement less 0.5 x the slide / D)
            "g32_s6000_anchor": _before("refine.search.anchor=0.5"),
            "g32_s6000_tol02_anchor": _searched("refine.search.turn_tolerance=0.02", "refine.search.anchor=0.5"),
            # at the flat part's tolerance, more of the network's cells (threshold 0.05) and every hypothesis searched
            "g32_s6000_t2_thr05": _searched("+decoding.threshold=0.05"),
            "g32_s6000_t2_merge0": _searched("refine.search.merge=0"),
            "g32_s6000_t2_thr05_merge0": _searched(*WIDER),
            # the same with half the model points (300: ICP, the search and the polish each about half the work)
            "g32_s6000_t2_thr05_merge0_mp300": _searched(*WIDER, "refine.icp.model_points=300"),
            # the same with the coarse grid's turns and shifts twice as far apart (10 degrees, 0.04 D: a quarter of the
            # candidates; the pattern search then stops at half these steps)
            "g32_s6000_t2_thr05_merge0_coarse": _searched(*WIDER, "refine.search.turn_step_deg=10",
                                                          "refine.search.shift_step=0.04"),
            # the same with the searched poses polished by projective ICP (no k-d tree)
            "g32_s6000_t2_thr05_merge0_ppolish": _searched(*WIDER, "refine.icp.polish_association=projective"),
            # the same with the duplicates the search made dropped before the polish (on the search's agreements),
            # and with those ICP brought within 0.5 delta of a better one dropped before the search
            "g32_s6000_t2_thr05_merge0_early": _searched(*EARLY),
            "g32_s6000_t2_thr05_merge0_early_icp05": _searched(*EARLY, "refine.search.suppress_icp=0.5"),
            # ... and the coarse grid scored on every second (third) of a candidate's camera-facing model points
            "g32_s6000_t2_thr05_merge0_early_cs2": _searched(*CS2),
            "g32_s6000_t2_thr05_merge0_early_cs3": _searched(*EARLY, "refine.search.coarse_stride=3"),
            # ... and only those whose searched agreement is at least half (0.7) the image's best polished
            "g32_s6000_t2_thr05_merge0_early_cs2_ps05": _searched(*FLAT),
            "g32_s6000_t2_thr05_merge0_early_cs2_ps07": _searched(*CS2, "refine.search.polish_share=0.7"),
            "g32_s6000_t2_thr05_merge0_early_cs3_ps05": _searched(*EARLY, "refine.search.coarse_stride=3",
                                                                  "refine.search.polish_share=0.5"),
            # ... with a flat part's tolerance 0.015 D, or points the sensor sees through the part weighing twice
            "g32_s6000_t2_thr05_merge0_early_cs2_tol015": _searched(*CS2, "refine.search.turn_tolerance=0.015"),
            "g32_s6000_t2_thr05_merge0_early_cs2_stw2": _searched(*CS2, "refine.search.see_through_weight=2"),
            # the speed settings (FLAT) again, and with what the sensor sees through the part weighing 2 or 3 times,
            # at 0.015 D, more of the network's cells (threshold 0.03), ICP stopping at steps under 0.001 rad and
            # 0.1 mm (not 1e-4 and 0.01 mm: the projective ICP's pairs change with every step, most ran all ten)
            "g32_s6000_flat": _searched(*FLAT),
            "g32_s6000_flat_conv3": _searched(*FLAT, "refine.icp.converged=[0.001,0.0001]"),
            "g32_s6000_flat_stw2": _searched(*STW2),
            "g32_s6000_flat_stw3": _searched(*FLAT, "refine.search.see_through_weight=3"),
            "g32_s6000_flat_stw2_tol015": _searched(*STW2, "refine.search.turn_tolerance=0.015"),
            "g32_s6000_flat_thr03": _searched("+decoding.threshold=0.03", *FLAT_REFINE),
            # on top of stw2 the ranking's agreements on 2000 model points of their own (search.rank_points); then
            # ICP and the search on 400 or 300 model points (the ranking keeps its 2000), or the first ICP six steps
            "g32_s6000_flat_stw2_rank": _searched(*RANK),
            "g32_s6000_flat_stw2_rank_mp400": _searched(*RANK, "refine.icp.model_points=400"),
            "g32_s6000_flat_stw2_rank_mp300": _searched(*RANK, "refine.icp.model_points=300"),
            "g32_s6000_flat_stw2_rank_it6": _searched(*RANK, "refine.icp.iterations=6"),
            "g32_s6000_t2_thr07_merge0_early_cs2": _searched("+decoding.threshold=0.07", "refine.search.merge=0",
                                                             "refine.search.suppress_searched=true",
                                                             "refine.search.coarse_stride=2")},
    },
    # the new-parts recipe (experiment=dense, its budget). exact: the committed config's symmetry (the exact group
    # opnet-object finds); near_revolution: the declaration opnet-object --declare-near writes (every turn about
    # the main axis moves the surface by less than delta: a depth image cannot tell the spins apart)
    # grid: the plate's kept lever (its D over twice the cells) on a part the recipe already frames at ~5.6 cells
    "itodd08": {
        "symmetry": {"exact": {},
                     "near_revolution": {"train": [*NEAR_REVOLUTION, "~object.symmetry.order"]}},
        "grid": {"g32": {"train": ["parameterization.grid=32"]}},
        "pixels": DENSE_PIXEL_ARMS,
        "orientation": {"lori3": {"train": ["loss.lambda_ori=3"]}, **SPIN_CODEC_ARMS},
        "decoding": TURN_ARMS,
        "quality": QUALITY_ARMS,
        # the data-scaling probe: the recipe trained on its first 10 training piles (of 20; the same steps)
        "data": {**DATA_ARMS, **BOTH_ARMS, "piles10": {"train": ["data.train_groups=10"]}},
    },
    "itodd27": {
        "symmetry": {"exact": {},
                     "near_revolution": {"train": NEAR_REVOLUTION}},
        "grid": {"g32": {"train": ["parameterization.grid=32"]}},
        # the orientation's loss weighted 3 x against position and presence (the misses of both are spins)
        "orientation": {"lori3": {"train": ["loss.lambda_ori=3"]}},
        "decoding": TURN_ARMS,
        "quality": QUALITY_ARMS,
        # the float32 stem beside the fresh spins; its A/B: view_spin at the same seed (piles whose held-out side-on
        # share matches view_spin's to the fourth decimal)
        "data": {**DATA_ARMS, "view_spin_fp32stem": BOTH_ARMS["view_spin_fp32stem"]},
    },
}


def arm_spec(part: str, arm: str) -> tuple[str, dict[str, Any]]:
    """(lever, spec) of ``arm`` of ``part``."""
    for lever, arms in ARMS[part].items():
        if arm in arms:
            return lever, arms[arm]
    raise SystemExit(f"error: {part}: no arm {arm!r} (arms: {', '.join(a for v in ARMS[part].values() for a in v)})")


def run_dir(part: str, arm: str, seed: int) -> Path:
    return RUNS / part / f"{arm}_s{seed}"


def trained_to(out: Path, steps: int) -> bool:
    """Whether the run in ``out`` reached ``steps`` (its learning curve's last row; a run stopped part-way
    has a ``last.ckpt`` but has not)."""
    rows = learning_curve(out)
    return bool(rows) and int(rows[-1]["step"]) >= steps


learning_curve = CELLS.learning_curve


# ---------------------------------------------------------------------------------------------- the plate


def plate_train(arm: str, seed: int) -> Path:
    _, spec = arm_spec("plate", arm)
    if "model" in spec:  # the one command's model (cells.py --stage cell), trained there
        return model_run(spec)
    if "from" in spec:  # scored differently, trained as another arm
        return plate_train(spec["from"], seed)
    out = run_dir("plate", arm, seed)
    if spec.get("recipe") == "cell":  # the one command's recipe, its own steps, piles and tuning
        if best_checkpoint(out) is None or not (out / "tune_val").is_dir():
            last = out / "checkpoints" / "last.ckpt"
            resume = [f"ckpt_path={last}"] if last.is_file() else []
            run_logged(train_command([*CELLS.cell_overrides(200, 2, 0.5, None), "test=false", f"seed={seed}",
                                      *spec.get("train", []), *resume], out), out / "console.log")  # fmt: skip
        return out
    train_sets, _ = CELLS.datasets(CELL_DATA, 200, 12)
    roots = "[" + ",".join(str(r) for r, *_ in train_sets) + "]"
    steps = plate_steps(arm)
    if not trained_to(out, steps):
        last = out / "checkpoints" / "last.ckpt"  # a run stopped part-way resumes where it stopped
        resume = [f"ckpt_path={last}"] if last.is_file() else []
        run_logged(train_command(["object=ipd_plate", "data=ipa", f"data.root={roots}", "data.generate=null",
                                  f"data.roi=auto:{CELLS.roi_side():g}", "parameterization=eve",
                                  "augmentation.p_rotate=0.5", "test=false", f"seed={seed}",
                                  f"trainer.max_steps={steps}", "trainer.max_epochs=100000",
                                  "trainer.enable_progress_bar=false", *spec.get("train", []), *resume], out),
                   out / "console.log")  # fmt: skip
    return out


def plate_sets() -> dict[str, list[Path]]:
    _, tests = CELLS.datasets(CELL_DATA, 200, 12)
    return {"val": [CELLS.validation_set(CELL_DATA, 6)[0]], "held_out": [r for r, _ in tests["moved"]]}


def model_run(spec: dict[str, Any]) -> Path:
    """The run behind an arm scored with the shipped model (``"model": "cell"``: ``models/real_ipd_plate.ckpt``,
    made by ``cells.py --stage cell``), which must be there."""
    if not CELLS.CELL_MODEL.is_file():
        raise SystemExit(f"error: {CELLS.CELL_MODEL}: not there (python scripts/experiments/cells/cells.py --stage cell)")
    return CELL_RUNS / spec["model"]


def plate_steps(arm: str) -> int:
    """The training steps behind an arm's network (an arm scored "from" another: that arm's)."""
    _, spec = arm_spec("plate", arm)
    if "recipe" in spec:  # the one command's own steps for the plate
        return CELLS.RECIPE_STEPS
    if "model" in spec:
        points = learning_curve(model_run(spec))
        return int(points[-1]["step"]) if points else 0
    return plate_steps(spec["from"]) if "from" in spec else spec.get("steps", PLATE_STEPS)


def plate_eval(arm: str, seed: int, split: str, refine: str) -> dict[str, Any]:
    _, spec = arm_spec("plate", arm)
    if refine == "none" and "from" in spec and not spec.get("eval") and "tune" not in spec:  # the other arm's
        return plate_eval(spec["from"], seed, split, refine)
    out = run_dir("plate", arm, seed) / "eval" / f"{split}_{refine}"
    if not (out / "summary.json").is_file():
        trained = model_run(spec) if "model" in spec else run_dir("plate", spec.get("from", arm), seed)
        ckpt = CELLS.CELL_MODEL if "model" in spec else best_checkpoint(trained)
        if ckpt is None:
            raise SystemExit(f"error: {trained}: not trained")
        ckpt = tuned_copy(ckpt, run_dir("plate", arm, seed), spec)
        refined = spec.get("refined", []) if refine != "none" else []
        overrides = [*CELLS.REFINE[refine], *spec.get("eval", []), *refined]
        if ("model" in spec or "recipe" in spec) and split == "val":  # its own training piles' validation cycles
            run_logged([sys.executable, str(REPO_ROOT / "eval.py"), f"ckpt={ckpt}", "split=val", f"out={out}",
                        "examples=0", *overrides], out.with_suffix(".log"))  # fmt: skip
        else:
            CELLS.evaluate(ckpt, plate_sets()[split], out, overrides)
    return json.loads((out / "summary.json").read_text())


def tuned_copy(ckpt: Path, out: Path, spec: dict[str, Any]) -> Path:
    """``ckpt`` itself, or for an arm with "tune" a copy in ``out``/checkpoints decoding with "start" and then as
    tuned after training on its validation split (:func:`opnet.cli.decoding_search.tune_in_place`, its record in
    ``out``/tune_val: made once)."""
    if "tune" not in spec:
        return ckpt
    from opnet.cli.build import load_checkpoint
    from opnet.tools import tune_decoding as td

    dest = out / "checkpoints" / Path(ckpt).name
    if not (out / "tune_val" / td.TUNED_RECORD).is_file():
        dest.parent.mkdir(parents=True, exist_ok=True)
        configured = td.current_settings(load_checkpoint(ckpt)[0].parameterization)
        td.write_tuned_checkpoint(ckpt, dest, {**configured, **spec.get("start", {})})
        record = td.tune_in_place(dest, spec["tune"], out / "tune_val")
        print(f"[{out.name}] {td.tuned_line(record)}", flush=True)
    return dest


def row_of(part: str, arm: str, seed: int, split: str, decoded: dict[str, Any], refined: dict[str, Any] | None,
           steps: int, overrides: list[str]) -> dict[str, Any]:  # fmt: skip
    b = decoded.get("breakdown", {})
    n = max(b.get("to_find", 0), 1)
    spec = arm_spec(part, arm)[1]
    points = learning_curve(model_run(spec) if "model" in spec else run_dir(part, spec.get("from", arm), seed))
    minutes = points[-1]["train_minutes"] if points else ""
    # the best validation AP during training: held-out cycles of the training piles' own generator (rendered as
    # they were), against which the split's AP shows what does not carry over to other piles
    in_training = max((float(p["val_ap"]) for p in points if p.get("val_ap")), default=None)
    return {"part": part, "lever": arm_spec(part, arm)[0], "arm": arm, "seed": seed, "steps": steps, "split": split,
            "ap_decoded": round(decoded["ap"], 4), "ap_refined": round(refined["ap"], 4) if refined else "",
            "ms_per_frame": round((refined.get("icp") or {}).get("ms_per_image", 0.0), 1) if refined else "",
            "found": round(b.get("matched", 0) / n, 4),
            "found_refined": round(refined["breakdown"]["matched"] / n, 4) if refined and "breakdown" in refined else "",
            **{k: round(b.get(k, 0) / n, 4) for k in ("no_hypothesis", "missed_lateral", "missed_depth", "missed_tilt",
                                                       "missed_spin")},
            **{k: round(b.get(k, float("nan")), 2) for k in ("lateral_mm_p50", "depth_mm_p50", "tilt_deg_p50",
                                                             "spin_deg_p50")},
            **{k: round(v, 4) if v != "" else "" for k, v in view_shares(b).items()},
            "train_minutes": minutes, "train_val_ap": round(in_training, 4) if in_training is not None else "",
            "overrides": " ".join(overrides)}  # fmt: skip


def plate_rows(arm: str, seed: int, splits: list[str], refine: bool) -> list[dict[str, Any]]:
    _, spec = arm_spec("plate", arm)
    rows = []
    for split in splits:
        decoded = plate_eval(arm, seed, split, "none")
        refined = plate_eval(arm, seed, split, CELLS.RECIPE_REFINE) if refine else None
        rows.append(row_of("plate", arm, seed, split, decoded, refined, plate_steps(arm),
                           [*spec.get("train", []), *spec.get("eval", []), *spec.get("refined", [])]))
        print(f"[plate {arm} s{seed} {split}] AP {rows[-1]['ap_decoded']}"
              + (f", refined {rows[-1]['ap_refined']}" if refine else ""), flush=True)
    return rows


# ---------------------------------------------------------------------------------------------- the dense parts


def dense_roots(part: str) -> tuple[Path, Path]:
    """The new-parts benchmark's training and held-out piles of ``part`` (bench_dense.py's names)."""
    return (DENSE_DATA / f"{part}_train_c{DENSE_CYCLES}_v8_d75_s0", DENSE_DATA / f"{part}_test_p12_d75_s1")


#: validation piles of their own for the dense parts: single views of 40 piles of seed 2 (the training piles' seed 0,
#: the held-out piles' seed 1), made as the held-out piles are. The runs' validation split holds 2 piles (16 views),
#: the held-out set 12: too few parts to find (about 6 a view) to tell apart arms 0.05 apart, and the two disagreed
WIDE_VAL_PILES = 40
WIDE_VAL_SEED = 2
SPLITS = ("val", "wide_val", "held_out")


@functools.cache
def wide_val_root(part: str) -> Path:
    """The dense part's wide validation piles (:data:`WIDE_VAL_PILES`), generated on first use (checked once a
    run: every arm scored on them asks)."""
    root = DENSE_DATA / f"{part}_test_p{WIDE_VAL_PILES}_d75_s{WIDE_VAL_SEED}"
    bench = _load("bench_dense", REPO_ROOT / "scripts" / "bench" / "bench_dense.py")
    bench.generate(part, root, WIDE_VAL_PILES, 75, WIDE_VAL_SEED, 1, bench.CAMERA, None)
    return root


def dense_run(part: str, arm: str, seed: int) -> Path:
    """Train ``arm`` of a dense part at the new-parts budget (bench_dense.py: generates the piles first, trains,
    scores the held-out piles as decoded); the run's folder."""
    _, spec = arm_spec(part, arm)
    out = run_dir(part, arm, seed)
    if (out / "test" / "summary.json").is_file():
        return out
    extra = [f"seed={seed}", *spec.get("train", [])]
    run_logged([sys.executable, str(REPO_ROOT / "scripts" / "bench" / "bench_dense.py"), "--objects", part,
                "--config", f"{arm}_s{seed}", "--gen-cycles", str(DENSE_CYCLES), "--views", "8",
                "--steps", str(spec.get("steps", DENSE_STEPS)), "--validations", "20", "--runs-dir", str(RUNS / part),
                "--data-dir", str(DENSE_DATA), "--out", str(RUNS / part / "bench"),
                # an arm without scene settings keeps the piles its A/B was made on (no fresh spins)
                "--train-scene", *spec.get("scene", ["view_spin=false"]), "--extra", *extra],
               RUNS / part / f"bench_{arm}_s{seed}.log")  # fmt: skip
    made = RUNS / part / f"{part}_{arm}_s{seed}"  # bench_dense.py's run folder
    if made != out and made.is_dir():
        made.rename(out)
    return out


def own_group_ap(part: str, scored: Path) -> float:
    """The AP of the poses an evaluation wrote (``scored``/gt, ``scored``/results) under the symmetry of the
    part's committed config (``opnet-evaluate --object <part>``)."""
    dest = scored / "own_group.json"
    if not dest.is_file():
        run_logged([sys.executable, "-m", "opnet.cli.evaluate", "--gt", str(scored / "gt"), "--results",
                    str(scored / "results"), "--object", part, "--quiet", "--out", str(dest)],
                   scored.with_name(f"{scored.name}_own_group.log"))  # fmt: skip
    return round(json.loads(dest.read_text())["ap"], 4)


def dense_eval(part: str, arm: str, seed: int, split: str) -> dict[str, Any]:
    """The summary of a dense arm as decoded on ``split``: its held-out test (bench_dense.py's), or ``eval.py`` of
    the network it is scored with (its own, or the ``from`` arm's) with its ``eval`` overrides."""
    _, spec = arm_spec(part, arm)
    trained = dense_run(part, spec.get("from", arm), seed)
    if split == "held_out" and not spec.get("eval") and "tune" not in spec:
        return json.loads((trained / "test" / "summary.json").read_text())
    out = run_dir(part, arm, seed) / "eval" / f"{split}_none"
    if not (out / "summary.json").is_file():
        ckpt = tuned_copy(best_checkpoint(trained), run_dir(part, arm, seed), spec)
        # the wide validation piles are scored as the held-out piles are: in place of them, every view of 70 parts
        where = [f"data.test_root={wide_val_root(part)}"] if split == "wide_val" else []
        run_logged([sys.executable, str(REPO_ROOT / "eval.py"), f"ckpt={ckpt}", f"out={out}",
                    f"split={'val' if split == 'val' else 'test'}", "refine=none", "examples=0", *where,
                    *spec.get("eval", [])], out.with_suffix(".log"))  # fmt: skip
    return json.loads((out / "summary.json").read_text())


def dense_rows(part: str, arm: str, seed: int, splits: list[str], refine: bool) -> list[dict[str, Any]]:
    """The rows of a dense arm: as decoded on each split (held-out: its test), and on the held-out piles with the
    new-parts refinement (an arm scored with another arm's network: that arm's refined score)."""
    _, spec = arm_spec(part, arm)
    rows = []
    for split in splits:
        decoded = dense_eval(part, arm, seed, split)
        refined = None
        if refine and split == "held_out":
            trained = dense_run(part, spec.get("from", arm), seed)
            dest = trained / "test_refined"  # the new-parts benchmark's name for it too
            if not (dest / "summary.json").is_file():
                run_logged([sys.executable, str(REPO_ROOT / "eval.py"), f"ckpt={best_checkpoint(trained)}", f"out={dest}",
                            "refine=search_fast", "examples=0"], trained / "test_refined.log")  # fmt: skip
            refined = json.loads((dest / "summary.json").read_text())
        row = row_of(part, arm, seed, split, decoded, refined, spec.get("steps", DENSE_STEPS),
                     [*spec.get("train", []), *spec.get("eval", [])])
        if split == "held_out" and any(o.lstrip("~+").startswith("object.symmetry") for o in spec.get("train", [])):
            # the arm declared another symmetry, which its own test scores with: the same poses under the group
            # of conf/object/<part>.yaml too, so that the declaration's gain and the network's are told apart
            out = dense_run(part, arm, seed)
            row["ap_decoded_own_group"] = own_group_ap(part, out / "test")
            if refined is not None:
                row["ap_refined_own_group"] = own_group_ap(part, out / "test_refined")
        print(f"[{part} {arm} s{seed} {split}] AP {row['ap_decoded']}"
              + (f", refined {row['ap_refined']}" if refined is not None else ""), flush=True)  # fmt: skip
        rows.append(row)
    return rows


# ---------------------------------------------------------------------------------------------- the page

#: what the tables say, written from them (each number is in the CSV)
NOTES = [
    "## Notes", "",
    "- *Grid* (kept; chosen on val): the plate's D spans 3.5 cells of the recipe's 16 over the 0.8 m crop; at "
    "`parameterization.grid=32` (7 cells, the same 128-pixel input and budget) the plate's AP as decoded is "
    "0.341 ± 0.029 on val (base 0.081 ± 0.031) and 0.316 ± 0.015 held-out (base 0.082 ± 0.024), 2 seeds. The cell "
    "recipe sizes its grid to the part (`part_cells: 5` in `experiment=cell`; `part_cells=null`: the grid as given). "
    "On the ITODD parts, which the new-parts recipe already frames at about 5.6 cells of 16, grid 32 (seed 0, the "
    "same piles and budget) gains nothing: ITODD 08 0.253 against 0.256, ITODD 27 0.372 against 0.445 as decoded. "
    "More cells help a part that spans too few, not one that spans five. *Steps* (on top of grid 32): twice the steps (`g32_s6000`, 6000, the cosine schedule stretched over them; "
    "3 seeds) lift the plate as decoded to 0.435 ± 0.024 on val and 0.416 ± 0.014 held-out (grid 32 at 3000, 2 "
    "seeds: 0.341 / 0.316), found 52 % (54 %), and with the recorded search to 0.663 / 0.610. The in-training AP "
    "levels off at 0.45-0.48 over the last 500 steps of each seed."
    " *No gain* within the base's spread (its two seeds differ by 0.03-0.04 AP as decoded: one seed of another arm "
    "tells apart only a change larger than that): the position loss weighted 10× (`lxy10`), a 256-pixel input at the same "
    "16 cells (`in256_st8`, the part 40 pixels instead of 20): pixels per part are not what the plate lacked, cells "
    "per part are. Nor ITODD 08's: the same stem at 256 pixels (the wheel 90 pixels across instead of 45, the same "
    "network and budget, seed 0) scores 0.346 held-out against 0.368 and 0.408 for the recipe's two runs of seed 0 "
    "(`turns4_tuned`, `new_parts.py`), each after its tuning (validation 0.364 against 0.346), its oblique spins no "
    "better read ([spin_by_view.md](spin_by_view.md)). Pose averaging helps a little (no averaging: 0.052 against 0.065 held-out, seed 0). The orientation's "
    "loss weighted 3× (`lori3`, the new-parts budget, seed 0, the same piles) leaves ITODD 27's spin misses where they "
    "were (30 %) and scores 0.385 as decoded against the recipe's 0.445 (refined 0.652 against 0.640); ITODD 08 scores "
    "0.281 against 0.256 (spin misses 28 % against 37 %, position misses up; refined 0.382 against 0.396). One seed "
    "each, in opposite directions: not kept.",
    "- *Refinement* (the kept network; chosen on val, seeds 0 and 1, then 3 seeds): at 0.04 D a pose across two "
    "stacked plates agrees with both (`tol04`: 0.590 ± 0.011); a flat part's own `turn_tolerance` of 0.02 D (the "
    "default since) 0.672 ± 0.011, held-out 0.610 ± 0.010. More of the network's cells and every hypothesis searched "
    "(`t2_thr05_merge0`) add 0.05 at 460 ms per frame; settings that cut the search's work (duplicates dropped before "
    "the polish, a coarse grid on every second point, only poses within half the best agreement polished: `flat`) "
    "cost under 0.01; the sensor's see-through weighted twice (`flat_stw2`, +0.010 over 3 seeds) and the ranking on "
    "2000 points of its own (`flat_stw2_rank`, +0.01) gain; ICP and the search on 400 points bring it within 300 ms "
    "(`flat_stw2_rank_mp400`, = `refine=search_flat` with the threshold 0.05, what `experiment=cell` records for a "
    "flat part): **0.716 ± 0.017** on val, **0.662 ± 0.002** held-out, 237-273 ms per frame "
    "([frame_speed.md](frame_speed.md)).",
    "- *Turns* (kept; chosen on val, no training: each part's recipe network, seed 0): the decoding pools the "
    "input's half turn or four quarter turns (`+decoding.turns=2|4`, docs/method.md#decoding). As decoded on val: "
    "ITODD 27 0.542 → 0.633 (2) → 0.670 (4), ITODD 08 0.209 → 0.270 → 0.259, the plate (the shipped cell model, on "
    "its own training piles' validation cycles) 0.542 → 0.580 → 0.569. Both help all three; 4 turns has the higher "
    "mean (0.499 against 0.494) and is what `experiment=dense` and `experiment=cell` now record. Held-out, scored "
    "once after: ITODD 27 0.445 → 0.538, ITODD 08 0.256 → 0.254, the plate where the bin moved 0.389 → 0.432. On "
    "the networks of two other arms (`g32`, `lori3`) 4 turns "
    "lift val on both parts too (ITODD 27 0.497 → 0.626, 0.528 → 0.677; ITODD 08 0.270 → 0.339, 0.230 → 0.273); "
    "held-out ITODD 27 0.372 → 0.453, 0.385 → 0.517, ITODD 08 0.253 → 0.387, 0.281 → 0.252. "
    "ITODD 27's spin misses fall from 30 % to 26 %; ITODD 08's stay at 38 %: a spin the network does not see in one "
    "turn it does not see in another. A compact part loses nothing: the shipped dense bunny model on the official "
    "Siléane piles (`sileane_rerender.py --fitted`, then `eval.py ckpt=models/dense_bunny.ckpt data.root=<them> "
    "data.test_root=<them> +decoding.turns=4`) scores 0.965 against 0.947 with one pass. *Tuned after training* "
    "(kept in `experiment=dense`: `tune_decoding: 8`; `turns4_tuned`, `cell_tuned`): each network's decoding with 4 "
    "turns searched on its own validation scenes (every 8th; the plate's training piles hold 200: all) and written "
    "into its checkpoint. On those scenes ITODD 27 0.661 → 0.711 (min_visibility 0.3, eps 1.0), ITODD 08 0.277 → "
    "0.351 (score p, min_visibility 0.4, eps 0.75), the plate 0.554 → 0.600 (eps 1.0); held-out, scored once after: "
    "ITODD 27 0.538 → 0.601, ITODD 08 0.254 → 0.368, the plate where the bin moved 0.444 → 0.476 (the shipped model as "
    "re-made with the turns, before it tuned). All three gain, all with a narrower averaging radius than the "
    "configured 1.5 δ. "
    "Made by the recipe before fresh spins (`new_parts.py --run`, whose validation with the turns picked another "
    "ITODD 08 checkpoint): "
    "ITODD 27 0.601, ITODD 08 0.408 (configured 0.538, 0.281); `experiment=cell` (`tune_decoding: 1`, `cells.py "
    "--stage cell`): the shipped plate model 0.476 where the bin moved, its search unchanged (it decodes without "
    "the averaging).",
    "- *Orientation quality* (not kept; seed 0, each part's piles and budget; arms `quality`, `cell_quality`; "
    "docs/method.md#orientation-quality): the network also learns q̂, how right the orientation of each of its cells "
    "is, and scores p̂ q̂. Before any tuning it does much of what the tuning does: held-out as decoded with each "
    "configured decoding, ITODD 08 0.281 → 0.398 and ITODD 27 0.538 → 0.600 (the recipe's runs against the quality "
    "arms), the plate on its validation scenes 0.554 → 0.568. After each recipe's own tuning on validation little is "
    "left: held-out ITODD 08 0.368 (the `exact` network tuned; the recipe's own run 0.408) → 0.424, ITODD 27 0.601 → "
    "0.599, the plate where the bin moved 0.476 → 0.479 (validation 0.600 → 0.598). q̂ ranks out the cells whose spin "
    "is poor, which the tuned minimum visibility (0.3-0.4 for both ITODD parts) mostly does already. One seed, and "
    "within the seeds' spread on two of the three parts: not kept; `quality: false` stays every configuration's "
    "default. *Fresh spins per view* (kept: `experiment=dense` sets `scene.view_spin: auto`; each part's budget; "
    "arm `view_spin`, "
    "docs/data.md#fresh-spins-per-view): the recipe's ITODD 08 network ends with a training loss of the orientation "
    "at a third of its validation loss (2.66 against 8.25; position 0.16 against 0.13), as if 24 piles showed too "
    "few spins. Its training piles made again from the same physics, every part turned by a fresh spin about its "
    "axis in each view after the first (the wheel's hull is a body of revolution), leave both the gap (2.98 against "
    "7.42) and the held-out AP where they were: 0.404 against the recipe's own run's 0.408 after each one's tuning, "
    "0.301 against 0.281 as configured; found 63 % against 67 %, side-on 54 % against 54 %. The spins are not what "
    "is short (its validation row is its own spun piles'). Against the recipe's network tuned the same way at the "
    "same seeds (`turns4_tuned`, seeds 0-2) it gains a little: on the recipe's validation piles (the `eval.py` "
    "command below) at every seed, 0.377, 0.456, 0.441 against 0.346, 0.357, 0.397 (**0.425 ± 0.042** against "
    "0.367 ± 0.027); held-out at two seeds of three, 0.404, 0.412, 0.312 against 0.368, 0.353, 0.325 (**0.376 ± "
    "0.055** against 0.349 ± 0.022), far below the part's target. ITODD 27, whose flat face shows its spin, gains "
    "at every "
    "seed (seeds 0-2, the same piles, budget and seeds as the recipe's network tuned the same way, `turns4_tuned`): "
    "held-out **0.680 ± 0.015** against 0.567 ± 0.035 (per seed +0.09, +0.12, +0.13), found 75 % against 67 %, "
    "spin p50 5.2° against 6.1°; on the recipe's own validation piles (`eval.py ckpt=<view_spin_s*> split=val "
    "data.root=<the recipe's training piles>`) 0.760 ± 0.082 against 0.683 ± 0.079 (+0.10, +0.06, +0.07). The "
    "recipe as committed reaches ITODD 27's 0.6 at one seed of three, fresh spins at all three. Fresh spins help "
    "where the depth holds the spin, and a little on ITODD 08, whose depth mostly does not (below). Kept, as it "
    "gained on the validation piles of both parts it fits at every seed: `experiment=dense` sets "
    "`scene.view_spin: auto`, which turns exactly the parts whose hull is a body of revolution about their axis and "
    "whose spins are not free (of the measured parts ITODD 08 and ITODD 27; the plate's hull does not qualify, "
    "pepper's spins are free); `opnet-object` says so for such a part. The new-parts rows, re-made with it by "
    "`new_parts.py --run` (seed 0): ITODD 27 0.692 (0.601 before), ITODD 08 0.404 (0.408 before; its seed-0 "
    "`view_spin` run again, to the same figure). "
    "*Fewer piles* (`piles10`, ITODD 08, seed 0, the same steps): the recipe trained on the first 10 of "
    "its 20 training piles scores 0.374 held-out (validation 0.362), against 0.368 and 0.408 for the two runs on all "
    "20 (validation 0.346): twice the piles bought nothing beyond the seeds' spread, so more piles are not the lever "
    "either.",
    "- *What the image shows* (the breakdown counts the parts to find by how the camera sees their main axis, "
    "docs/method.md#where-the-misses-go; columns *found end-on*, *found side-on (side-on share)*): ITODD 08 is a "
    "wheel whose five spokes sit inside its rim. Lying on its tread (side-on: the axis within 30° of the image plane; "
    "36 % of the held-out parts to find, 53 % of the validation's) its spin shows nowhere: the `quality` network finds "
    "45 % of those held-out (validation 42 %) against 85 % (89 %) of those seen end-on, and the recipe's own run 54 % "
    "against 85 % ([the new-parts table](../new_parts/README.md)). A spin guessed at random lies within δ (15.5° of "
    "the 72° between spokes, from the part's Λ and δ) 43 % of the time. ITODD 27, flat, seen edge-on: 32 % (53 %) "
    "against 84 % (90 %) face-on. No training reaches a spin the depth does not hold, and the metric counts each such "
    "guess. Beyond them ITODD 08 lacks ranking: the recipe's network finds 67 % of the held-out parts, and AP 0.408 "
    "is what 14 confident false positives a scene make of them. "
    "*What the depth holds* (the spin study: [spin_observability.md](spin_observability.md), "
    "[spin_ceiling.md](spin_ceiling.md), [spin_by_view.md](spin_by_view.md)): rendered alone at the recipe's 45 "
    "pixels, ITODD 08 turned 36° about its axis changes the depth (by over 1 mm) of 356 of its 1034 input pixels "
    "seen end-on, 71 of 1428 with its axis 40° from the line of sight, 20 at 50°, 6 at 55° and 2 at 60°; at 90 "
    "pixels the shares are alike (68 of 5925 at 50°): the rim hides the spokes, not the resolution. A network "
    "perfect in position, tilt and ranking that reads every spin up to 50° and guesses beyond scores 0.642 on the "
    "held-out piles under the part's cyclic group (45°: 0.539; 60°: 0.771): the target of 0.6 lies at what the "
    "depth holds. The recipe's network puts the spin of its best-scored pose within 6° for 64 % of the validation "
    "parts seen end-on, 22 % of those seen oblique (a random spin: 17 %) and 12 % of those side-on; on its own "
    "training piles 67 %, 43 % and 27 %: of the oblique wheels it learnt the scenes it saw, not how to read them. "
    "The 256-pixel stem (`in256_st8`: 26 % oblique) and half the piles (`piles10`: 28 %) leave that where it was. "
    "*Symmetry* (ITODD 08, seed 0, the new-parts budget): declared as the near-revolution opnet-object names "
    "(every turn about the main axis moves 98 % of its surface by at most 2.67 mm, under its delta of 7.03 mm; "
    "`--declare-near`), the part scores 0.744 held-out as decoded, 0.782 refined, no spin misses left. Under its "
    "committed group (cyclic 5) the same poses score 0.122 / 0.239, the committed group trained (`exact`, the same "
    "piles, budget and seed) 0.256 / 0.396: the gain is the declaration's. The network is no longer asked for a spin the depth hardly shows, and the metric "
    "no longer counts it; make it where every such spin serves the same grasp.",
    "- *Ranking* (not kept; ITODD 08, seed 0, no training: [rank_share.md](rank_share.md), "
    "`scripts/experiments/flat_parts/rank_share.py`). Where ITODD 08's false positives lie, its `view_spin` network "
    "run again at seed 0 on another machine (held-out 0.446, validation 0.453: the two CPUs' physics differ in the "
    "last bits, so the same command made other piles; the table keeps the first machine's runs): of the hypotheses "
    "scored at least as high as the median true positive, 49 % held-out (41 % on validation) are a second pose of "
    "a part another hypothesis finds, at its place (within D/4) but not merged with it, 10 % (16 %) a wrong pose of "
    "a part none finds, 39 % (42 %) true positives: 2.4 such duplicates a scene against 1.9 parts found. Ranking "
    "each hypothesis by its share of the scores at its place (`s (s/S)^alpha`, S summed within rho D; rho 0.1-0.5, "
    "alpha 0.5-2), by how the camera sees its axis (`s cos(a)^beta`, the spin shows end-on; beta 0.5-2), or both, "
    "moves validation by -0.045 to +0.017 (best: rho 0.5, alpha 0.5, beta 0.5, 0.453 → 0.470) and held-out by at "
    "most +0.005 (0.445 → 0.450): a duplicate and the pose it doubles share one place, so any score of the place "
    "ranks both alike; which of them is right is the spin the depth does not show. *Both small levers together* "
    "(`view_spin_quality`: fresh spins per view and the quality channel, seed 0, the same machine, piles and budget "
    "as that `view_spin` run, each tuned on validation): held-out 0.375 against 0.446, validation 0.422 against "
    "0.453; found 75 % against 70 %, but 4.0 confident duplicates a scene against 2.4. Neither kept.",
    "- *The last two levers* (not kept; ITODD 08, seed 0, the same piles, budget and machine kind as that "
    "`view_spin` run, each tuned on validation; the confident duplicates by `rank_share.py <ckpt> --rho 0 --alpha 0 "
    "--beta 0`). *Fresh spins and the finer grid* (`view_spin_g32`: the plate's `parameterization.grid=32`, the "
    "wheel's D over about 11 cells; with the four turns it had lifted the recipe's network, `g32_turns4`): "
    "validation 0.466 against 0.453, held-out 0.403 against 0.446; found 74 % against 70 %, confident duplicates "
    "1.9 a scene against 2.4. *Unseen spins not asked for* (`view_spin_blind55`, `loss.spin_unseen_deg=55`, "
    "docs/method.md#unseen-spins: where the wheel's axis lies more than 55° from the optical axis, beyond which a "
    "36° turn changes 6 of its input pixels by over 1 mm, the loss asks for the axis only): validation 0.444, "
    "held-out 0.311; found 69 %, but 4.6 confident duplicates a scene: a network not asked for a spin gives the "
    "cells of one wheel spins of their own, which the averaging keeps apart. Neither gains beyond the seeds' "
    "spread of ±0.05, and the second loses.",
    "- *Spins reported, not read* (a probe, not a lever; ITODD 08, that `view_spin` network at seed 0, no training: "
    "[spin_hedge.md](spin_hedge.md), `scripts/experiments/flat_parts/spin_hedge.py`). Beside each decoded pose "
    "(or only the best-scored of its place) whose axis lies more than 0 or 45° from its line of sight, one or two "
    "copies turned about the axis by a half or a third of the 72° between spokes, scored 0.05-0.5 times the pose: "
    "the parts found rise from 76 % to 80-92 % held-out, the AP moves by -0.06 to +0.01 (the best on validation, "
    "0.467 against 0.453, is 0.448 held-out against 0.445). The metric does not reward guessing the unseen spin "
    "more often: every copy that finds a part is ranked among copies that find none. What the poses already "
    "are: of the side-on wheels found, the true positive is the best-scored pose at the part (within D/4) for 25 % "
    "on validation (31 % held-out) and outscored there by another pose for 75 % (69 %), against 59 % and 19 % of "
    "the end-on ones on validation; the four quarter turns of the decoding already give a side-on wheel three or "
    "four spins, ranked as by chance. The same network reads the spins of its validation parts as of its "
    "training parts ([spin_by_view_fresh_spins.md](spin_by_view_fresh_spins.md): within 6° for 31 % and 34 % of "
    "the oblique ones, 19 % and 21 % of the side-on ones; the recipe's network without fresh spins: 22 % and 43 % "
    "oblique), so it no longer learns its piles' spins by heart; but the side-on wheels' axes point the wrong way "
    "(tilt over 90°) for 35 % of them on validation against 6 % on the training piles. Turned end over end the "
    "wheel fails its symmetry test by 7.58 mm (opnet-object, 98 % of the surface), just over δ (7.03 mm): the "
    "metric counts the flip, and lying on its tread the wheel shows it only by that much.",
    "- *Fresh flips per view* (not kept; `view_spin_flip`: `scene.view_flip=true` beside the fresh spins, "
    "docs/data.md#fresh-flips-per-view; ITODD 08 is the only measured part whose hull allows it). Seed 0 on the very "
    "piles and spins of that `view_spin` run (the parts not flipped stand where they stand there): validation "
    "0.509 against 0.453, held-out 0.428 against 0.446; found 79 % held-out, tilt misses 5 %, confident "
    "duplicates 1.9 a scene held-out against 2.4 (seed 1: 0.5, but 1.6 confident true positives against 1.9). "
    "Seed 1 (its "
    "comparison the table's `view_spin` seed 1, made on the first machine's piles): validation 0.491 against 0.429, "
    "held-out 0.381 against 0.412. The network no longer learns the flips by heart (side-on wheels upside down: "
    "29 % on validation, 24 % on its training piles, against 35 % and 6 %: "
    "[spin_by_view_fresh_flips.md](spin_by_view_fresh_flips.md)) and reads more oblique spins (37 % within 6° "
    "against 31 %). The two splits disagree at both seeds: +0.06 on the validation split, which holds two piles "
    "(their 16 views), -0.02 and -0.03 on the 12 held-out piles. Chosen on validation it would be kept; the "
    "held-out piles, six times the piles, say it does not carry over, so no recipe takes it, and the dense "
    "validation split's size is what to mend before choosing on it again.",
    "- *Validation piles of their own* (`--splits wide_val`: single views of 40 piles of seed 2, made as the "
    "held-out piles are, their 240 scenes of 70-75 parts; ITODD 08, every network of the fresh-spins arms, each "
    "decoded as its run tuned it). Against the partner trained on the same piles at the same seed "
    "(`view_spin_again`, the `view_spin` command again on this machine kind: validation 0.453, wide 0.461, held-out "
    "0.446), the 2-pile validation split has `view_spin_flip`, `view_spin_clean` and `view_spin_g32` ahead "
    "(+0.056, +0.039, +0.013) and two behind; the 40 piles have all five behind (-0.024 to -0.050), as the 12 "
    "held-out piles do (-0.018 to -0.135). At seed 1 (`view_spin_again` 0.488 / 0.448 / 0.420) fresh flips are "
    "+0.003 on validation, -0.001 on the wide piles and -0.039 held-out: over both seeds -0.013 wide, -0.029 "
    "held-out, not the +0.030 the two piles said. The two validation piles' own dense scenes (70 parts or more, 96 "
    "scenes) do no better: they rank the partner last (0.234 against 0.264-0.344), so it is the two piles, not the "
    "sparse scenes among them, that mislead. The decoding tuned on every second wide scene "
    "(`opnet-tune-decoding --root <them> --stride 2`: score p, minimum visibility 0.4, radius 1.0; wide 0.466 -> "
    "0.481) scores 0.432 held-out against 0.446 for the run's own: the decoding is not where ITODD 08's AP hides "
    "either. `data.val_root` (training) and `opnet-tune-decoding --root` choose on such piles; the recipes keep "
    "their validation share (a recipe change would re-make every dense row).",
    "- *Depth as rendered* (not kept; `view_spin_clean`, seed 0, the partner's piles and budget: no elastic warp, "
    "blur, noise or dropout in training, the random resize and quarter turns kept). The recipe's noise reaches 2.5 "
    "mm at ITODD 08's rig (1 % of its 249 mm working range), above the 1 mm by which a 36° turn moves the 71 pixels "
    "where an oblique wheel shows its spokes. Without it: validation 0.492 against 0.453, wide 0.420 against 0.461, "
    "held-out 0.415 against 0.446; found 77 % held-out. What the clean depth gains on the two validation piles "
    "does not carry over to other piles: the noise is not what keeps the network from the spokes.",
    "- *Depth read in float32* (`view_spin_fp32stem`: `model.fp32_stem=true` beside the fresh spins, "
    "docs/method.md#network-input; ITODD 08, the new-parts budget). Training runs under bf16 autocast on a CPU with "
    "native bf16, so the stem read the normalized depth rounded to 1/256 of its value: 0.5-1 mm at ITODD 08's rig "
    "(249 mm working range), as much as the relief by which an oblique wheel shows its spokes. Its partner is the "
    "`view_spin` command once more (`view_spin_again2`) on piles the same commands made again: not those of "
    "`view_spin_again`'s machine (side-on shares 0.357 held-out and 0.366 wide against 0.333 and 0.335) but the very "
    "piles of the table's `view_spin` runs, whose validation and held-out rows the partner reproduces at all three "
    "seeds to the fourth decimal (training is deterministic for a seed on given piles). Their fingerprints "
    "(`python -m opnet.datasets.check --fingerprint`): training 045787f8c53a42dc, wide c51436636813f817, held-out "
    "02137b36157f819f. Three paired seeds, float32 stem against partner: validation 0.406 / 0.409 / 0.448 "
    "against 0.372 / 0.429 / 0.436 (**0.421 ± 0.023** against 0.412 ± 0.035, paired gain +0.009 ± 0.027), "
    "wide 0.427 / 0.460 / 0.426 against 0.355 / 0.428 / 0.362 (**0.437 ± "
    "0.019** against 0.382 ± 0.041, +0.056 ± 0.022, ahead at every seed), held-out 0.489 / 0.392 / 0.416 against "
    "0.404 / 0.412 / 0.312 (**0.432 ± 0.051** against 0.376 ± 0.055, +0.056 ± 0.067, ahead at two seeds of three). "
    "Training minutes alike (20.6 / 21.0 against 21.3 / 21.8 / 18.8; seed 1 of the arm's 47.9 include 20 shared "
    "with a test run). How it gains is not one thing: at seed 0 the spin misses fall (7 % against 17 % held-out, 6 % "
    "against 22 % wide), at seed 2 they rise (wide 14 % against 9 %) and the parts found fall (70 % against 76 %) "
    "while the AP rises, its confident poses right more often. The spins of the best-scored poses "
    "([spin_by_view_fp32_stem.md](spin_by_view_fp32_stem.md), seed 0; "
    "[spin_by_view_fp32_stem_seeds12.md](spin_by_view_fp32_stem_seeds12.md), seeds 1 and 2; every 8th validation "
    "scene): within 6° for 70 / 65 / 58 % of the wheels seen end-on against 63 / 61 / 58 %, oblique 23 / 26 / 38 % "
    "against 22 / 30 / 30 %, side-on 15 / 15 / 20 % against 16 / 19 / 19 %: no view whose spins it reads better at "
    "every seed. Chosen on the wide validation piles it helps ITODD 08 (+0.056 ± 0.022, more than the partner's "
    "seed spread of 0.041), and held-out agrees on the mean; still 0.17 below the part's 0.6. On ITODD 27 (seed 0, "
    "piles made again whose side-on shares match `view_spin`'s to the fourth decimal, 0.1227 validation and 0.2297 "
    "held-out; fingerprints: training c635cfd78735c6b5, held-out db2d747350eae08c) it scores validation 0.821 against "
    "`view_spin`'s 0.810 and held-out 0.627 against 0.692 (found 71 % against 76 %, spin misses 17 % against 14 %); "
    "seed 1 (the same piles) validation 0.788 against 0.785, held-out 0.665 against 0.684: over both seeds a tie on "
    "validation (+0.007), a loss held-out (-0.042). Not measured on the plate. It helps one part of three, so no "
    "recipe takes it (`model.fp32_stem: false` stays the default); ITODD 27's seed 2 and the plate would settle it.",
    "",
]


def write_page(rows: list[dict[str, Any]]) -> None:
    """The arms' table (mean ± sd over seeds) per part and split, as ``README.md`` beside the CSV."""
    groups: dict[tuple[str, str, str, str], list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["part"], r["split"], r["lever"], r["arm"]), []).append(r)
    lines = ["# Flat, thin and spinning parts: where the poses go wrong, each lever's A/B", "",
             "`python scripts/experiments/flat_parts/flat_parts.py` (every number in [flat_parts.csv](flat_parts.csv)). "
             "AP: Brégier, max occlusion 0.5; mean ± sd over the seeds given (one value: one seed). Misses by the largest share of their "
             "squared pose distance (no hypothesis within D/2; lateral, depth, tilt of the main axis, spin about it).",
             ""]  # fmt: skip
    for part in dict.fromkeys(r["part"] for r in rows):
        for split in SPLITS:
            order = [a for arms in ARMS.get(part, {}).values() for a in arms]  # the arms as ARMS lists them
            keys = sorted((k for k in groups if k[0] == part and k[1] == split),
                          key=lambda k: order.index(k[3]) if k[3] in order else len(order))
            if not keys:
                continue
            # arms that declared another symmetry: their poses scored under the part's committed group too
            own_group = any(r.get("ap_decoded_own_group") for k in keys for r in groups[k])
            lines += [f"## {part}, {split.replace('_', '-')} piles", "",
                      "| lever | arm | seeds | AP decoded | AP refined | found % | no hyp % | lateral % | depth % | "
                      "tilt % | spin % | tilt p50 ° | spin p50 ° | found end-on % | found side-on % (side-on share) | "
                      "refine ms/img | AP in training |"
                      + (" AP decoded / refined, the part's own group |" if own_group else ""),
                      "|---" * (18 if own_group else 17) + "|"]  # fmt: skip
            for key in keys:
                g = groups[key]

                def m(field: str, scale: float = 1.0, digits: int = 3, g: list = g) -> str:
                    vals = [float(r[field]) * scale for r in g if r.get(field) not in ("", None)]
                    if len(vals) == 1:  # one seed: no spread to give
                        return f"{vals[0]:.{digits}f}"
                    return mean_sd_text(vals, digits) if vals else "–"

                own = ("–" if not any(r.get("ap_decoded_own_group") for r in g)  # the arm scored under its own group
                       else f"{m('ap_decoded_own_group')} / {m('ap_refined_own_group')}")
                lines.append(f"| {key[2]} | {key[3]} | {len(g)} | {m('ap_decoded')} | {m('ap_refined')} | "
                             f"{m('found', 100, 1)} | {m('no_hypothesis', 100, 1)} | {m('missed_lateral', 100, 1)} | "
                             f"{m('missed_depth', 100, 1)} | {m('missed_tilt', 100, 1)} | {m('missed_spin', 100, 1)} | "
                             f"{m('tilt_deg_p50', 1, 1)} | {m('spin_deg_p50', 1, 1)} | {m('found_end_on', 100, 0)} | "
                             f"{m('found_side_on', 100, 0)} ({m('side_on', 100, 0)}) | {m('ms_per_frame', 1, 0)} | "
                             f"{m('train_val_ap')} |" + (f" {own} |" if own_group else ""))  # fmt: skip
            lines.append("")
    lines += NOTES
    for part, levers in ARMS.items():  # what the script defines and has not scored yet
        waiting = [a for arms in levers.values() for a in arms if not any(r["part"] == part and r["arm"] == a for r in rows)]
        if waiting:
            lines.append(f"Not scored yet ({part}): {', '.join(waiting)}.")
    lines.append("")
    (OUT / "README.md").write_text("\n".join(lines))
    print("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", choices=list(ARMS), default="plate")
    ap.add_argument("--arms", nargs="+", default=[])
    ap.add_argument("--seeds", nargs="+", type=int, default=[0])
    ap.add_argument("--splits", nargs="+", choices=SPLITS, default=["val", "held_out"],
                    help="wide_val: the dense parts' validation piles of their own (WIDE_VAL_PILES)")
    ap.add_argument("--no-refine", action="store_true", help="score as decoded only")
    ap.add_argument("--report", action="store_true", help="only re-make the page from the CSV")
    args = ap.parse_args(argv)
    OUT.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    if args.part == "plate" and "wide_val" in args.splits:
        raise SystemExit("error: --splits wide_val: the dense parts' piles; the plate's validation piles are val_c6")
    if not args.report:
        for arm in args.arms:
            arm_spec(args.part, arm)
        for seed in args.seeds:
            for arm in args.arms:
                if args.part == "plate":
                    plate_train(arm, seed)
                    rows += plate_rows(arm, seed, args.splits, not args.no_refine)
                else:
                    rows += dense_rows(args.part, arm, seed, args.splits, not args.no_refine)
    all_rows = merge_csv(OUT / "flat_parts.csv", FIELDS, rows, ("part", "arm", "seed", "split"))
    write_page(all_rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
