"""Brégier et al. evaluation: pure functions (per-scene matching, mean curve, AP) and a
torchmetrics wrapper (docs/method.md#evaluation).

``PoseAP`` (the torchmetrics ``Metric``) is imported on first use: torchmetrics is slow to import
and the command-line evaluator does not need it.
"""

from __future__ import annotations

from opnet._lazy import lazy_exports

# names are imported on first use (PEP 562): the records load without PyTorch (opnet.deploy)
_WHERE = {
    "SceneCurve": "bregier", "evaluate_scene": "bregier", "evaluate_scenes": "bregier",
    "instances_to_find": "bregier", "pose_distances": "bregier", "scene_curve_from_distances": "bregier",
    "summarize": "bregier", "average_precision": "curves", "best_f1": "curves", "mean_curve": "curves",
    "recall_at_precision": "curves", "recall_is_monotone": "curves", "GroundTruthSet": "records",
    "HypothesisSet": "records", "EvaluationSummary": "report", "NonMonotoneRecallWarning": "report",
    "PoseAP": "torchmetric",
}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _WHERE)
