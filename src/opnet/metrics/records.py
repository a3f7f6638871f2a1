"""What the evaluator consumes: per-scene ground truth and pose hypotheses (any common frame)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class GroundTruthSet:
    """Ground-truth instances of one scene.

    Attributes:
        R: (N, 3, 3) float64 object rotations (object -> camera or world frame).
        t: (N, 3) float64 metres, same frame as R.
        occlusion_rate: (N,) float64 in [0, 1]; 1 - visibility.
        segmentation_id: (N,) int64 instance ids (as in the segmentation image).
    """

    R: np.ndarray
    t: np.ndarray
    occlusion_rate: np.ndarray
    segmentation_id: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))

    def __post_init__(self) -> None:
        self.R = np.asarray(self.R, dtype=np.float64).reshape(-1, 3, 3)
        self.t = np.asarray(self.t, dtype=np.float64).reshape(-1, 3)
        self.occlusion_rate = np.asarray(self.occlusion_rate, dtype=np.float64).reshape(-1)
        if len(self.segmentation_id) == 0 and len(self.t) > 0:
            self.segmentation_id = np.arange(1, len(self.t) + 1, dtype=np.int64)
        self.segmentation_id = np.asarray(self.segmentation_id, dtype=np.int64).reshape(-1)
        n = len(self.t)
        if not (len(self.R) == len(self.occlusion_rate) == len(self.segmentation_id) == n):
            raise ValueError(
                f"ground truth arrays disagree in length: R {len(self.R)}, t {n}, "
                f"occlusion_rate {len(self.occlusion_rate)}, segmentation_id {len(self.segmentation_id)}"
            )

    def __len__(self) -> int:
        return len(self.t)


@dataclass
class HypothesisSet:
    """Pose hypotheses of one scene; a higher score means more confidence.

    Attributes:
        R: (N, 3, 3) float64. t: (N, 3) float64 metres. score: (N,) float64.
        visibility: optional (N,) predicted visibility.
    """

    R: np.ndarray
    t: np.ndarray
    score: np.ndarray
    visibility: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.R = np.asarray(self.R, dtype=np.float64).reshape(-1, 3, 3)
        self.t = np.asarray(self.t, dtype=np.float64).reshape(-1, 3)
        self.score = np.asarray(self.score, dtype=np.float64).reshape(-1)
        if not (len(self.R) == len(self.t) == len(self.score)):
            raise ValueError(
                f"hypothesis arrays disagree in length: R {len(self.R)}, t {len(self.t)}, score {len(self.score)}"
            )
        if self.visibility is not None:
            self.visibility = np.asarray(self.visibility, dtype=np.float64).reshape(-1)

    def __len__(self) -> int:
        return len(self.t)

    def above(self, min_score: float) -> HypothesisSet:
        """The hypotheses whose score is at least ``min_score``."""
        return self.take(self.score >= min_score)

    def best(self, k: int) -> HypothesisSet:
        """The ``k`` best-scored hypotheses (ties in input order), as the evaluation's ``max_nb_results``
        keeps them; all of them for k < 0."""
        if k < 0 or k >= len(self):
            return self
        return self.take(np.sort(np.argsort(-self.score, kind="stable")[:k]))

    def take(self, keep: np.ndarray) -> HypothesisSet:
        """The hypotheses a boolean mask or index array selects, in their order."""
        vis = None if self.visibility is None else self.visibility[keep]
        return HypothesisSet(self.R[keep], self.t[keep], self.score[keep], vis)

    @classmethod
    def empty(cls) -> HypothesisSet:
        return cls(np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0))
