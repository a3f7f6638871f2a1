"""opnet.evaluation.evaluate: the one loop over a split, its evaluators in order, decoding only when one needs it."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import torch

from opnet.evaluation import Evaluator, OnScenes, evaluate


class StubSystem:
    """infer doubles the images; decode names each image's hypotheses by its first pixel."""

    device = torch.device("cpu")

    def __init__(self) -> None:
        self.decoded = 0
        self.training = True

    def eval(self) -> None:
        self.training = False

    def infer(self, images: torch.Tensor) -> torch.Tensor:
        return 2 * images

    def decode(self, output: torch.Tensor, cameras: Any, images: torch.Tensor | None = None) -> list[str]:
        self.decoded += 1
        return [f"h{float(o.flatten()[0]):g}" for o in output]


def batch(values: list[float], names: list[str]) -> Any:
    images = torch.tensor(values).reshape(-1, 1, 1, 1)
    return SimpleNamespace(images=images, cameras=[None] * len(values), gt_sets=[f"g{v:g}" for v in values],
                           names=names, to=lambda device: batch(values, names))


class Outputs(Evaluator):
    decodes = False

    def __init__(self) -> None:
        self.seen: list[torch.Tensor] = []

    def process(self, batch: Any, output: torch.Tensor, hyps: Any) -> None:
        assert hyps is None
        self.seen.append(output)

    def evaluate(self, scenes: Any) -> list[torch.Tensor]:
        return self.seen


def test_evaluators_see_the_scenes_in_order_and_a_refinement_in_place() -> None:
    system = StubSystem()
    loader = [batch([1.0, 2.0], ["a", "b"]), batch([3.0], ["c"])]

    def refine(scenes: dict) -> str:
        for name, (gt, h) in scenes.items():
            scenes[name] = (gt, h + "*")
        return "refined"

    results = evaluate(system, loader, [OnScenes(dict), OnScenes(refine), OnScenes(dict), OnScenes(len)])
    assert not system.training and system.decoded == 2
    assert results[0] == {"a": ("g1", "h2"), "b": ("g2", "h4"), "c": ("g3", "h6")}
    assert results[1] == "refined" and results[2]["c"] == ("g3", "h6*") and results[3] == 3


def test_nothing_is_decoded_when_no_evaluator_decodes() -> None:
    system = StubSystem()
    outputs, _ = evaluate(system, [batch([1.0, 2.0], ["a", "b"])], [Outputs(), Outputs()])
    assert system.decoded == 0 and [o.flatten().tolist() for o in outputs] == [[2.0, 4.0]]
