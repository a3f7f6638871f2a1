"""The spin study's two measurements (scripts/experiments/flat_parts/): what the depth shows of a part's spin,
and the AP a network that reads only that can reach."""

from __future__ import annotations

import importlib.util
import math

import numpy as np
import pytest
import trimesh

from opnet.geometry.pose_numpy import rodrigues
from opnet.metrics.bregier import evaluate_scenes
from opnet.metrics.breakdown import axis_angle
from opnet.metrics.records import GroundTruthSet, HypothesisSet
from opnet.objects import ObjectModel
from opnet.paths import REPO_ROOT


def script(name: str):
    path = REPO_ROOT / "scripts" / "experiments" / "flat_parts" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)  # type: ignore[union-attr]
    return module


def rim(spoke: bool, symmetry: dict) -> ObjectModel:
    """A rim (a body of revolution about z), with one spoke across its middle if ``spoke``: seen end-on the spoke
    shows the spin, seen side-on the rim hides it."""
    parts = [trimesh.creation.annulus(r_min=0.020, r_max=0.025, height=0.015, sections=64)]
    if spoke:
        parts.append(trimesh.creation.box(extents=(0.041, 0.006, 0.006)))
    return ObjectModel.from_mesh("rim", trimesh.util.concatenate(parts), symmetry)


def test_a_spin_shows_in_the_depth_only_where_a_feature_turns_in_view() -> None:
    observe = script("spin_observability")
    wheel = observe.observability(rim(True, {"kind": "cyclic", "order": 2}), [0, 90], [36], pixels=45, change=0.03)
    (end_on, part_end, (changed_end,)), (side_on, part_side, (changed_side,)) = wheel
    assert (end_on, side_on) == (0, 90) and part_end > 500 and part_side > 300
    assert changed_end > 40  # the spoke turned in the open ring: its pixels and those it uncovers
    assert changed_side <= 2  # the spoke inside the rim, the rim a body of revolution: nothing to see
    # a body of revolution shows no spin: only the pixels its facets' outline flips (a 64-gon ring: about 1 %)
    plain = observe.observability(rim(False, {"kind": "revolution"}), [0, 45], [36], pixels=45, change=0.03)
    for _, part, (changed,) in plain:
        assert changed <= 0.02 * part and 5 * changed < changed_end


def scenes_of(obj: ObjectModel, n: int, seed: int) -> dict[str, GroundTruthSet]:
    """Two scenes of ``n`` parts each, in front of the camera, their axes at spread angles to the line of sight."""
    rng = np.random.default_rng(seed)
    out = {}
    for k in range(2):
        t = np.c_[rng.uniform(-0.2, 0.2, (n, 2)), rng.uniform(0.8, 1.0, n)]
        axes = rng.normal(size=(n, 3))
        R = rodrigues(axes / np.linalg.norm(axes, axis=1, keepdims=True), rng.uniform(0, math.pi, n))
        out[f"s{k}"] = GroundTruthSet(R, t, np.zeros(n))
    return out


def test_the_ceiling_spins_only_the_parts_seen_past_the_cutoff_and_scores_them_by_the_metric() -> None:
    ceiling = script("spin_ceiling")
    obj = rim(True, {"kind": "cyclic", "order": 5})
    scenes = scenes_of(obj, 40, seed=0)
    axis = np.array([0.0, 0.0, 1.0])
    gt = scenes["s0"]
    angles = axis_angle(gt.R, gt.t, axis)
    find = np.ones(len(gt), bool)
    h = ceiling.ceiling_hypotheses(gt, angles, 45.0, axis, find, np.random.default_rng(1))
    blind = angles > 45.0
    assert 0 < blind.sum() < len(gt)
    np.testing.assert_allclose(h.t, gt.t)  # positions exact
    np.testing.assert_allclose(h.R @ axis, gt.R @ axis, atol=1e-12)  # every axis exact
    np.testing.assert_allclose(h.R[~blind], gt.R[~blind], atol=1e-12)  # spins exact where seen
    assert not np.allclose(h.R[blind], gt.R[blind])  # and turned where not
    assert set(h.score[blind]) == {0.5} and set(h.score[~blind]) == {1.0}  # ranked after the seen ones
    rows = dict((c, (share, mean)) for c, share, mean, _ in ceiling.ceilings(scenes, obj, [0.0, 45.0, 90.0], 5, 0.5))
    assert rows[90.0] == (1.0, pytest.approx(1.0))  # every spin seen: a perfect network scores 1
    assert rows[0.0][0] == 0.0 and 0.05 < rows[0.0][1] < 0.7  # none seen: the random spins' chance under cyclic 5
    assert rows[0.0][1] < rows[45.0][1] < 1.0
    # a body of revolution has no spin to miss: the same random turns score 1
    revolution = rim(False, {"kind": "revolution"})
    assert ceiling.ceilings(scenes, revolution, [0.0], 3, 0.5)[0][2] == pytest.approx(1.0)
    # the evaluator the ceiling uses agrees with scoring the truth itself
    assert evaluate_scenes({k: (g, ceiling.ceiling_hypotheses(g, axis_angle(g.R, g.t, axis), 90.0, axis,
                                                               np.ones(len(g), bool), np.random.default_rng(0)))
                            for k, g in scenes.items()}, obj.pose_space).ap == pytest.approx(1.0)  # fmt: skip


def test_the_spin_hedge_copies_only_poses_seen_side_on_turned_about_their_own_axis() -> None:
    hedge = script("spin_hedge")
    obj = rim(True, {"kind": "cyclic", "order": 5})
    axis = np.array([0.0, 0.0, 1.0])
    gt = scenes_of(obj, 40, seed=2)["s0"]
    half = rodrigues(axis[None], np.array([math.pi / 5]))[0]  # 36°: half the turn between symmetric equivalents
    wrong = HypothesisSet(gt.R @ half, gt.t, np.linspace(1.0, 0.5, len(gt)))  # every spin as far off as it gets
    side_on = axis_angle(gt.R, gt.t, axis) > 45.0
    out = hedge.hedged(wrong, axis, 72.0, 45.0, 2, 0.3)
    n = int(side_on.sum())
    assert 0 < n < len(gt) and len(out) == len(gt) + n
    np.testing.assert_array_equal(out.R[: len(gt)], wrong.R)  # the poses themselves untouched
    np.testing.assert_allclose(out.t[len(gt):], gt.t[side_on])  # the copies: where the side-on poses stand,
    np.testing.assert_allclose(out.R[len(gt):] @ axis, gt.R[side_on] @ axis, atol=1e-12)  # their axes,
    np.testing.assert_allclose(out.score[len(gt):], 0.3 * wrong.score[side_on])  # scored lower,
    np.testing.assert_allclose(out.R[len(gt):], gt.R[side_on] @ half @ half, atol=1e-12)  # turned by 36° more
    # a turn of 72° is the part's own symmetry: each copy finds its part, the poses find none
    scored = {"s": (gt, wrong)}
    assert evaluate_scenes(scored, obj.pose_space).ap == 0.0
    assert hedge.found_share({"s": (gt, out)}, obj.pose_space, obj.diameter, 1.0) == pytest.approx(n / len(gt))
    # ... but ranked after every pose: found at a precision of at most n / (N + n), which bounds the AP gained
    ap = evaluate_scenes({"s": (gt, out)}, obj.pose_space).ap
    assert 0.0 < ap < n / len(gt) * n / (len(gt) + n)
    assert hedge.hedged(wrong, axis, 72.0, 45.0, 1, 0.3) is wrong  # one copy: nothing added
    # only the best-scored pose of a place is copied where asked
    two = HypothesisSet(gt.R[[0, 0, 1]], gt.t[[0, 0, 1]], np.array([0.5, 0.9, 0.2]))
    np.testing.assert_array_equal(hedge.best_at_place(two, 0.01), [False, True, True])
