"""The decoding searched on a model's recorded outputs: what ``opnet-tune-decoding`` runs, and what train.py
runs after training with ``tune_decoding`` (:func:`tune_in_place`).

The network runs once over a split (every K-th scene) and once over each quarter turn the search may pool
(:class:`RecordedSplit`); every setting then only re-decodes the stored outputs and re-scores them with the
Brégier AP. The search (:func:`search`) is coordinate-wise over :data:`SEARCH`: the score, the minimum
visibility, the turns and the pose averaging's radius, minimum cluster and cluster score.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import itertools
import json
import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import torch  # noqa: E402
from omegaconf import OmegaConf  # noqa: E402

from opnet.cli.build import build_datamodule, load_checkpoint  # noqa: E402
from opnet.cli.tools import save_checkpoint  # noqa: E402
from opnet.data.sample import Batch
from opnet.evaluation import AveragePrecision, Evaluator, evaluate
from opnet.fileio.atomic import write_errors_named, write_text_atomic  # noqa: E402
from opnet.metrics.records import GroundTruthSet  # noqa: E402
from opnet.parameterizations.averaging import PoseAveraging  # noqa: E402
from opnet.parameterizations.base import Parameterization  # noqa: E402
from opnet.parameterizations.turns import quarters  # noqa: E402
from opnet.run_settings import CHECKPOINT_KEY, RunSettings
from opnet.settings_schema import QUALITY_SCORES

SEARCH: dict[str, list[Any]] = {
    "averaging": [False, True],
    "score": ["p", "p*v", *QUALITY_SCORES],  # the last two only for a network with a quality channel
    "min_visibility": [0.0, 0.1, 0.2, 0.3, 0.4],
    "eps": [0.25, 0.5, 0.75, 1.0, 1.5, 2.0],
    "min_samples": [1, 2, 3],
    "cluster_score": ["max", "sum", "mean"],
    "turns": [1, 2, 4],
}
AVERAGING_KEYS = ("eps", "min_samples", "cluster_score")
#: the most rounds of the search (each round tries every candidate of every setting once more)
MAX_ROUNDS = 10


@dataclass
class RecordedSplit:
    """Network outputs of a split, kept to be decoded many times."""

    parameterization: Parameterization
    outputs: list[torch.Tensor]
    cameras: list[list[Any]]
    gts: list[list[GroundTruthSet]]
    max_occlusion: float
    #: quarter turn q (1-3) -> the outputs of each batch's images turned by it (the turns recorded)
    turned: dict[int, list[torch.Tensor]] = dataclasses.field(default_factory=dict)

    @classmethod
    def record(cls, ckpt: str, split: str, stride: int = 1, turns: tuple[int, ...] | None = None,
               root: str | Path | None = None) -> RecordedSplit:
        """Run the checkpoint's network once over every ``stride``-th scene of ``split``, and over each of
        them turned by each quarter turn of ``turns`` (None: those its configured decoding pools; (1, 2, 3):
        every turn, so that the search tries ``turns`` too) (:func:`opnet.evaluation.evaluate` with an
        :class:`Outputs` evaluator: nothing decoded). ``root``: instead of ``split``, every scene of that
        dataset with at least the run's ``data.test_min_objects`` parts (as ``data.test_root`` scores it)."""
        system, cfg = load_checkpoint(ckpt)
        if root is not None:
            OmegaConf.update(cfg, "data.test_root", str(root), force_add=True)
            split = "test"
        if turns is None:
            turns = quarters(system.parameterization.turns)[1:]
        dm = build_datamodule(cfg, system.parameterization.obj, train=False)
        dm.setup("test")
        recorder = Outputs(system, turns)
        outputs, cameras, gts = evaluate(system, every_kth(getattr(dm, f"{split}_dataloader")(), stride), [recorder])[0]
        return cls(system.parameterization, outputs, cameras, gts, system.max_occlusion, recorder.turned)

    def scenes(self, settings: dict[str, Any]) -> dict[str, tuple[GroundTruthSet, Any]]:
        """Scene name -> (ground truth, hypotheses) decoded with ``settings``."""
        param = decoder(self.parameterization, settings)
        scenes = {}
        for i, (out, cams, gt) in enumerate(zip(self.outputs, self.cameras, self.gts, strict=True)):
            turned = [(q, self.turned[q][i]) for q in quarters(param.turns)[1:]]
            for h, g in zip(param.decode(out, cams, turned=turned), gt, strict=True):
                scenes[f"s{len(scenes):06d}"] = (g, h)
        return scenes

    def ap(self, settings: dict[str, Any]) -> float:
        space = self.parameterization.obj.pose_space
        return AveragePrecision(space, self.max_occlusion).evaluate(self.scenes(settings)).ap


class Outputs(Evaluator):
    """The evaluator of :meth:`RecordedSplit.record`: keeps each batch's network output, cameras and
    ground truth, decoding nothing; its result is (outputs, cameras, ground truths), one entry a batch. With a
    ``system`` and quarter ``turns``, also the system's outputs of the batch's images turned by each (``turned``)."""

    decodes = False

    def __init__(self, system: Any = None, turns: tuple[int, ...] = ()) -> None:
        self.outputs: list[torch.Tensor] = []
        self.cameras: list[list[Any]] = []
        self.gts: list[list[GroundTruthSet]] = []
        self.system = system
        self.turned: dict[int, list[torch.Tensor]] = {q: [] for q in turns}

    def process(self, batch: Batch, output: torch.Tensor, hyps: Any) -> None:
        if self.turned:
            for q, out in self.system.turned_outputs(batch.images, self.turned):
                self.turned[q].append(out)
        self.outputs.append(output)
        self.cameras.append(list(batch.cameras))
        self.gts.append(list(batch.gt_sets))

    def evaluate(self, scenes: Any) -> tuple[list[torch.Tensor], list[list[Any]], list[list[GroundTruthSet]]]:
        return self.outputs, self.cameras, self.gts


def decoded_as_recorded(ckpt: str | Path, splits: Iterable[str]) -> tuple[dict[str, RecordedSplit], dict[str, Any],
                                                                       dict[str, dict[str, tuple[Any, Any]]]]:
    """Each split's outputs recorded once (:meth:`RecordedSplit.record`), the decoding the checkpoint records,
    and each split's scenes decoded with it: ``(recorded, settings, decoded)``, keyed by split."""
    recorded = {split: RecordedSplit.record(str(ckpt), split) for split in splits}
    settings = current_settings(next(iter(recorded.values())).parameterization)
    return recorded, settings, {split: rec.scenes(settings) for split, rec in recorded.items()}


def every_kth(batches: Iterable[Batch], stride: int) -> Iterator[Batch]:
    """The batches of a loader holding only every ``stride``-th image of the split (counted across
    batches; a batch left with none is skipped, one left whole passes as it is)."""
    seen = 0
    for batch in batches:
        keep = [j for j in range(len(batch)) if (seen + j) % stride == 0]
        seen += len(batch)
        if len(keep) == len(batch):
            yield batch
        elif keep:
            yield _rows(batch, keep)


def _rows(batch: Batch, keep: list[int]) -> Batch:
    """The images ``keep`` (ascending) of a batch, with their ground truth."""
    index = torch.tensor(keep)
    gt = batch.gt
    pick = torch.isin(gt.batch_index, index.to(gt.batch_index.device))
    sub = dataclasses.replace(
        gt, batch_index=torch.searchsorted(index.to(gt.batch_index.device), gt.batch_index[pick]),
        R_cam_obj=gt.R_cam_obj[pick], t_cam_obj=gt.t_cam_obj[pick], visibility=gt.visibility[pick],
        instance_id=gt.instance_id[pick], batch_size=len(keep),
        segmentation=None if gt.segmentation is None else gt.segmentation[index.to(gt.segmentation.device)])
    return Batch(batch.images[index.to(batch.images.device)], [batch.cameras[j] for j in keep], sub,
                 [batch.gt_sets[j] for j in keep], [batch.names[j] for j in keep])


def decoding_overrides(settings: dict[str, Any]) -> dict[str, Any]:
    """The decoding ``settings`` (keys of :data:`SEARCH`) as ``decoding=`` overrides spell them."""
    plain = {k: v for k, v in settings.items() if k not in (*AVERAGING_KEYS, "averaging")}
    plain["averaging"] = {k: v for k, v in settings.items() if k in AVERAGING_KEYS} if settings["averaging"] else False
    return plain


def decoding_arguments(settings: dict[str, Any]) -> list[str]:
    """The decoding ``settings`` (keys of :data:`SEARCH`) as eval.py's and predict.py's ``+decoding.*`` arguments."""
    args = []
    for key, value in decoding_overrides(settings).items():
        if isinstance(value, dict):
            args += [f"+decoding.{key}.{k}={v}" for k, v in value.items()]
        else:
            args.append(f"+decoding.{key}={str(value).lower() if isinstance(value, bool) else value}")
    return args


def decoder(param: Parameterization, settings: dict[str, Any]) -> Parameterization:
    """The parameterization with the decoding ``settings`` (keys of :data:`SEARCH`)."""
    return param.with_decoding(**decoding_overrides(settings))


def current_settings(param: Parameterization) -> dict[str, Any]:
    """The configured decoding (averaging settings at their defaults where averaging is off)."""
    averaging = param.averaging or PoseAveraging(param.obj.pose_space)
    return {"averaging": param.averaging is not None, "score": param.score, "min_visibility": param.min_visibility,
            "eps": averaging.eps, "min_samples": averaging.min_samples, "cluster_score": averaging.cluster_score,
            "turns": param.turns}


def search(splits: list[RecordedSplit], rounds: int = 2,
           verbose: bool = True) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """Coordinate-wise search from the configured settings, ``rounds`` >= 1; returns (best settings, every row);
    ``verbose``: each setting tried printed as it is scored.

    Raises:
        ValueError: ``rounds`` < 1 (nothing would be tuned).
    """
    if rounds < 1:
        raise ValueError(f"--rounds {rounds}: expected a whole number >= 1 (0 rounds tune nothing)")
    best = current_settings(splits[0].parameterization)
    recorded = set.intersection(*(set(s.turned) for s in splits))  # the quarter turns every split has outputs of
    keys = [k for k in SEARCH if k in best and (k != "turns" or recorded == {1, 2, 3})]
    rows: list[dict[str, Any]] = []
    seen: dict[tuple[Any, ...], float] = {}

    def score(settings: dict[str, Any]) -> float:
        key = tuple(settings[k] for k in keys)
        if key not in seen:
            aps = [s.ap(settings) for s in splits]
            seen[key] = sum(aps) / len(aps)
            rows.append({**settings, "ap": seen[key], **{f"ap_{i}": a for i, a in enumerate(aps)}})
            if verbose:
                print("  " + "  ".join(f"{k}={settings[k]}" for k in keys) + f"  ->  AP {seen[key]:.4f}", flush=True)
        return seen[key]

    default_ap = score(best)
    quality = splits[0].parameterization.has_quality
    for _, key in itertools.product(range(rounds), keys):
        candidates = [{**best, key: value} for value in SEARCH[key]
                      if quality or not (key == "score" and value in QUALITY_SCORES)]
        best = max(candidates, key=score)
    rows[0]["default"] = True
    if verbose:
        print(f"configured: AP {default_ap:.4f};  best: AP {score(best):.4f}  {best}")
    return best, rows


#: the saved config's keys (conf/decoding/tuned.yaml) of each setting of :data:`SEARCH`
CONFIG_KEYS = {"averaging": "averaging", "score": "score", "min_visibility": "min_visibility", "eps": "averaging_eps",
               "min_samples": "averaging_min_samples", "cluster_score": "averaging_score", "turns": "turns"}


def write_tuned_checkpoint(src: str | Path, dest: Path, settings: dict[str, Any]) -> None:
    """A copy of checkpoint ``src`` whose saved config (and settings entry, :mod:`opnet.run_settings`,
    where it has one) decodes with ``settings``, written atomically to ``dest`` and read back: its
    parameterization must decode as tuned.

    Raises:
        ValueError: ``dest`` is ``src`` or cannot be written, or the copy does not load with the tuned decoding.
    """
    from opnet.cli.build import read_checkpoint

    if Path(src).resolve() == dest.resolve():
        raise ValueError(f"--write {dest}: is the checkpoint being tuned; write a new file")
    ckpt = read_checkpoint(src)
    param = ckpt["hyper_parameters"]["config"]["parameterization"]
    for key, value in settings.items():
        param[CONFIG_KEYS[key]] = value
    if CHECKPOINT_KEY in ckpt:  # the settings the checkpoint is read with
        saved = RunSettings.from_dict(ckpt[CHECKPOINT_KEY], f"{src}: the checkpoint's {CHECKPOINT_KEY}")
        tuned = saved.decoding.with_overrides(decoding_overrides(settings))
        ckpt[CHECKPOINT_KEY] = saved.with_decoding(tuned).to_dict()
    save_checkpoint(ckpt, dest)
    system, _ = load_checkpoint(dest)
    loaded = current_settings(system.parameterization)
    compared = [k for k in settings if settings["averaging"] or k not in AVERAGING_KEYS]  # unused without averaging
    if any(loaded[k] != settings[k] for k in compared):
        dest.unlink()
        raise ValueError(f"{dest}: the written checkpoint does not decode with the tuned settings {settings}")


#: the file beside the sweep that records what a recipe's tuning after training chose (:func:`tune_in_place`)
TUNED_RECORD = "tuned.json"


@torch.no_grad()
def tune_in_place(ckpt: str | Path, stride: int, out: Path) -> dict[str, Any]:
    """What a recipe with ``tune_decoding`` does after training: the decoding of ``ckpt`` searched on every
    ``stride``-th scene of its validation split (the turns its decoding pools recorded), and written into ``ckpt``
    itself (atomically, the weights untouched) where it scores a higher validation AP than the configured one.

    Writes the sweep (:func:`write_table`) and :data:`TUNED_RECORD` (the configured and the chosen decoding with
    their validation AP; ``changed``: the settings written, empty where the configured one stayed) to ``out``.
    Returns that record.
    """
    ckpt = Path(ckpt)
    split = RecordedSplit.record(str(ckpt), "val", stride)
    configured = current_settings(split.parameterization)
    record: dict[str, Any] = {"checkpoint": ckpt.name, "stride": stride, "configured": configured,
                              "scenes": sum(len(g) for g in split.gts), "changed": {}}
    if record["scenes"]:
        best, rows = search([split], verbose=False)
        write_table(rows, out)
        chosen_ap, configured_ap = max(r["ap"] for r in rows), rows[0]["ap"]
        record.update(ap_configured=configured_ap, chosen=best, ap_chosen=chosen_ap)
        if chosen_ap > configured_ap:
            record["changed"] = {k: v for k, v in best.items() if configured[k] != v}
            scratch = ckpt.with_name(ckpt.name + ".tuning")
            try:
                write_tuned_checkpoint(ckpt, scratch, best)
                os.replace(scratch, ckpt)
            finally:
                scratch.unlink(missing_ok=True)
    with write_errors_named(out / TUNED_RECORD):
        write_text_atomic(out / TUNED_RECORD, json.dumps(record, indent=2) + "\n")
    return record


def tuned_line(record: dict[str, Any]) -> str:
    """One line for the console of what :func:`tune_in_place` did."""
    if not record["scenes"]:
        return "decoding      : kept as configured (no validation scenes to tune it on)"
    if not record["changed"]:
        return f"decoding      : kept as configured (validation AP {record['ap_configured']:.3f}, the best of the search)"
    changed = ", ".join(f"{k} {v}" for k, v in record["changed"].items())
    return (f"decoding      : tuned on validation ({record['scenes']} scenes): {changed}; "
            f"validation AP {record['ap_configured']:.3f} -> {record['ap_chosen']:.3f}")


def write_table(rows: list[dict[str, Any]], out: Path) -> None:
    """``decoding_sweep.csv`` and ``decoding_sweep.md`` of the search's ``rows`` in ``out``, each atomically."""
    fields = sorted({k for r in rows for k in r}, key=lambda k: (k.startswith("ap"), k))
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=fields)
    writer.writeheader()
    writer.writerows(rows)
    with write_errors_named(out / "decoding_sweep.csv"):
        write_text_atomic(out / "decoding_sweep.csv", buf.getvalue())
    ranked = sorted(rows, key=lambda r: -r["ap"])
    lines = ["| " + " | ".join(fields) + " |", "|" + "---|" * len(fields)]
    lines += ["| " + " | ".join(f"{r.get(k, '')}" if not isinstance(r.get(k), float) else f"{r[k]:.4f}"
                                for k in fields) + " |" for r in ranked]  # fmt: skip
    with write_errors_named(out / "decoding_sweep.md"):
        write_text_atomic(out / "decoding_sweep.md", "\n".join(lines) + "\n")
