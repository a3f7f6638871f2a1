"""The orientation quality channel: the loss teaches q̂ how right each cell's orientation is, the decoding scores
with it, train.py and the decoding's tuning carry it, and a network without one refuses the scores that read it."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from opnet.cli.build import load_checkpoint
from opnet.losses import MultiTaskLoss, occupied_cells, quality_error, quality_target
from opnet.objects.library import builtin_object
from opnet.parameterizations.eve import EVEParameterization
from opnet.parameterizations.rotation import SixDCodec
from opnet.settings_schema import SettingError


def _eve(quality: bool, **kwargs) -> EVEParameterization:
    obj = builtin_object("zbracket")
    return EVEParameterization(obj, grid=8, rotation=SixDCodec(obj.symmetry), quality=quality, **kwargs)


def test_the_layout_gains_one_channel_q_after_the_rotation() -> None:
    plain, with_q = _eve(False), _eve(True)
    assert with_q.out_channels == plain.out_channels + 1
    assert with_q.channel_layout() == [*plain.channel_layout(), "q"]
    assert with_q.has_quality and not plain.has_quality


def test_the_quality_target_is_one_for_the_truth_and_a_half_at_delta() -> None:
    """q* = 2^-(d/δ)², d the Brégier rotation distance ||(R̂ - R) Λ||_F (computed here from its definition)."""
    import numpy as np

    param = _eve(True)
    codec, space = param.rotation, param.obj.pose_space
    Lambda = np.asarray(space.Lambda)

    def turn(a: float) -> np.ndarray:
        return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])

    def distance(a: float) -> float:
        return float(np.linalg.norm((turn(a) - np.eye(3)) @ Lambda))

    lo, hi = 0.0, 0.5  # the turn whose distance is δ, by bisection
    for _ in range(60):
        lo, hi = ((lo + hi) / 2, hi) if distance((lo + hi) / 2) < space.delta else (lo, (lo + hi) / 2)
    angles = [0.0, lo, 0.5 * lo]
    R = torch.as_tensor(np.stack([turn(a) for a in angles]))
    truth = torch.eye(3, dtype=torch.float64).expand(len(angles), 3, 3)
    q = quality_target(codec.encode(R), codec.encode(truth), param)
    expected = [2 ** -((distance(a) / space.delta) ** 2) for a in angles]
    assert expected[0] == 1.0 and expected[1] == pytest.approx(0.5, abs=1e-6)
    assert q.tolist() == pytest.approx(expected, abs=1e-5)


def test_the_loss_trains_q_toward_its_target_and_leaves_the_orientation_alone() -> None:
    """Only the quality channel receives the quality term's gradient; a network without the channel has no term."""
    param = _eve(True)
    S, C = param.grid_size, param.channels_per_slot
    target = torch.zeros(1, C, S, S)
    lay = param.layout
    target[0, lay.presence, 2, 3] = 1.0
    target[0, lay.visibility, 2, 3] = 0.8
    target[0, lay.rotation, 2, 3] = param.rotation.encode(torch.eye(3, dtype=torch.float64)[None])[0].float()
    output = target.clone()
    output[0, lay.quality, 2, 3] = 0.2  # the orientation exact: q* = 1, error 0.64
    losses = MultiTaskLoss(orientation="sym_channel_l2", lambda_quality=2.0)(output, target, param)
    assert losses["quality"].item() == pytest.approx(2.0 * 0.64, rel=1e-5)
    output[0, lay.rotation.start + 4, 2, 3] += 0.1  # the x column turned: q* < 1, and it would move with it
    output.requires_grad_(True)
    losses = MultiTaskLoss(orientation="sym_channel_l2", lambda_quality=2.0)(output, target, param)
    losses["quality"].backward()
    grad = output.grad[0, :, 2, 3]
    assert grad[lay.quality] < 0 and torch.count_nonzero(grad) == 1
    _, o, t = occupied_cells(param.split_slots(output.detach()), param.split_slots(target), lay)
    assert quality_error(o, t, param).shape == (1,)
    assert "quality" not in MultiTaskLoss()(target[:, :-1], target[:, :-1], _eve(False))


def test_an_encoded_target_decodes_to_the_truth_with_full_quality() -> None:
    """The target's q is that of an exact orientation (1): decoding a target scored p*q gives the truth, scored 1."""
    from opnet.parameterizations.batch import GroundTruthBatch
    from opnet.geometry.camera import Camera

    param = _eve(True, score="p*q", averaging=False)
    R = torch.eye(3, dtype=torch.float64)[None]
    gt = GroundTruthBatch(batch_index=torch.zeros(1, dtype=torch.long), R_cam_obj=R,
                          t_cam_obj=torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64),
                          visibility=torch.ones(1, dtype=torch.float64), instance_id=torch.ones(1, dtype=torch.long),
                          batch_size=1)
    camera = Camera(100.0, 100.0, 63.5, 63.5, 128, 128, 0.5, 1.5)
    target = param.encode(gt, camera)
    assert (param.split_slots(target)[:, :, param.layout.quality] == param.split_slots(target)[:, :, 0]).all()
    hyps = param.decode(target, [camera])[0]
    assert len(hyps) >= 1 and torch.allclose(torch.as_tensor(hyps.score), torch.ones(len(hyps), dtype=torch.float64))
    assert abs(hyps.t[:, 2] - 1.0).max() < 1e-3


def test_scores_read_the_quality_channel_and_a_network_without_one_refuses_them() -> None:
    param = _eve(True, score="p*q")
    feat = torch.zeros(2, param.channels_per_slot)
    feat[:, param.layout.presence] = torch.tensor([0.9, 0.8])
    feat[:, param.layout.visibility] = torch.tensor([0.5, 1.0])
    feat[:, param.layout.quality] = torch.tensor([0.1, 0.9])
    score, _ = param.hypothesis_scores(feat)
    assert torch.allclose(score, torch.tensor([0.09, 0.72]))
    score, _ = param.with_decoding(score="p*v*q").hypothesis_scores(feat)
    assert torch.allclose(score, torch.tensor([0.045, 0.72]))
    with pytest.raises(SettingError, match=r"parameterization.score='p\*q': reads the quality channel q"):
        _eve(False, score="p*q")
    with pytest.raises(SettingError, match=r"decoding.score='p\*v\*q'"):
        _eve(False).with_decoding(score="p*v*q")


def test_train_py_trains_a_quality_channel_and_the_tuning_searches_its_scores(tiny_dataset: Path,
                                                                            tmp_path: Path) -> None:
    from opnet.cli import train as train_cli
    from opnet.cli.decoding_search import RecordedSplit, search

    from conftest import tiny_train_cfg

    out = tmp_path / "run"
    result = train_cli.run(tiny_train_cfg(tiny_dataset, out, [
        "parameterization=eve", "parameterization.quality=true", "parameterization.score=p*q",
        "trainer.precision=32"]))
    system, _ = load_checkpoint(result["checkpoint"])
    assert system.parameterization.has_quality and system.parameterization.score == "p*q"
    split = RecordedSplit.record(result["checkpoint"], "val")
    _, rows = search([split], rounds=1, verbose=False)
    assert {"p*q", "p*v*q"} <= {r["score"] for r in rows}
