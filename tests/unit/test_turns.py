"""The decoding's ``turns``: the input turned by quarter turns is what a turned camera sees, and the hypotheses of
every turn, turned back, are the image's own poses."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from opnet.analysis.toy_scenes import random_scene_batch
from opnet.geometry.camera import Camera
from opnet.objects import builtin_object
from opnet.parameterizations import EVEParameterization, GroundTruthBatch, VanillaParameterization
from opnet.parameterizations.turns import quarters, turn_matrix, turned_back, turned_camera
from opnet.settings_schema import SettingError
from param_checks import pose_errors

#: an input camera with an off-centre principal point and unequal focal lengths: every swap shows
CAMERA = Camera(fx=140.0, fy=150.0, cx=57.3, cy=70.9, width=128, height=128, clip_start=0.5, clip_end=1.5)


def test_quarters() -> None:
    assert quarters(1) == (0,) and quarters(2) == (0, 2) and quarters(4) == (0, 1, 2, 3)
    with pytest.raises(ValueError, match="turns=3"):
        quarters(3)


@pytest.mark.parametrize("q", [1, 2, 3])
def test_the_turned_input_is_what_the_turned_camera_sees(q: int) -> None:
    """A point seen at pixel (u, v) lies, in ``np.rot90(image, q)``, where the turned camera projects ``Q^q X``."""
    rng = np.random.default_rng(q)
    X = np.column_stack([rng.uniform(-0.3, 0.3, 50), rng.uniform(-0.3, 0.3, 50), rng.uniform(0.8, 1.2, 50)])
    u, v = CAMERA.project(X).T
    cols, rows = np.rint(u).astype(int), np.rint(v).astype(int)
    inside = (cols >= 0) & (cols < 128) & (rows >= 0) & (rows < 128)
    image = np.zeros((128, 128))
    image[rows[inside], cols[inside]] = np.arange(1, inside.sum() + 1)
    turned = np.rot90(image, q)
    cam = turned_camera(CAMERA, q)
    u2, v2 = cam.project(X @ turn_matrix(q).T).T
    # the projection lands where the pixel went (the same sub-pixel offset, turned)
    got = turned[np.rint(v2[inside]).astype(int), np.rint(u2[inside]).astype(int)]
    np.testing.assert_array_equal(got, np.arange(1, inside.sum() + 1))
    assert turned_camera(cam, 4 - q) == CAMERA


def test_turned_back_undoes_the_turn_for_numpy_and_torch() -> None:
    rng = np.random.default_rng(0)
    R = np.linalg.qr(rng.normal(size=(4, 3, 3)))[0]
    t = rng.normal(size=(4, 3))
    Q = turn_matrix(1)
    R2, t2 = turned_back(Q @ R, t @ Q.T, 1)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t2, t, atol=1e-12)
    Rt, tt = turned_back(torch.from_numpy(Q @ R), torch.from_numpy(t @ Q.T), 1)
    np.testing.assert_allclose(Rt.numpy(), R, atol=1e-12)
    np.testing.assert_allclose(tt.numpy(), t, atol=1e-12)


def _turned_gt(gt: GroundTruthBatch, q: int) -> GroundTruthBatch:
    Q = torch.from_numpy(turn_matrix(q)).float()
    seg = None if gt.segmentation is None else torch.rot90(gt.segmentation, q, dims=(-2, -1))
    return GroundTruthBatch(gt.batch_index, Q @ gt.R_cam_obj, gt.t_cam_obj @ Q.T, gt.visibility, gt.instance_id,
                            gt.batch_size, seg)


@pytest.mark.parametrize("cls", [VanillaParameterization, EVEParameterization])
def test_the_hypotheses_of_every_turn_are_the_images_own_poses(cls: type) -> None:
    """The target of each turned scene, decoded with ``turns`` 4: without averaging, four times the image's own
    hypotheses, each at its part's pose in the image's camera; with averaging, one per part, at its pose."""
    obj = builtin_object("zbracket")
    gt = random_scene_batch(obj, CAMERA, 2, (3, 5), torch.Generator().manual_seed(1), overhang=0.0)
    param = cls(obj, grid=16, turns=4, averaging=False)
    outputs = {q: param.encode(_turned_gt(gt, q), turned_camera(CAMERA, q)) for q in range(4)}
    assigned = param.assigned(gt, CAMERA)
    for averaging in (False, True):
        decoder = param.with_decoding(averaging={"eps": 0.5} if averaging else False)
        alone = decoder.with_decoding(turns=1).decode(outputs[0], CAMERA)
        hyps = decoder.decode(outputs[0], CAMERA, turned=[(q, outputs[q]) for q in (1, 2, 3)])
        for b, h in enumerate(hyps):
            sel = ((gt.batch_index == b) & assigned).numpy()
            R_gt, t_gt = gt.R_cam_obj.double().numpy()[sel], gt.t_cam_obj.double().numpy()[sel]
            assert len(h) == (1 if averaging else 4) * len(alone[b]) >= len(t_gt)
            nearest = np.linalg.norm(h.t[:, None] - t_gt[None], axis=-1).argmin(1)
            assert set(nearest.tolist()) == set(range(len(t_gt)))
            if averaging:
                assert len(h) == len(t_gt)
            dt, dr = pose_errors(param, R_gt[nearest], t_gt[nearest], h.R, h.t)
            assert dt.max() < 1e-4 and dr.max() < 1e-4


def test_turns_need_the_turned_outputs_and_a_turn_count_of_1_2_or_4() -> None:
    param = VanillaParameterization(builtin_object("zbracket"), grid=8, turns=2)
    out = torch.zeros(1, param.out_channels, 8, 8)
    with pytest.raises(ValueError, match=r"decoding.turns=2 pools the outputs of the input turned by \[2\]"):
        param.decode(out, CAMERA)
    with pytest.raises(ValueError, match=r"turned by \[2\] quarter turns; given \[1\]"):
        param.decode(out, CAMERA, turned=[(1, out)])
    assert len(param.decode(out, CAMERA, turned=[(2, out)])) == 1
    with pytest.raises(SettingError, match=r"^decoding.turns=3: expected 1, 2 or 4"):
        param.with_decoding(turns=3)
    with pytest.raises(SettingError, match=r"parameterization.turns=0: expected 1, 2 or 4"):
        VanillaParameterization(builtin_object("zbracket"), grid=8, turns=0)
