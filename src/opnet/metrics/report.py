"""The result of an evaluation: headline metrics, mean curve, per-scene figures; printing and JSON.

A scene with nothing to find has recall 1 at every threshold, as in the official tool (recall is
1 when there is nothing to find); a split made only of such scenes has AP, MAP and F1 of 1.0 whatever
its false positives. The numbers are kept for fidelity, and every report says it: the count of scenes
with nothing to find and of their false positives (``to_dict``), and a note in place of a score
(:func:`nothing_to_find_note`).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from opnet.metrics.curves import recall_is_monotone

_COUNT_KEYS = ("gt", "to_find", "hypotheses", "tp", "fp", "ignored")


class NonMonotoneRecallWarning(UserWarning):
    """Recall decreases along a precision-recall curve; AP integrates the steps anyway.

    This happens with mutual-nearest-neighbour matching: a new hypothesis can become the nearest
    of an instance while its own nearest instance is another one, so a true positive is lost
    (docs/method.md#matching-and-scores). The official tool stops with an assertion there.
    """


@dataclass(frozen=True)
class EvaluationSummary:
    """Metrics of a set of scenes of one object (docs/method.md#matching-and-scores).

    Attributes:
        ap: average precision of the scene-averaged curve (the headline "AP").
        map: mean over scenes of the per-scene AP (a different number).
        f1: best F1 score of the mean curve.
        recall_at_p50, recall_at_p99: recall where the mean precision still is >= 0.5 / 0.99.
        per_scene: scene name -> AP of its own curve.
        precision, recall: (U,) float64 the mean curve, one point per threshold.
        thresholds: (U,) float64 descending score thresholds, starting at +inf.
        scene_counts: scene name -> {"gt", "to_find", "hypotheses", "tp", "fp", "ignored"}
            (tp / fp / ignored with every hypothesis in, i.e. at the lowest threshold).
        max_occlusion: instances with a larger occlusion rate need not be found.
        delta: metres, distance threshold of a correct pose.
    """

    ap: float
    map: float
    f1: float
    recall_at_p50: float
    recall_at_p99: float
    per_scene: dict[str, float]
    precision: np.ndarray = field(repr=False)
    recall: np.ndarray = field(repr=False)
    thresholds: np.ndarray = field(repr=False)
    scene_counts: dict[str, dict[str, Any]] = field(default_factory=dict, repr=False)
    max_occlusion: float = 0.5
    delta: float = float("nan")

    @property
    def num_scenes(self) -> int:
        return len(self.per_scene)

    @property
    def to_find(self) -> int:
        """Instances to find over every scene (0 when no scene counts are known)."""
        return sum(int(c.get("to_find", 0)) for c in self.scene_counts.values())

    @property
    def scenes_nothing_to_find(self) -> int:
        """Scenes whose ground truth holds no instance to find (their recall is 1 by convention)."""
        return sum(1 for c in self.scene_counts.values() if c.get("to_find") == 0)

    @property
    def false_positives_nothing_to_find(self) -> int:
        """False positives of the scenes with nothing to find (every hypothesis in)."""
        return sum(int(c.get("fp", 0)) for c in self.scene_counts.values() if c.get("to_find") == 0)

    def to_dict(self, curve: bool = False) -> dict[str, Any]:
        """JSON-ready summary; ``curve=True`` adds the mean curve (the +inf threshold as null)."""
        out: dict[str, Any] = {
            "ap": self.ap,
            "map": self.map,
            "f1": self.f1,
            "recall_at_p50": self.recall_at_p50,
            "recall_at_p99": self.recall_at_p99,
            "num_scenes": self.num_scenes,
            "to_find": self.to_find,
            "scenes_nothing_to_find": self.scenes_nothing_to_find,
            "false_positives_nothing_to_find": self.false_positives_nothing_to_find,
            "max_occlusion": self.max_occlusion,
            "delta": None if math.isnan(self.delta) else self.delta,
            "per_scene": dict(self.per_scene),
            "scenes": {n: {"ap": ap, **self.scene_counts.get(n, {})} for n, ap in self.per_scene.items()},
        }
        if curve:
            out["curve"] = {
                "thresholds": [None if math.isinf(t) else float(t) for t in self.thresholds],
                "precision": self.precision.tolist(),
                "recall": self.recall.tolist(),
            }
        return out

    def table(self, per_scene: bool = True) -> str:
        """Human-readable report: the headline metrics, then one line per scene."""
        lines = [
            f"Brégier evaluation: {self.num_scenes} scenes, max occlusion {self.max_occlusion:g}, "
            f"delta {self.delta:.6g} m",
            f"  AP     {self.ap:.6f}   (area under the scene-averaged PR curve)",
            f"  MAP    {self.map:.6f}   (mean of per-scene APs)",
            f"  F1     {self.f1:.6f}",
            f"  R@P50  {self.recall_at_p50:.6f}",
            f"  R@P99  {self.recall_at_p99:.6f}",
        ]
        note = nothing_to_find_note(self.num_scenes, self.scenes_nothing_to_find,
                                    self.false_positives_nothing_to_find, self.ap)
        if note is not None and self.scenes_nothing_to_find >= self.num_scenes:  # no score at all: the note instead
            lines[1:] = [f"  {note}", "  AP, MAP, F1, R@P50, R@P99: 1 by convention (recall is 1 where nothing is to be "
                                      "found), not scores"]  # fmt: skip
        elif note is not None:
            lines.insert(1, f"  {note}")
        if per_scene and self.per_scene:
            width = max(12, *(len(n) for n in self.per_scene))
            header = "  ".join(f"{h:>4}" for h in ("gt", "find", "hyps", "tp", "fp", "ign"))
            lines.append(f"  {'scene':<{width}}  {'AP':>6}  {header}")
            for name, ap in self.per_scene.items():
                c = self.scene_counts.get(name, {})
                counts = "  ".join(f"{c.get(k, ''):>4}" for k in _COUNT_KEYS)
                lines.append(f"  {name:<{width}}  {ap:6.4f}  {counts}")
            lines.append("  (find: instances to find; tp / fp / ign: hypotheses with every score in)")
        return "\n".join(lines)


def nothing_to_find_note(scenes: int, empty: int, false_positives: int, ap: float) -> str | None:
    """What an AP over scenes with nothing to find is: for a split of only such scenes, a convention
    and not a score; for some of them, how many and their false positives. None when every scene
    has something to find.

    Args:
        scenes: scenes evaluated; empty: of those, with nothing to find; false_positives: theirs.
        ap: the AP reported for the split.
    """
    if empty <= 0:
        return None
    if empty >= scenes:
        return (f"nothing to find in this split: AP is reported as {ap:.1f} by convention, "
                f"{false_positives} false positives")
    return (f"{empty} of {scenes} scenes had nothing to find (recall 1 there by convention), "
            f"{false_positives} false positives in them")


def warn_non_monotone(scene_recalls: Mapping[str, np.ndarray], mean_recall: np.ndarray) -> None:
    """Issue one :class:`NonMonotoneRecallWarning` naming the curves whose recall decreases."""
    bad = [name for name, r in scene_recalls.items() if not recall_is_monotone(r)]
    if not bad and recall_is_monotone(mean_recall):
        return
    shown = ", ".join(bad[:5]) + (f", ... ({len(bad) - 5} more)" if len(bad) > 5 else "")
    where = f"{len(bad)} scene curve(s) ({shown})" if bad else "the mean curve"
    warnings.warn(
        f"recall decreases along {where}: mutual-nearest-neighbour matching lost a true positive as "
        "the threshold dropped; AP integrates the negative steps as they are",
        NonMonotoneRecallWarning,
        stacklevel=3,
    )
