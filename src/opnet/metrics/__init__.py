"""Brégier et al. evaluation: pure functions (per-scene matching, mean curve, AP) and a
torchmetrics wrapper (metric_and_formats.md §2).

``PoseAP`` (the torchmetrics ``Metric``) is imported on first use: torchmetrics is slow to import
and the command-line evaluator does not need it.
"""

from typing import Any

from opnet.metrics.bregier import (
    SceneCurve,
    evaluate_scene,
    evaluate_scenes,
    instances_to_find,
    pose_distances,
    scene_curve_from_distances,
    summarize,
)
from opnet.metrics.curves import (
    average_precision,
    best_f1,
    mean_curve,
    recall_at_precision,
    recall_is_monotone,
)
from opnet.metrics.records import GroundTruthSet, HypothesisSet
from opnet.metrics.report import EvaluationSummary, NonMonotoneRecallWarning

__all__ = [
    "EvaluationSummary",
    "GroundTruthSet",
    "HypothesisSet",
    "NonMonotoneRecallWarning",
    "PoseAP",
    "SceneCurve",
    "average_precision",
    "best_f1",
    "evaluate_scene",
    "evaluate_scenes",
    "instances_to_find",
    "mean_curve",
    "pose_distances",
    "recall_at_precision",
    "recall_is_monotone",
    "scene_curve_from_distances",
    "summarize",
]


def __getattr__(name: str) -> Any:
    if name == "PoseAP":
        from opnet.metrics.torchmetric import PoseAP

        return PoseAP
    raise AttributeError(f"module 'opnet.metrics' has no attribute {name!r}")
