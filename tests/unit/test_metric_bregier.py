"""Brégier evaluator: the official regression target, a literal per-threshold reference on many
random scenes, and hand-made scenes whose curves are known."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from opnet.datasets.sileane_json import read_scene_pairs
from opnet.geometry import PoseSpace, quaternion_to_matrix
from opnet.geometry.symmetry import dihedral_group
from opnet.metrics import (
    GroundTruthSet,
    HypothesisSet,
    NonMonotoneRecallWarning,
    evaluate_scene,
    evaluate_scenes,
    instances_to_find,
    pose_distances,
    scene_curve_from_distances,
)
from opnet.metrics.bregier import pose_distances_per_scene
from opnet.objects import ObjectModel

# the official tool's output on ../shared/data/sileane_bunny_sample (docs/method.md#evaluation)
GOLDEN_PER_SCENE = {
    "bunny_3_070": 0.7647, "bunny_3_071": 0.9286, "bunny_3_072": 0.8333, "bunny_3_073": 0.7647,
    "bunny_3_074": 0.7500, "bunny_3_075": 0.8462, "bunny_3_076": 0.8125, "bunny_3_077": 0.7647,
    "bunny_3_078": 0.7222, "bunny_3_079": 0.7692, "bunny_3_080": 0.8235,
}

# simple spaces: translation-only scenes (identity rotations) have distance |t1 - t2|
LINE = PoseSpace(np.diag([0.02, 0.03, 0.04]), np.eye(3)[None], delta=1.0)
SPACES = {
    "none": PoseSpace(np.diag([0.02, 0.03, 0.05]), np.eye(3)[None], delta=0.05),
    "dihedral3": PoseSpace(np.diag([0.03, 0.03, 0.05]), dihedral_group(3), delta=0.05),
    "revolution_flip": PoseSpace(np.diag([0.01, 0.01, 0.05]), np.stack((np.eye(3), np.diag([1.0, -1, -1]))),
                                 delta=0.05, revolution=True, lam=0.051),
}


# ---- the literal reference of docs/method.md#matching-and-scores ------------------------------
def reference_scene_curve(D: np.ndarray, score: np.ndarray, to_find: np.ndarray, delta: float, k: int = -1):
    """Loop over thresholds, re-matching from scratch each time, exactly as the pseudo-code reads."""
    M, N = D.shape
    find = set(np.flatnonzero(to_find).tolist())
    ngt = [int(np.argmin(D[i])) for i in range(M)] if N else []
    precision, recall = [], []
    for s in [math.inf, *sorted(set(score.tolist()), reverse=True)]:
        P = [i for i in range(M) if score[i] >= s]
        if k > 0:
            P = sorted(P, key=lambda i: -score[i])[:k]
        tp = fp = 0
        found: set[int] = set()
        if P and N == 0:
            fp = len(P)
        elif P:
            nhyp = {j: min(P, key=lambda i: D[i, j]) for j in range(N)}
            for i in P:
                j = ngt[i]
                if D[i, j] > delta or nhyp[j] != i:
                    fp += 1
                elif j in find:
                    tp += 1
                    found.add(j)
        fn = len(find) - len(found)
        wanted = min(k, tp + fn) if k > 0 else tp + fn
        precision.append(tp / (tp + fp) if tp + fp else 1.0)
        recall.append(tp / wanted if wanted else 1.0)
    return np.array(precision), np.array(recall)


def reference_mean_curve(curves):
    """The official averaging: at every threshold of the union, each scene's last point >= it."""
    union = sorted({t for c in curves for t in c.thresholds.tolist()}, reverse=True)
    P, R = [], []
    for s in union:
        idx = [int(np.flatnonzero(c.thresholds >= s)[-1]) for c in curves]
        P.append(np.mean([c.precision[i] for c, i in zip(curves, idx)]))
        R.append(np.mean([c.recall[i] for c, i in zip(curves, idx)]))
    return np.array(union), np.array(P), np.array(R)


def pairwise_distances(space: PoseSpace, hyps: HypothesisSet, gt: GroundTruthSet) -> np.ndarray:
    """(M, N) via the element-wise PoseSpace.distance (not the cdist path the evaluator uses)."""
    if len(hyps) == 0 or len(gt) == 0:
        return np.zeros((len(hyps), len(gt)))
    R1, t1, R2, t2 = (torch.from_numpy(a) for a in (hyps.R[:, None], hyps.t[:, None], gt.R[None], gt.t[None]))
    return space.distance(R1, t1, R2, t2).numpy()


def random_rotations(rng: np.random.Generator, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    return quaternion_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))


def random_scene(rng: np.random.Generator, delta: float) -> tuple[GroundTruthSet, HypothesisSet]:
    """Few instances close together, hypotheses near them (in and out of δ), exact duplicates,
    false positives, scores from a small set (ties), occlusion rates around the 0.5 boundary."""
    n, m = int(rng.integers(0, 7)), int(rng.integers(0, 10))
    R = random_rotations(rng, n)
    t = rng.uniform(-1.5 * delta, 1.5 * delta, (n, 3))
    gt = GroundTruthSet(R, t, rng.choice([0.0, 0.3, 0.5, 0.7, 1.0], n))
    kind = rng.integers(0, 3, m) if n else np.full(m, 2)
    src = rng.integers(0, max(n, 1), m)
    hR, ht = random_rotations(rng, m), rng.uniform(-1.5 * delta, 1.5 * delta, (m, 3))
    for i in range(m):
        if kind[i] < 2:  # near an instance, noise within or beyond delta
            hR[i], ht[i] = R[src[i]], t[src[i]] + rng.normal(0, 0.4 * delta * (1 + 2 * kind[i]), 3)
        if i and rng.random() < 0.2:  # exact duplicate of the previous hypothesis
            hR[i], ht[i] = hR[i - 1], ht[i - 1]
    return gt, HypothesisSet(hR, ht, rng.integers(0, 4, m).astype(float))


# ---- golden ---------------------------------------------------------------------------------------
@pytest.mark.shared
def test_official_bunny_sample(bunny_sample: Path) -> None:
    space = ObjectModel.from_poseutils(bunny_sample / "poseutils.json").pose_space
    summary = evaluate_scenes(read_scene_pairs(bunny_sample / "gt", bunny_sample / "results"), space)
    assert round(summary.ap, 6) == 0.797872
    assert round(summary.map, 6) == 0.798151
    assert round(summary.f1, 6) == 0.882159
    assert round(summary.recall_at_p50, 4) == 0.7982
    assert {k: round(v, 4) for k, v in summary.per_scene.items()} == GOLDEN_PER_SCENE
    d = summary.to_dict()
    assert set(d) >= {"ap", "map", "f1", "recall_at_p50", "recall_at_p99", "per_scene"}
    assert d["scenes"]["bunny_3_070"]["to_find"] == 17 and "bunny_3_080" in summary.table()


# ---- vectorized == literal reference ----------------------------------------------------------------
@pytest.mark.parametrize("space_name", sorted(SPACES))
def test_matches_literal_reference_on_random_scenes(space_name: str) -> None:
    space = SPACES[space_name]
    rng = np.random.default_rng(len(space_name))
    scenes = {f"s{i}": random_scene(rng, space.delta) for i in range(150)}
    for k in (-1, 3):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", NonMonotoneRecallWarning)
            summary = evaluate_scenes(scenes, space, max_nb_results=k)
        curves = []
        for gt, hyps in scenes.values():
            D = pairwise_distances(space, hyps, gt)
            p_ref, r_ref = reference_scene_curve(D, hyps.score, instances_to_find(gt), space.delta, k)
            curve = evaluate_scene(gt, hyps, space, max_nb_results=k)
            np.testing.assert_array_equal(curve.precision, p_ref)
            np.testing.assert_array_equal(curve.recall, r_ref)
            curves.append(curve)
        t_ref, p_ref, r_ref = reference_mean_curve(curves)
        np.testing.assert_array_equal(summary.thresholds, t_ref)
        np.testing.assert_allclose(summary.precision, p_ref, atol=1e-12)
        np.testing.assert_allclose(summary.recall, r_ref, atol=1e-12)
        assert summary.map == pytest.approx(np.mean([c.ap for c in curves]), abs=1e-12)


@pytest.mark.parametrize("space_name", sorted(SPACES))
def test_batched_distances_equal_distance_matrix(space_name: str) -> None:
    space = SPACES[space_name]
    rng = np.random.default_rng(3)
    pairs = [random_scene(rng, space.delta)[::-1] for _ in range(40)]
    batched = pose_distances_per_scene(pairs, space, budget=500)  # several chunks
    for (hyps, gt), D in zip(pairs, batched):
        np.testing.assert_allclose(D, pose_distances(hyps, gt, space), atol=1e-9)


# ---- hand-made scenes ---------------------------------------------------------------------------------
def line_gt(x: list[float], occlusion: list[float] | None = None) -> GroundTruthSet:
    t = np.zeros((len(x), 3))
    t[:, 0] = x
    return GroundTruthSet(np.tile(np.eye(3), (len(x), 1, 1)), t, occlusion or [0.0] * len(x))


def line_hyps(x: list[float], score: list[float]) -> HypothesisSet:
    t = np.zeros((len(x), 3))
    t[:, 0] = x
    return HypothesisSet(np.tile(np.eye(3), (len(x), 1, 1)), t, score)


def test_duplicate_is_a_false_positive() -> None:
    c = evaluate_scene(line_gt([0.0]), line_hyps([0.1, 0.2], [2.0, 1.0]), LINE)
    assert c.thresholds.tolist() == [math.inf, 2.0, 1.0]
    assert c.precision.tolist() == [1.0, 1.0, 0.5] and c.recall.tolist() == [0.0, 1.0, 1.0]
    assert c.tp.tolist() == [0, 1, 1] and c.fp.tolist() == [0, 0, 1] and c.ap == 1.0


def test_a_later_closer_duplicate_takes_over() -> None:
    """The match is recomputed per threshold: the better-placed, lower-scored hypothesis becomes
    the true positive, the first one the duplicate."""
    c = evaluate_scene(line_gt([0.0]), line_hyps([0.5, 0.1], [2.0, 1.0]), LINE)
    assert c.tp.tolist() == [0, 1, 1] and c.fp.tolist() == [0, 0, 1]


def test_stolen_match_lowers_recall_and_warns() -> None:
    """h1 is nearest to instance B (occluded, ignored) but closer to A than h0 is: h0 becomes a
    duplicate and the true positive on A is lost (docs/method.md#matching-and-scores)."""
    scene = (line_gt([0.0, 0.8], [0.0, 0.9]), line_hyps([-0.5, 0.45], [2.0, 1.0]))
    c = evaluate_scene(*scene, LINE)
    assert c.recall.tolist() == [0.0, 1.0, 0.0] and c.precision.tolist() == [1.0, 1.0, 0.0]
    assert c.ap == 1.0  # the negative step is integrated: 1 * (1 - 0) + 0 * (0 - 1)
    with pytest.warns(NonMonotoneRecallWarning, match="1 scene curve"):
        assert evaluate_scenes({"s": scene}, LINE).ap == 1.0


def test_match_on_an_occluded_instance_is_ignored() -> None:
    c = evaluate_scene(line_gt([0.0, 5.0], [0.0, 0.51]), line_hyps([0.1, 5.1, 9.0], [3.0, 2.0, 1.0]), LINE)
    assert c.tp.tolist() == [0, 1, 1, 1] and c.fp.tolist() == [0, 0, 0, 1]
    assert c.num_to_find == 1 and c.recall.tolist() == [0.0, 1.0, 1.0, 1.0]


def test_occlusion_bounds_are_inclusive() -> None:
    gt = line_gt([0.0, 1.0, 2.0, 3.0], [-0.1, 0.5, 0.5000001, 1.0])
    assert instances_to_find(gt).tolist() == [True, True, False, False]
    assert instances_to_find(gt, max_occlusion=1.0, min_occlusion=0.0).tolist() == [False, True, True, True]


def test_far_hypothesis_is_a_false_positive_even_if_nearest() -> None:
    c = evaluate_scene(line_gt([0.0]), line_hyps([1.001, 0.999], [2.0, 1.0]), LINE)
    assert c.tp.tolist() == [0, 0, 1] and c.fp.tolist() == [0, 1, 1]
    exactly_delta = scene_curve_from_distances(np.array([[1.0]]), np.array([1.0]), np.array([True]), delta=1.0)
    assert exactly_delta.tp.tolist() == [0, 1]  # d <= delta is correct


def test_equal_scores_enter_together() -> None:
    c = evaluate_scene(line_gt([0.0, 5.0]), line_hyps([0.0, 5.0, 9.0], [1.0, 1.0, 0.5]), LINE)
    assert c.thresholds.tolist() == [math.inf, 1.0, 0.5]
    assert c.recall.tolist() == [0.0, 1.0, 1.0] and c.precision.tolist() == [1.0, 1.0, 2 / 3]


def test_no_hypotheses_and_no_ground_truth() -> None:
    c = evaluate_scene(line_gt([0.0, 1.0]), HypothesisSet.empty(), LINE)
    assert c.thresholds.tolist() == [math.inf] and c.recall.tolist() == [0.0] and c.ap == 0.0
    c = evaluate_scene(line_gt([]), line_hyps([0.0], [1.0]), LINE)  # nothing to find: recall 1
    assert c.precision.tolist() == [1.0, 0.0] and c.recall.tolist() == [1.0, 1.0] and c.ap == 1.0
    c = evaluate_scene(line_gt([0.0], [1.0]), HypothesisSet.empty(), LINE)
    assert c.recall.tolist() == [1.0] and c.ap == 1.0


def test_max_nb_results_caps_positives_and_recall() -> None:
    gt, hyps = line_gt([0.0, 5.0, 10.0]), line_hyps([0.0, 5.0, 10.0], [3.0, 2.0, 1.0])
    c = evaluate_scene(gt, hyps, LINE, max_nb_results=2)
    assert c.tp.tolist() == [0, 1, 2, 2] and c.recall.tolist() == [0.0, 0.5, 1.0, 1.0]
    with pytest.raises(ValueError, match="max_nb_results"):
        evaluate_scene(gt, hyps, LINE, max_nb_results=0)


def test_mean_curve_averages_at_union_thresholds() -> None:
    a = (line_gt([0.0]), line_hyps([0.0], [2.0]))  # r: 0 -> 1 at 2
    b = (line_gt([0.0, 5.0]), line_hyps([0.0, 9.0], [3.0, 1.0]))  # r: 0 -> .5 at 3; p 1 -> .5 at 1
    s = evaluate_scenes({"a": a, "b": b}, LINE)
    assert s.thresholds.tolist() == [math.inf, 3.0, 2.0, 1.0]
    np.testing.assert_allclose(s.recall, [0.0, 0.25, 0.75, 0.75])
    np.testing.assert_allclose(s.precision, [1.0, 1.0, 1.0, 0.75])
    assert s.ap == pytest.approx(0.75) and s.map == pytest.approx(0.75)
    assert s.per_scene == {"a": 1.0, "b": 0.5}


def test_invalid_input() -> None:
    with pytest.raises(ValueError, match="'score' contains NaN"):
        evaluate_scene(line_gt([0.0]), line_hyps([0.0], [math.nan]), LINE)
    with pytest.raises(ValueError, match="no scenes"):
        evaluate_scenes({}, LINE)
    with pytest.raises(ValueError, match="shape"):
        scene_curve_from_distances(np.zeros((2, 3)), np.zeros(2), np.zeros(2, bool), 1.0)
