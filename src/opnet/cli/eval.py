"""``python eval.py ckpt=<path>``: decode a split, write Siléane-format results, print the AP table."""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from omegaconf import DictConfig, OmegaConf

from opnet.cli.build import build_datamodule, load_checkpoint
from opnet.cli.console import report, result_summary
from opnet.cli.locks import writer_lock
from opnet.datasets.outputs import require_output_folder
from opnet.datasets.sileane_json import write_gt_json, write_results_json
from opnet.estimator import PoseEstimator
from opnet.evaluation import OnScenes, Scenes, evaluate, scoring
from opnet.fileio.atomic import write_bytes_atomic, write_text_atomic
from opnet.metrics.breakdown import error_breakdown
from opnet.metrics.diagnostics import orientation_misses
from opnet.metrics.records import GroundTruthSet, HypothesisSet
from opnet.refine import (
    STAGES,
    STATUSES,
    ICPSettings,
    Refiner,
    model_refinement,
    settings_from_config,
)
from opnet.run_settings import InputSettings
from opnet.settings_schema import SettingError
from opnet.visualize import draw_models

log = logging.getLogger(__name__)


def evaluate_split(system: PoseEstimator, datamodule: Any, split: str, out_dir: Path, examples: int = 0,
                   icp: ICPSettings | None = None) -> dict[str, Any]:  # fmt: skip
    """Predict a split, write ``gt/`` and ``results/`` (Siléane JSON), ``summary.json``, ``ap_table.md``
    (eval.py and train.py's test; one :func:`opnet.evaluation.evaluate` with the refinement, the
    result writers, the AP, the diagnostics and the turns of the orientation misses as its evaluators).

    Args:
        icp: refine every hypothesis against its scene's depth image (:mod:`opnet.refine`);
            None: the network's poses as decoded.
    Returns the summary dict (ap, map, f1, recall_at_p50, recall_at_p99, per_scene, ...).
    """
    datamodule.setup("test")
    loader = getattr(datamodule, f"{split}_dataloader")()
    samples, obj = datamodule.splits[split], system.parameterization.obj
    refine = [OnScenes(lambda scenes: refine_scenes(scenes, samples, obj, icp))] if icp else []
    writers = [OnScenes(lambda scenes: _write_scene_files(scenes, out_dir)),
               OnScenes(lambda scenes: _write_bop_results(datamodule, split, scenes, out_dir / "bop_results.csv"))]
    if examples:
        writers.append(OnScenes(lambda scenes: write_examples(system, samples, scenes, out_dir / "predictions",
                                                              examples)))
    turns = OnScenes(lambda scenes: orientation_misses(scenes, obj.pose_space, obj.diameter,
                                                       max_occlusion=system.max_occlusion))
    split_errors = OnScenes(lambda scenes: error_breakdown(scenes, obj.pose_space, obj.diameter,
                                                           max_occlusion=system.max_occlusion))
    *done, count, summary, diagnostics, misses, breakdown = evaluate(
        system, loader, [*refine, *writers, OnScenes(len), *scoring(system), turns, split_errors])
    result = summary.to_dict()
    result["diagnostics"] = diagnostics.to_dict()
    result["orientation_misses"] = misses.to_dict()
    result["breakdown"] = breakdown.to_dict()
    result.update(split=split, scenes=count, object=obj.name,
                  parameterization=type(system.parameterization).__name__)
    if icp:
        result["icp"] = done[0]
    write_text_atomic(out_dir / "summary.json", json.dumps(result, indent=2))
    write_text_atomic(out_dir / "ap_table.md", summary.table() + "\n\n" + diagnostics.table() + "\n"
                      + misses.table() + "\n" + breakdown.table() + "\n")
    return result


def _write_scene_files(scenes: Scenes, out_dir: Path) -> None:
    """``gt/`` and ``results/`` under ``out_dir``: each scene's ground truth and hypotheses (Siléane JSON)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    for name, (gt, hyps) in scenes.items():
        write_gt_json(out_dir / "gt" / f"{name}.json", gt)
        write_results_json(out_dir / "results" / f"{name}.json", hyps)


def refine_scenes(scenes: dict[str, tuple[GroundTruthSet, HypothesisSet]], samples: Any, obj: Any,
                  settings: ICPSettings) -> dict[str, Any]:  # fmt: skip
    """Refine the hypotheses of every scene in place against the scene's own depth image as the
    data module reads it (with the scene cache: the cached canvas, twice the network input by
    default; without: the dataset's image), with its camera; returns the milliseconds per image (and
    per stage of the refinement) and the count of each status."""
    refiner = Refiner.for_object(obj, settings)
    counts = dict.fromkeys(STATUSES, 0)
    seconds = 0.0
    stages: dict[str, float] = {}
    for i in range(len(samples)):
        record = samples.record(i)
        if record.name not in scenes:
            continue
        gt, hyps = scenes[record.name]
        start = time.perf_counter()
        refined, status = refiner(hyps, record.depth, record.camera, stages)
        seconds += time.perf_counter() - start
        scenes[record.name] = (gt, refined)
        for s in status:
            counts[s] += 1
    n = max(len(scenes), 1)
    return {"ms_per_image": 1000 * seconds / n, "statuses": counts, "settings": dataclasses.asdict(settings),
            "ms_per_image_by_stage": {k: round(1000 * stages[k] / n, 2) for k in STAGES if k in stages}}


def _write_bop_results(datamodule: Any, split: str, scenes: dict[str, tuple[GroundTruthSet, HypothesisSet]],
                       path: Path) -> None:
    """The predictions as a BOP results CSV (for the user's own bop_toolkit), when the scene names
    are BOP (``<scene>_<image>``) or IPA (``cycle_XXXX_NNN``) ones; poses back in the BOP model frame."""
    from opnet.datasets.bop import (
        bop_results_rows,
        is_bop_split,
        model_info,
        models_dir_of,
        symmetry_from_bop,
    )

    obj_id = getattr(datamodule, "object_id", None)
    own = getattr(datamodule, f"{split}_roots", None)  # a split of datasets of its own (data.test_root, val_root)
    roots = own if own else getattr(datamodule, "roots", [])
    R_align = None
    if obj_id is not None and roots and is_bop_split(Path(roots[0])):
        models = models_dir_of(Path(roots[0]))
        R_align = symmetry_from_bop(model_info(models, obj_id), str(models))[1]
    try:
        lines = bop_results_rows(((n, h) for n, (_, h) in scenes.items()), obj_id or 1, R_align)
    except ValueError:  # names of another layout (Siléane): no BOP ids to write
        return
    write_text_atomic(path, "\n".join(lines) + "\n")


def write_examples(
    system: PoseEstimator, samples: Any, scenes: dict[str, tuple[GroundTruthSet, HypothesisSet]], out: Path, n: int,
    min_score: float = 0.5,
) -> list[Path]:
    """PNGs of the first ``n`` scenes: depth with each estimated object's model (score >= min_score) on it."""
    mesh = system.parameterization.obj.mesh
    if mesh is None:
        return []
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for i in range(min(n, len(samples))):
        record = samples.record(i)
        confident = scenes[record.name][1].above(min_score)
        img = draw_models(record.depth, record.camera, mesh.vertices, mesh.faces, confident)
        path = out / f"{record.name}.png"
        write_bytes_atomic(path, cv2.imencode(".png", img[..., ::-1])[1].tobytes())  # a full disk is an error
        written.append(path)
    return written


def with_decoding_overrides(param: Any, overrides: Any) -> Any:
    """The checkpoint's parameterization with the decoding settings of ``decoding=`` overridden
    (threshold, score, min_visibility, turns; averaging: false, or a mapping of eps, min_samples,
    cluster_score); nothing given: unchanged. A bad value or an unknown key is one ``SettingError`` naming
    it as written (``decoding.averaging.eps``, :mod:`opnet.settings_schema`)."""
    if not overrides:
        return param
    if not isinstance(overrides, Mapping):
        raise SettingError("decoding", overrides, "expected a mapping of threshold, score, min_visibility, turns, "
                           "averaging")
    settings = OmegaConf.to_container(overrides) if isinstance(overrides, DictConfig) else dict(overrides)
    return param.with_decoding(**settings)


def apply_decoding_overrides(system: PoseEstimator, overrides: Any) -> None:
    """Make ``system`` decode with its settings' decoding overridden by ``decoding=`` (eval.py's and
    predict.py's ``+decoding.*``; :meth:`opnet.run_settings.DecodingSettings.with_overrides`); nothing
    given: unchanged. A bad value or an unknown key is one ``SettingError`` naming it as written."""
    if isinstance(overrides, DictConfig):
        overrides = OmegaConf.to_container(overrides)
    system.set_decoding(system.settings.decoding.with_overrides(overrides))


def model_settings(system: PoseEstimator, refine: Any, decoding: Any) -> ICPSettings | None:
    """eval.py's and predict.py's refinement and decoding for ``system``: ``refine=model`` (their
    default) is the refinement the checkpoint records (none if it records none); that search decodes
    without pose averaging (every hypothesis is refined and verified on its own) unless ``+decoding.averaging``
    says otherwise, and every search the image alone (``turns`` 1: the turns' hypotheses would multiply its
    work) unless ``+decoding.turns`` does. Applies the decoding; returns the refinement's settings."""
    if isinstance(refine, DictConfig):
        refine = OmegaConf.to_container(refine, resolve=True)
    refine, by_model = model_refinement(refine, system.settings.refine)
    icp = settings_from_config(refine)
    if isinstance(decoding, DictConfig):
        decoding = OmegaConf.to_container(decoding)
    if icp is not None and icp.search is not None:
        decoding = {"turns": 1, **({"averaging": False} if by_model else {}), **(decoding or {})}
    apply_decoding_overrides(system, decoding)
    if by_model:
        log.info("refinement: %s, the one the checkpoint records (refine=none: the poses as decoded)",
                 system.settings.refine)
    return icp


def framing_overrides(framing: InputSettings) -> dict[str, Any]:
    """The ``data.*`` keys of the model's framing (input size, canvas fit, region of interest), with
    which a data module frames its scenes as the model was trained to see them."""
    return {"input_size": framing.size, "fit": framing.fit,
            "roi": list(framing.roi) if isinstance(framing.roi, tuple) else framing.roi}


def warn_other_clip(samples: Any, trained: tuple[float, float] | None) -> None:
    """Log a warning when the scenes' cameras normalize depth with other clip planes than the
    model's training scenes did (the network then sees its inputs scaled otherwise): scenes whose
    camera files set the planes (IPA, Siléane, generated); BOP scenes take the model's planes
    unless ``data.clip`` gives others."""
    planes = samples.clip_planes() if trained is not None and len(samples) else None
    if planes is not None and not np.allclose(planes, trained, atol=1e-6):
        log.warning("the scenes' clip planes [%g, %g] m differ from the model's training planes [%g, %g] m: the "
                    "network sees their depth normalized otherwise (+data.clip=[%g,%g] for BOP data)",
                    *planes, *trained, *trained)


def run(cfg: DictConfig) -> dict[str, Any]:
    """Entry logic of eval.py (see conf/eval.yaml)."""
    started = time.monotonic()
    out_dir = Path(cfg.out) if cfg.get("out") else Path(cfg.ckpt).resolve().parent.parent / f"eval_{cfg.split}"
    require_output_folder(out_dir, [Path(cfg.ckpt)], "out=")  # a file or /dev/null: refused before the evaluation
    with writer_lock(out_dir, "out="):  # a second eval into this folder stops at once
        return _evaluate(cfg, out_dir, started)


def _evaluate(cfg: DictConfig, out_dir: Path, started: float) -> dict[str, Any]:
    """The evaluation of :func:`run` into ``out_dir`` (locked)."""
    system, run_cfg = load_checkpoint(cfg.ckpt)
    icp = model_settings(system, cfg.get("refine"), cfg.get("decoding"))
    log.info("inference: %s", system.configure_inference(cfg.get("inference")))
    overrides = {k: v for k, v in (cfg.get("data") or {}).items() if v is not None}
    for key, value in framing_overrides(system.settings.input).items():  # the model's, unless eval.py's data.* says
        if key not in overrides and run_cfg.data.get(key) != value:
            overrides[key] = value
    trained = system.settings.input.trained_clip
    if trained is not None and overrides.get("clip") is None:
        # BOP scenes are normalized with the model's training planes, not a range guessed from their first image
        overrides["clip"] = list(trained)
    if overrides.get("root") is not None and run_cfg.data.get("generate") is not None:
        overrides.setdefault("generate", None)  # another dataset is read as it is, never generated into
    if overrides:  # overrides of the data section (e.g. another dataset root)
        run_cfg = OmegaConf.merge(run_cfg, {"data": overrides})
    datamodule = build_datamodule(run_cfg, system.parameterization.obj, train=False)
    datamodule.setup("test")
    warn_other_clip(datamodule.splits[cfg.split], trained)
    result = evaluate_split(system, datamodule, cfg.split, out_dir, examples=int(cfg.get("examples", 0)), icp=icp)
    lines = result_summary(result, str(out_dir / "ap_table.md"), time.monotonic() - started, bool(cfg.get("verbose")))
    report(["", *lines, f"results       : {out_dir}/summary.json, {out_dir}/ap_table.md (per scene), {out_dir}/results/"])
    return result
