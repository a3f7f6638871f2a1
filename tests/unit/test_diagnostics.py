"""Error diagnostics: each miss reason, duplicates and false positives, error percentiles."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from opnet.geometry import axis_angle_rotation, quaternion_to_matrix
from opnet.metrics.diagnostics import diagnose, orientation_misses, rotation_errors_deg
from opnet.metrics.records import GroundTruthSet, HypothesisSet
from opnet.objects import builtin_object


def scene(seed: int = 0):
    obj = builtin_object("bracket")
    rng = np.random.default_rng(seed)
    R = quaternion_to_matrix(torch.randn(6, 4, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)).numpy()
    t = rng.uniform(-0.3, 0.3, (6, 3)) + [0, 0, 1]
    # instance 5 is 90 % occluded: it need not be found
    return obj, GroundTruthSet(R, t, np.array([0, 0, 0, 0, 0, 0.9]))


def test_every_miss_reason_duplicates_and_false_positives():
    obj, gt = scene()
    d = obj.delta
    R, t = gt.R.copy(), gt.t.copy()
    t[1, 0] += 2 * d  # instance 1: position off by 2 delta
    R[2] = R[2] @ axis_angle_rotation("X", torch.tensor(1.0, dtype=torch.float64)).numpy()  # 2: rotated
    keep = [0, 1, 2, 4]  # 3: no hypothesis at all
    hyps = HypothesisSet(
        np.concatenate([R[keep], gt.R[4:5], gt.R[0:1]]),
        np.concatenate([t[keep], gt.t[4:5] + 0.3 * d, gt.t[0:1] + [1.0, 0, 0]]),  # duplicate of 4, far FP
        np.array([0.9, 0.8, 0.7, 0.6, 0.55, 0.3]),
    )
    diag = diagnose({"s": (gt, hyps)}, obj.pose_space, obj.diameter)
    assert (diag.to_find, diag.matched) == (5, 2)
    assert (diag.no_hypothesis, diag.position, diag.orientation, diag.conflict) == (1, 1, 1, 0)
    assert (diag.hypotheses, diag.duplicates, diag.false_positives) == (6, 1, 3)
    assert (diag.confident_duplicates, diag.confident_false_positives) == (1, 2)  # score >= 0.5
    assert diag.t_err_mm_p50 == pytest.approx(0.0, abs=1e-9) and diag.r_err_deg_p50 < 1e-5
    assert "2 of 5 instances found" in diag.table()


def test_conflict_and_error_percentiles():
    obj, gt = scene(1)
    # two instances half a delta apart, one hypothesis 0.2 delta from the first: it is the nearest
    # hypothesis of both, but it can only be matched to its own nearest instance
    R = np.stack([gt.R[0], gt.R[0]])
    gt = GroundTruthSet(R, np.array([[0, 0, 1.0], [0.5 * obj.delta, 0, 1.0]]), np.zeros(2))
    hyps = HypothesisSet(R[:1], gt.t[:1] + [0.2 * obj.delta, 0, 0], np.array([0.9]))
    diag = diagnose({"s": (gt, hyps)}, obj.pose_space, obj.diameter)
    assert diag.matched == 1 and diag.conflict == 1
    assert diag.t_err_mm_p50 == pytest.approx(200 * obj.delta, rel=1e-9)  # 0.2 delta, in mm


def test_rotation_errors_are_symmetry_aware():
    shaft, zbracket = builtin_object("shaft"), builtin_object("zbracket")
    R = quaternion_to_matrix(torch.randn(5, 4, generator=torch.Generator().manual_seed(2), dtype=torch.float64)).numpy()
    spin = axis_angle_rotation("Z", torch.tensor(1.2, dtype=torch.float64)).numpy()
    half = axis_angle_rotation("Z", torch.tensor(np.pi, dtype=torch.float64)).numpy()
    tilt = axis_angle_rotation("X", torch.tensor(np.radians(10.0), dtype=torch.float64)).numpy()
    np.testing.assert_allclose(rotation_errors_deg(R @ spin, R, shaft.pose_space), 0, atol=1e-6)
    np.testing.assert_allclose(rotation_errors_deg(R @ half, R, zbracket.pose_space), 0, atol=1e-6)
    np.testing.assert_allclose(rotation_errors_deg(R @ tilt, R, zbracket.pose_space), 10.0, rtol=1e-9)
    np.testing.assert_allclose(rotation_errors_deg(R @ tilt, R, shaft.pose_space), 10.0, rtol=1e-9)


def test_empty_scenes():
    obj, gt = scene()
    empty = HypothesisSet.empty()
    diag = diagnose({"a": (gt, empty), "b": (GroundTruthSet(np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0)),
                                              HypothesisSet(gt.R[:2], gt.t[:2], np.array([0.9, 0.1])))},
                    obj.pose_space, obj.diameter)  # fmt: skip
    assert diag.no_hypothesis == 5 and diag.false_positives == 2 and diag.confident_false_positives == 1
    assert np.isnan(diag.t_err_mm_p50)


def _turned(obj_name: str, turns: list[tuple[int, str, float]], n: int = 40, seed: int = 3):
    """A scene of ``n`` far-apart instances and one hypothesis each at its origin, the first ones
    turned in the part's frame: ``(count, axis, radians)`` in order."""
    obj = builtin_object(obj_name)
    R = quaternion_to_matrix(torch.randn(n, 4, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)).numpy()
    t = np.stack([np.arange(n) * 2 * obj.diameter, np.zeros(n), np.ones(n)], 1)
    R_hat, i = R.copy(), 0
    for count, axis, angle in turns:
        R_hat[i:i + count] = R[i:i + count] @ axis_angle_rotation(axis, torch.tensor(angle, dtype=torch.float64)).numpy()
        i += count
    pair = (GroundTruthSet(R, t, np.zeros(n)), HypothesisSet(R_hat, t.copy(), np.linspace(1, 0.5, n)))
    return obj, orientation_misses({"s": pair}, obj.pose_space, obj.diameter)


def test_orientation_misses_find_a_face_confusion_and_tell_it_from_imprecision():
    _, m = _turned("bracket", [(24, "X", np.pi), (8, "Y", 0.6), (1, "Z", 0.01)])  # the last one is matched
    assert m.count == 32
    assert m.histogram == (0, 8, 0, 0, 0, 24) and m.turned_over == pytest.approx(0.75)
    half, tilt = m.modes[:2]
    assert (half.share, tilt.share) == (pytest.approx(0.75), pytest.approx(0.25))
    np.testing.assert_allclose(half.axis, [1, 0, 0], atol=1e-6)
    assert half.angle_deg == pytest.approx(180, abs=1e-6) and half.tilt_deg == pytest.approx(90)
    np.testing.assert_allclose(tilt.axis, [0, 1, 0], atol=1e-6)
    assert tilt.angle_deg == pytest.approx(np.degrees(0.6))
    assert "75% a 180° turn about (+1.00, +0.00, +0.00), 90° from the part's z" in m.table()


def test_many_orientation_misses_are_clustered_from_an_even_subsample(monkeypatch: pytest.MonkeyPatch) -> None:
    import opnet.metrics.diagnostics as diagnostics

    monkeypatch.setattr(diagnostics, "MAX_CLUSTERED", 12)  # 32 misses: the clusters of 12 of them
    _, m = _turned("bracket", [(24, "X", np.pi), (8, "Y", 0.6)])
    assert m.count == 32 and m.histogram == (0, 8, 0, 0, 0, 24)  # every miss in the histogram
    assert [round(mode.angle_deg) for mode in m.modes] == [180, 34] and m.modes[0].share == pytest.approx(0.75)


def test_orientation_misses_are_turns_beyond_the_parts_symmetry():
    # zbracket: a half turn about z is a symmetry, so it is no miss; the same plus 40° about x is one of 40°
    _, m = _turned("zbracket", [(10, "Z", np.pi), (10, "X", np.radians(40))])
    assert m.count == 10 and m.histogram[1] == 10 and m.modes[0].share == 1.0
    # a revolution part: any spin is free; an axis turned end over end is a 180° turn about an axis across it
    _, m = _turned("shaft", [(12, "Z", 2.0), (6, "X", np.pi), (3, "Y", np.radians(45))])
    assert m.count == 9 and m.histogram == (0, 3, 0, 0, 0, 6)
    assert m.modes[0].angle_deg == pytest.approx(180) and m.modes[0].tilt_deg == pytest.approx(90)
    empty = orientation_misses({}, builtin_object("shaft").pose_space, 0.1)
    assert (empty.count, empty.modes, empty.table()) == (0, (), "Orientation misses: none")
