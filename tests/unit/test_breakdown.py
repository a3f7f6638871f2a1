"""The error breakdown along a part's main axis: lateral, depth, tilt and spin, each on a known miss."""

from __future__ import annotations

import numpy as np
import torch

from opnet.geometry import axis_angle_rotation
from opnet.geometry.distance import PoseSpace
from opnet.metrics.breakdown import error_breakdown, main_axis, swing_twist
from opnet.metrics.records import GroundTruthSet, HypothesisSet


def turn(axis: str, deg: float) -> np.ndarray:
    return axis_angle_rotation(axis, torch.tensor(np.radians(deg), dtype=torch.float64)).numpy()


def plate() -> PoseSpace:
    """A flat part: thin along y (its normal), spreads 40 and 30 mm in its plane, no symmetry."""
    return PoseSpace(np.diag([0.04, 0.001, 0.03]), np.eye(3)[None], delta=0.012)


def test_main_axis_is_the_spread_that_stands_apart():
    assert abs(main_axis(plate())[1]) > 0.999  # a flat part's normal
    rod = PoseSpace(np.diag([0.01, 0.01, 0.08]), np.eye(3)[None], delta=0.02)
    assert abs(main_axis(rod)[2]) > 0.999  # a rod's axis
    ring = PoseSpace(np.diag([0.02, 0.02, 0.008]), np.eye(3)[None], delta=0.007)
    assert abs(main_axis(ring)[2]) > 0.999


def test_swing_twist_recomposes_and_splits_a_known_turn():
    axis = np.array([0.0, 1.0, 0.0])
    Q = turn("X", 20.0) @ turn("Y", 35.0)  # a 35 deg spin about y, then a 20 deg tilt of y about x
    swing, twist = swing_twist(Q[None], axis)
    np.testing.assert_allclose(swing[0] @ twist[0], Q, atol=1e-12)
    np.testing.assert_allclose(twist[0] @ axis, axis, atol=1e-12)  # the twist keeps the axis
    tilt = np.degrees(np.arccos(np.clip((swing[0] @ axis) @ axis, -1, 1)))
    assert abs(tilt - 20.0) < 1e-6
    np.testing.assert_allclose(twist[0], turn("Y", 35.0), atol=1e-12)


def test_each_miss_is_put_down_to_its_largest_share():
    space = plate()
    R0 = turn("Z", 10.0)
    n = 6
    R = np.repeat(R0[None], n, 0)
    t = np.array([[0.3 * k, 0.0, 1.0] for k in range(n)])
    gt = GroundTruthSet(R, t, np.zeros(n))
    R_hat, t_hat = R.copy(), t.copy()
    t_hat[1, 0] += 0.03  # lateral, 30 mm
    t_hat[2, 2] += 0.03  # depth, 30 mm
    R_hat[3] = R0 @ turn("X", 25.0)  # the normal (y) tilted by 25 deg
    R_hat[4] = R0 @ turn("Y", 40.0)  # spun 40 deg about the normal
    keep = [0, 1, 2, 3, 4]  # instance 5: no hypothesis
    hyps = HypothesisSet(R_hat[keep], t_hat[keep], np.linspace(0.9, 0.5, len(keep)))
    b = error_breakdown({"s": (gt, hyps)}, space, diameter=0.12)
    assert (b.to_find, b.matched, b.no_hypothesis) == (6, 1, 1)
    assert (b.missed_lateral, b.missed_depth, b.missed_tilt, b.missed_spin) == (1, 1, 1, 1)
    assert b.near == 5
    # one tilted and one spun of five near: p90 interpolates between 0 and the one error (np.percentile)
    assert b.tilt_deg_p50 == 0.0 and abs(b.tilt_deg_p90 - 0.6 * 25.0) < 1e-6
    assert b.spin_deg_p50 == 0.0 and abs(b.spin_deg_p90 - 0.6 * 40.0) < 1e-6
    assert abs(sum(b.shares().values()) - 1.0) < 1e-12  # every instance to find counted once


def test_the_instances_are_counted_by_how_the_camera_sees_their_main_axis():
    """The plate's normal (y) along the line of sight: end-on; tilted 45° from it: oblique; in the image plane:
    side-on; along the camera's x but 45° off the optical axis: oblique too (the line of sight, not the optical
    axis). Of the four (all to find), the side-on one is missed (spun), the others found."""
    space = plate()
    face_on = turn("X", 90.0)  # the part's y onto the camera's z
    oblique = turn("X", 45.0)
    edge_on = np.eye(3)  # y stays in the image plane
    across = turn("Z", -90.0)  # y onto the camera's x
    R = np.stack([face_on, oblique, edge_on, across])
    t = np.array([[0.0, 0.0, 1.0], [0.3, 0.0, 1.0], [-0.3, 0.0, 1.0], [1.0, 0.0, 1.0]])
    R_hat = R.copy()
    R_hat[2] = edge_on @ turn("Y", 60.0)
    b = error_breakdown({"s": (GroundTruthSet(R, t, np.zeros(4)), HypothesisSet(R_hat, t, np.ones(4)))}, space,
                        diameter=0.12)
    assert b.to_find_by_view == (1, 2, 1) and b.matched_by_view == (1, 2, 0)
    assert b.found_by_view() == {"end_on": 1.0, "oblique": 1.0, "side_on": 0.0}
    assert "end-on 100% of 1, oblique 100% of 2, side-on 0% of 1" in b.table()
