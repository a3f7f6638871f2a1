"""The multi-task loss: zero on perfect outputs, the paper's weights, gradients, symmetry."""

from __future__ import annotations

import math
from pathlib import Path

import hydra.utils
import pytest
import torch
from omegaconf import OmegaConf

from opnet.geometry import Camera, axis_angle_rotation, quaternion_to_matrix
from opnet.losses import MultiTaskLoss, symmetric_rotation_error
from opnet.objects import builtin_object
from opnet.parameterizations import GroundTruthBatch, SIParameterization, VanillaParameterization
from opnet.parameterizations.toy_scenes import random_scene_batch
from opnet.paths import config_dir

CAMERA = Camera.from_fov(60.0, 128, 128, 0.5, 1.5)
PARAM_CONFIGS = sorted((config_dir() / "parameterization").glob("*.yaml"))
LOSS_CONFIGS = sorted((config_dir() / "loss").glob("*.yaml"))
TERMS = ("presence", "visibility", "position", "orientation")
ZBRACKET = builtin_object("zbracket")
SHAFT = builtin_object("shaft")


def setup(config: Path, obj, seed: int = 0):
    param = hydra.utils.instantiate(OmegaConf.load(config), obj=obj)
    gt = random_scene_batch(obj, CAMERA, 2, 20, torch.Generator().manual_seed(seed))
    return param, param.encode(gt, CAMERA)


def noisy(target: torch.Tensor, seed: int = 1) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return (
        (target + 0.05 * torch.randn(target.shape, generator=gen)).clamp(0, 1).requires_grad_(True)
    )


@pytest.mark.parametrize("loss_config", LOSS_CONFIGS, ids=lambda p: p.stem)
@pytest.mark.parametrize("config", PARAM_CONFIGS, ids=lambda p: p.stem)
def test_zero_on_perfect_output_positive_otherwise_with_gradients(config: Path, loss_config: Path):
    loss_fn = hydra.utils.instantiate(OmegaConf.load(loss_config))
    for obj in (ZBRACKET, SHAFT):
        param, target = setup(config, obj)
        perfect = loss_fn(target.clone(), target, param)
        assert set(perfect) == {*TERMS, "total"}
        for name, value in perfect.items():
            assert value.item() == pytest.approx(0.0, abs=1e-9), name
        output = noisy(target)
        losses = loss_fn(output, target, param)
        assert losses["total"].item() == pytest.approx(
            sum(losses[t].item() for t in TERMS), rel=1e-6
        )
        for name in TERMS:
            assert losses[name].item() > 0, name
            (grad,) = torch.autograd.grad(losses[name], output, retain_graph=True)
            assert torch.isfinite(grad).all() and grad.abs().sum() > 0, name


def test_paper_weighting_on_a_single_cell():
    param = VanillaParameterization(ZBRACKET)
    vis = 0.7
    gt = GroundTruthBatch.from_arrays(
        [(torch.eye(3)[None], torch.tensor([[0.0, 0.0, 1.0]]), [vis], [1], None)] * 2
    )
    target = param.encode(gt, CAMERA)
    output = target.clone()
    grid = param.split_slots(output)
    grid[:, 0, 1, 8, 8] += 0.1  # visibility error 0.1 in the object cell
    grid[:, 0, 2, 8, 8] += 0.2  # x error
    grid[:, 0, 6, 8, 8] += 0.3  # φ2 error
    grid[:, 0, 0, 0, 0] = 0.5  # false presence in an empty cell
    grid[:, 0, 3, 0, 0] = 0.9  # position in an empty cell: not penalized
    losses = MultiTaskLoss()(output, target, param)
    assert (
        param.split_slots(target)[0, 0, 0, 8, 8] == 1
    )  # the principal point lies on the corner of cell (8, 8)
    assert losses["presence"].item() == pytest.approx(0.1 * 0.25, rel=1e-5)
    assert losses["visibility"].item() == pytest.approx(0.25 * 0.01, rel=1e-4)
    assert losses["position"].item() == pytest.approx(8 * vis**3 * 0.04, rel=1e-4)
    assert losses["orientation"].item() == pytest.approx(8 * vis**3 * 0.09, rel=1e-4)
    lam = MultiTaskLoss(lambda_p=1.0, lambda_v=0.0, lambda_ori=2.0)(output, target, param)
    assert lam["presence"].item() == pytest.approx(0.25, rel=1e-5) and lam["visibility"].item() == 0
    assert lam["orientation"].item() == pytest.approx(2 * 8 * vis**3 * 0.09, rel=1e-4)


def test_si_uses_linear_pose_weight():
    param = SIParameterization(ZBRACKET)
    v = torch.tensor([0.0, 0.5, 1.0])
    torch.testing.assert_close(param.pose_weight(v), v)
    torch.testing.assert_close(VanillaParameterization(ZBRACKET).pose_weight(v), 8 * v**3)


def test_sym_rotation_is_zero_for_symmetric_equivalents_and_grows_with_error():
    gen = torch.Generator().manual_seed(3)
    R = quaternion_to_matrix(torch.randn(10, 4, generator=gen, dtype=torch.float64))
    half_turn = axis_angle_rotation("Z", torch.tensor(math.pi, dtype=torch.float64))
    cyclic = VanillaParameterization(ZBRACKET)
    assert symmetric_rotation_error(R @ half_turn, R, cyclic).abs().max() < 1e-20
    small = R @ axis_angle_rotation("X", torch.tensor(0.01, dtype=torch.float64))
    large = R @ axis_angle_rotation("X", torch.tensor(0.1, dtype=torch.float64))
    e_small, e_large = (
        symmetric_rotation_error(small, R, cyclic),
        symmetric_rotation_error(large, R, cyclic),
    )
    assert (e_small > 0).all() and (e_large > 50 * e_small).all()
    revolution = VanillaParameterization(SHAFT)
    spin = axis_angle_rotation("Z", torch.rand(10, generator=gen, dtype=torch.float64) * 6)
    assert symmetric_rotation_error(R @ spin, R, revolution).abs().max() < 1e-20
    lam = SHAFT.pose_space.lam
    tilt = symmetric_rotation_error(large, R, revolution)
    expected = (
        lam**2 * (2 * math.sin(0.05)) ** 2 / SHAFT.delta**2
    )  # chord of a 0.1 rad tilt of the axis
    torch.testing.assert_close(tilt, torch.full_like(tilt, expected))


def test_loss_rejects_mismatched_shapes():
    param = VanillaParameterization(ZBRACKET)
    with pytest.raises(ValueError, match="shape"):
        MultiTaskLoss()(torch.zeros(1, 8, 16, 16), torch.zeros(1, 8, 8, 8), param)
    with pytest.raises(ValueError, match="orientation"):
        MultiTaskLoss(orientation="quaternion")
