"""One evaluation path: :func:`evaluate` runs a model over a split and hands its predictions to a
list of evaluators (after detectron2's ``inference_on_dataset(model, data_loader, evaluator)``).

Every caller goes through it: eval.py and train.py's test (:func:`opnet.cli.eval.evaluate_split`:
refinement, result files, AP and diagnostics), the learning curve's test scores
(:class:`opnet.callbacks.LearningCurve`), ``scripts/experiments/learning/ab_learning.py`` and ``opnet-tune-decoding``
(whose evaluator keeps the network outputs to decode them many times).

An evaluator sees every batch (:meth:`Evaluator.process`: the batch, the network output and, unless
no evaluator decodes, the hypotheses) and then the whole split (:meth:`Evaluator.evaluate`: scene
name -> (ground truth, hypotheses), camera frame); evaluators run in the order given, so one that
replaces the hypotheses in place (a refinement) is seen refined by those after it.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any

import torch

from opnet.data.sample import Batch
from opnet.geometry.distance import PoseSpace
from opnet.metrics.bregier import EvaluationSummary, evaluate_scenes
from opnet.metrics.diagnostics import ErrorDiagnostics, diagnose
from opnet.metrics.records import GroundTruthSet, HypothesisSet

Scenes = dict[str, tuple[GroundTruthSet, HypothesisSet]]


class Evaluator:
    """A consumer of a split's predictions (detectron2's ``DatasetEvaluator``).

    Attributes:
        decodes: whether it needs the hypotheses; when no evaluator does, the network outputs are
            not decoded and :meth:`evaluate` gets no scenes.
    """

    decodes = True

    def process(self, batch: Batch, output: torch.Tensor, hyps: list[HypothesisSet] | None) -> None:
        """One batch (on the model's device), its network output and its hypotheses (None: not decoded)."""

    def evaluate(self, scenes: Scenes) -> Any:
        """The result over the whole split (after the evaluators before it)."""
        return None


class AveragePrecision(Evaluator):
    """The Brégier AP of the split (:func:`opnet.metrics.bregier.evaluate_scenes`): an
    :class:`~opnet.metrics.bregier.EvaluationSummary`."""

    def __init__(self, space: PoseSpace, max_occlusion: float = 0.5) -> None:
        self.space, self.max_occlusion = space, max_occlusion

    def evaluate(self, scenes: Scenes) -> EvaluationSummary:
        return evaluate_scenes(scenes, self.space, max_occlusion=self.max_occlusion)


class Diagnostics(Evaluator):
    """Why instances are missed (:func:`opnet.metrics.diagnostics.diagnose`): an
    :class:`~opnet.metrics.diagnostics.ErrorDiagnostics`."""

    def __init__(self, space: PoseSpace, diameter: float, max_occlusion: float = 0.5) -> None:
        self.space, self.diameter, self.max_occlusion = space, diameter, max_occlusion

    def evaluate(self, scenes: Scenes) -> ErrorDiagnostics:
        return diagnose(scenes, self.space, self.diameter, max_occlusion=self.max_occlusion)


class OnScenes(Evaluator):
    """Any function of the split's scenes (result writers, a refinement that replaces the
    hypotheses in place); its return value is the result."""

    def __init__(self, fn: Callable[[Scenes], Any]) -> None:
        self.fn = fn

    def evaluate(self, scenes: Scenes) -> Any:
        return self.fn(scenes)


def scoring(system: Any) -> list[Evaluator]:
    """:class:`AveragePrecision` and :class:`Diagnostics` of a system's object at its ``max_occlusion``."""
    obj, occlusion = system.parameterization.obj, system.max_occlusion
    return [AveragePrecision(obj.pose_space, occlusion), Diagnostics(obj.pose_space, obj.diameter, occlusion)]


@torch.no_grad()
def evaluate(system: Any, batches: Iterable[Batch], evaluators: Sequence[Evaluator]) -> list[Any]:
    """Run ``system`` (an :class:`opnet.estimator.PoseEstimator`, put in eval mode) over ``batches`` (a
    split's loader) and return each evaluator's result, in order.

    Each batch goes to the system's device; the output is :meth:`~opnet.estimator.PoseEstimator.infer`'s
    (the fast path where :meth:`~opnet.estimator.PoseEstimator.configure_inference` set one) and is decoded
    with :meth:`~opnet.estimator.PoseEstimator.decode` when an evaluator ``decodes``.
    """
    system.eval()
    decodes = any(e.decodes for e in evaluators)
    scenes: Scenes = {}
    for batch in batches:
        batch = batch.to(system.device)
        output = system.infer(batch.images)
        hyps = system.decode(output, batch.cameras, batch.images) if decodes else None
        for e in evaluators:
            e.process(batch, output, hyps)
        if hyps is not None:
            for name, gt, h in zip(batch.names, batch.gt_sets, hyps):
                scenes[name] = (gt, h)
    return [e.evaluate(scenes) for e in evaluators]


def predict_scenes(system: Any, batches: Iterable[Batch]) -> Scenes:
    """Every scene of a split decoded: scene name -> (ground truth, hypotheses), camera frame
    (:func:`evaluate` with one evaluator that keeps the scenes)."""
    return evaluate(system, batches, [OnScenes(dict)])[0]


__all__ = ["AveragePrecision", "Diagnostics", "Evaluator", "OnScenes", "Scenes", "evaluate", "predict_scenes", "scoring"]
