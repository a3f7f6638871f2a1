"""``PoseAP``: the Brégier evaluation as a torchmetrics ``Metric`` for Lightning validation.

The metric only holds state (every scene's ground truth and hypotheses); ``compute()`` calls the
pure functions of :mod:`opnet.metrics.bregier`. Usage in a LightningModule::

    self.val_ap = PoseAP(object_model.pose_space)             # in __init__
    self.val_ap.update(hypotheses, ground_truths)              # validation_step, lists per scene
    self.log_dict({f"val/{k}": v for k, v in self.val_ap.compute().items()})   # on_validation_epoch_end
    self.val_ap.reset()

Distributed use: the states are list states reduced by concatenation, so torchmetrics' sync
gathers every rank's scenes (scene boundaries are kept by per-scene counts). The matching itself
runs on each process over all gathered scenes, on the CPU; it is meant for validation sets of up
to a few thousand scenes, not for per-step logging.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from torchmetrics import Metric
from torchmetrics.utilities import dim_zero_cat

from opnet.geometry.distance import PoseSpace
from opnet.metrics.bregier import evaluate_scenes
from opnet.metrics.diagnostics import ErrorDiagnostics, diagnose
from opnet.metrics.records import GroundTruthSet, HypothesisSet
from opnet.metrics.report import EvaluationSummary

_ROW = 13  # R (9, row-major), t (3), then occlusion_rate (gt) or score (hypotheses)
METRIC_KEYS = ("ap", "map", "f1", "recall_at_p50", "recall_at_p99")


class PoseAP(Metric):
    """Brégier average precision over the scenes seen since the last ``reset()``.

    Args:
        space: the object's pose space (distance and threshold δ).
        max_occlusion, min_occlusion: instances to find have an occlusion rate in this range.
        max_nb_results: keep only the k best hypotheses per scene (-1: all).
        diameter: the object's diameter in metres; when given, ``compute()`` also fills
            ``last_diagnostics`` (:func:`opnet.metrics.diagnostics.diagnose`).
    """

    is_differentiable = False
    higher_is_better = True
    full_state_update = False

    def __init__(
        self,
        space: PoseSpace,
        max_occlusion: float = 0.5,
        min_occlusion: float = -0.1,
        max_nb_results: int = -1,
        diameter: float | None = None,
        **kwargs: Any,
    ) -> None:
        super().__init__(**kwargs)
        self.space = space
        self.max_occlusion = max_occlusion
        self.min_occlusion = min_occlusion
        self.max_nb_results = max_nb_results
        self.diameter = diameter
        self.last_summary: EvaluationSummary | None = None
        self.last_diagnostics: ErrorDiagnostics | None = None
        for name in ("gt_rows", "gt_counts", "hyp_rows", "hyp_counts"):
            self.add_state(name, default=[], dist_reduce_fx="cat")

    def update(self, hyps: Sequence[HypothesisSet], gts: Sequence[GroundTruthSet]) -> None:
        """Add scenes: ``hyps[k]`` are the hypotheses of the scene whose ground truth is ``gts[k]``."""
        if len(hyps) != len(gts):
            raise ValueError(
                f"PoseAP.update: {len(hyps)} hypothesis sets for {len(gts)} ground-truth sets"
            )
        for h, g in zip(hyps, gts, strict=True):
            self.hyp_rows.append(self._rows(h.R, h.t, h.score))
            self.hyp_counts.append(torch.tensor([len(h)], dtype=torch.float64, device=self.device))
            self.gt_rows.append(self._rows(g.R, g.t, g.occlusion_rate))
            self.gt_counts.append(torch.tensor([len(g)], dtype=torch.float64, device=self.device))

    def compute(self) -> dict[str, torch.Tensor]:
        """{"ap", "map", "f1", "recall_at_p50", "recall_at_p99"}: float64 scalar tensors.

        All NaN when no scene was added.
        """
        gts, hyps = self._scenes()
        summary, diagnostics = None, None
        if gts:
            scenes = {f"scene_{i:05d}": pair for i, pair in enumerate(zip(gts, hyps, strict=True))}
            summary = evaluate_scenes(
                scenes, self.space, self.max_occlusion, self.min_occlusion, self.max_nb_results
            )
            if self.diameter is not None:
                diagnostics = diagnose(scenes, self.space, self.diameter, self.max_occlusion, self.min_occlusion)
        self.last_summary, self.last_diagnostics = summary, diagnostics
        values = {k: float("nan") if summary is None else getattr(summary, k) for k in METRIC_KEYS}
        return {k: torch.tensor(v, dtype=torch.float64, device=self.device) for k, v in values.items()}

    def pr_curve(self) -> dict[str, torch.Tensor] | None:
        """The mean PR curve of the last ``compute()`` (thresholds from +inf down), or None."""
        s = self.last_summary
        if s is None:
            return None
        return {k: torch.from_numpy(getattr(s, k).copy()) for k in ("thresholds", "precision", "recall")}

    @property
    def last_curve(self) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(precision, recall, thresholds) float64 numpy of the last ``compute()``, or None."""
        s = self.last_summary
        return None if s is None else (s.precision, s.recall, s.thresholds)

    # ---- state packing -------------------------------------------------------------------------
    def _rows(self, R: np.ndarray, t: np.ndarray, last: np.ndarray) -> torch.Tensor:
        """(N * 13,) float64: the rows [R (9), t (3), last] of N poses, flattened."""
        rows = np.concatenate((np.reshape(R, (-1, 9)), np.reshape(t, (-1, 3)), np.reshape(last, (-1, 1))), 1)
        return torch.from_numpy(rows.reshape(-1)).to(device=self.device, dtype=torch.float64)

    def _scenes(self) -> tuple[list[GroundTruthSet], list[HypothesisSet]]:
        gts = [GroundTruthSet(a[:, :9], a[:, 9:12], a[:, 12]) for a in _unpack(self.gt_rows, self.gt_counts)]
        hyps = [HypothesisSet(a[:, :9], a[:, 9:12], a[:, 12]) for a in _unpack(self.hyp_rows, self.hyp_counts)]
        return gts, hyps


def _unpack(rows: list[torch.Tensor] | torch.Tensor, counts: list[torch.Tensor] | torch.Tensor) -> list[np.ndarray]:
    """Per-scene (N_s, 13) arrays from a list state, or from its gathered concatenation."""
    if isinstance(counts, list) and not counts:
        return []
    n = dim_zero_cat(counts).reshape(-1).round().long().cpu().numpy()
    flat = dim_zero_cat(rows).reshape(-1, _ROW).double().cpu().numpy()
    return np.split(flat, np.cumsum(n)[:-1])
