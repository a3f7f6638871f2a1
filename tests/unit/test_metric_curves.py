"""Scalar summaries of PR curves (docs/method.md#matching-and-scores), on hand-computed curves."""

from __future__ import annotations

import numpy as np
import pytest

from opnet.metrics import average_precision, best_f1, mean_curve, recall_at_precision, recall_is_monotone

INF = np.inf


def test_average_precision_is_the_non_interpolated_step_integral() -> None:
    p, r = [1.0, 1.0, 0.5, 0.6], [0.0, 0.5, 0.5, 0.9]
    assert average_precision(p, r) == pytest.approx(1.0 * 0.5 + 0.5 * 0.0 + 0.6 * 0.4)
    assert average_precision([1.0], [1.0]) == 1.0  # nothing to find: recall 1 from the start
    assert average_precision([], []) == 0.0


def test_non_monotone_recall_is_integrated_as_is() -> None:
    p, r = [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]
    assert not recall_is_monotone(r) and recall_is_monotone([0.0, 0.5, 0.5 - 1e-13])
    assert average_precision(p, r) == 1.0


def test_best_f1() -> None:
    assert best_f1([1.0, 0.8, 0.5], [0.0, 0.6, 1.0]) == pytest.approx(2 * 0.8 * 0.6 / 1.4)
    assert best_f1([1.0, 0.0], [0.0, 0.0]) == 0.0  # p + r = 0 counts as 0, not NaN


@pytest.mark.parametrize(
    ("p", "r", "level", "expected"),
    [
        ([1.0, 0.9, 0.4, 0.3], [0.0, 0.6, 0.7, 0.8], 0.5, 0.6),  # last point before the drop
        ([1.0, 0.9, 0.8], [0.0, 0.5, 0.9], 0.5, 0.9),  # never drops: the final recall
        ([1.0, 0.4, 0.9, 0.3], [0.0, 0.2, 0.7, 0.8], 0.5, 0.7),  # climbs back: largest run end
        ([1.0, 0.4, 0.6], [0.0, 0.3, 0.8], 0.5, 0.8),  # final run after a drop counts too
        ([1.0, 0.98], [0.0, 0.9], 0.99, 0.0),
        ([1.0, 0.99 - 1e-15], [0.0, 0.9], 0.99, 0.9),  # summation noise does not flip the test
    ],
)
def test_recall_at_precision(p: list[float], r: list[float], level: float, expected: float) -> None:
    assert recall_at_precision(p, r, level) == pytest.approx(expected)


def test_mean_curve_union_and_last_point_at_or_above() -> None:
    t, p, r = mean_curve(
        [np.array([INF, 5.0, 1.0]), np.array([INF, 3.0])],
        [np.array([1.0, 1.0, 0.5]), np.array([1.0, 0.0])],
        [np.array([0.0, 0.5, 0.5]), np.array([1.0, 1.0])],
    )
    assert t.tolist() == [INF, 5.0, 3.0, 1.0]
    np.testing.assert_allclose(p, [1.0, 1.0, 0.5, 0.25])
    np.testing.assert_allclose(r, [0.5, 0.75, 0.75, 0.75])


def test_mean_curve_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="positive number of curves"):
        mean_curve([], [], [])
    with pytest.raises(ValueError, match=r"\+inf"):
        mean_curve([np.array([2.0])], [np.array([1.0])], [np.array([0.0])])
