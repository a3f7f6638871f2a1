"""PoseAP (torchmetrics wrapper): same numbers as the pure functions, across updates, resets and a
simulated distributed gather."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from opnet.datasets.sileane_json import read_scene_pairs
from opnet.geometry import PoseSpace
from opnet.metrics import GroundTruthSet, HypothesisSet, PoseAP, evaluate_scenes
from opnet.objects import ObjectModel

SPACE = PoseSpace(np.diag([0.02, 0.03, 0.05]), np.eye(3)[None], delta=0.05)


def scenes(n: int, seed: int = 0) -> list[tuple[GroundTruthSet, HypothesisSet]]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        k, m = int(rng.integers(0, 6)), int(rng.integers(0, 8))
        t = rng.uniform(-0.1, 0.1, (k, 3))
        gt = GroundTruthSet(np.tile(np.eye(3), (k, 1, 1)), t, rng.choice([0.0, 0.7], k))
        ht = rng.uniform(-0.1, 0.1, (m, 3))
        if k:
            ht[: m // 2] = t[rng.integers(0, k, m // 2)] + rng.normal(0, 0.01, (m // 2, 3))
        out.append((gt, HypothesisSet(np.tile(np.eye(3), (m, 1, 1)), ht, rng.random(m))))
    return out


def expected(pairs: list[tuple[GroundTruthSet, HypothesisSet]]) -> dict[str, float]:
    s = evaluate_scenes({f"s{i}": p for i, p in enumerate(pairs)}, SPACE)
    return {"ap": s.ap, "map": s.map, "f1": s.f1, "recall_at_p50": s.recall_at_p50, "recall_at_p99": s.recall_at_p99}


def test_accumulates_over_updates_and_resets() -> None:
    pairs = scenes(30)
    metric = PoseAP(SPACE)
    for start in range(0, 30, 7):
        batch = pairs[start : start + 7]
        metric.update([h for _, h in batch], [g for g, _ in batch])
    got = metric.compute()
    assert set(got) == {"ap", "map", "f1", "recall_at_p50", "recall_at_p99"}
    for key, value in expected(pairs).items():
        assert got[key].dtype == torch.float64 and float(got[key]) == pytest.approx(value, abs=1e-12)
    curve = metric.pr_curve()
    assert curve is not None and curve["precision"].shape == curve["recall"].shape == curve["thresholds"].shape
    assert float(curve["thresholds"][0]) == float("inf")
    precision, recall, thresholds = metric.last_curve  # what the LightningModule plots
    assert np.array_equal(precision, curve["precision"].numpy()) and len(thresholds) == len(recall)
    metric.reset()
    metric.update([pairs[0][1]], [pairs[0][0]])
    assert float(metric.compute()["ap"]) == pytest.approx(expected(pairs[:1])["ap"])


def test_gathered_states_keep_scene_boundaries() -> None:
    """After a distributed sync every list state is one concatenated tensor (plus the empty tensor
    torchmetrics adds for a rank without data); compute() must split the scenes back."""
    pairs = scenes(12, seed=1)
    metric = PoseAP(SPACE)
    metric.update([h for _, h in pairs], [g for g, _ in pairs])
    for name in ("gt_rows", "gt_counts", "hyp_rows", "hyp_counts"):
        setattr(metric, name, torch.cat([*getattr(metric, name), torch.tensor([], dtype=torch.float64)]))
    got = metric.compute()
    for key, value in expected(pairs).items():
        assert float(got[key]) == pytest.approx(value, abs=1e-12)


def test_bad_update_and_empty_compute() -> None:
    metric = PoseAP(SPACE)
    with pytest.raises(ValueError, match="2 hypothesis sets for 1 ground-truth"):
        metric.update([HypothesisSet.empty()] * 2, scenes(1))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # torchmetrics warns about compute() before update()
        assert torch.isnan(metric.compute()["ap"])
    assert metric.pr_curve() is None and metric.last_curve is None


@pytest.mark.shared
def test_official_bunny_sample(bunny_sample: Path) -> None:
    space = ObjectModel.from_poseutils(bunny_sample / "poseutils.json").pose_space
    pairs = list(read_scene_pairs(bunny_sample / "gt", bunny_sample / "results").values())
    metric = PoseAP(space, max_occlusion=0.5)
    metric.update([h for _, h in pairs], [g for g, _ in pairs])
    got = metric.compute()
    assert round(float(got["ap"]), 6) == 0.797872 and round(float(got["map"]), 6) == 0.798151
