"""Round-trip contract of every parameterization config: decode(encode(gt)) recovers the truth."""

from __future__ import annotations

from pathlib import Path

import hydra.utils
import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from opnet.analysis.toy_scenes import random_scene_batch
from opnet.geometry import Camera
from opnet.objects import builtin_object
from opnet.parameterizations import GroundTruthBatch, Parameterization, VanillaParameterization
from opnet.parameterizations.euler_codec import EulerCodec
from opnet.parameterizations.rotation import SixDCodec
from opnet.paths import config_dir
from param_checks import assert_round_trip, parameterization_names

CAMERA = Camera.from_fov(60.0, 128, 128, 0.5, 1.5)
CONFIGS = [config_dir() / "parameterization" / f"{name}.yaml" for name in parameterization_names()]
ROTATIONS = sorted((config_dir() / "rotation").glob("*.yaml"))
OBJECTS = ("bracket", "zbracket", "shaft", "pin")
_OBJECT_CACHE: dict[str, object] = {}


def make(config: Path, name: str, rotation: Path | None = None, **overrides: object) -> Parameterization:
    if name not in _OBJECT_CACHE:
        _OBJECT_CACHE[name] = builtin_object(name)
    obj = _OBJECT_CACHE[name]
    codec = None
    if rotation is not None:
        codec = hydra.utils.instantiate(OmegaConf.load(rotation), _partial_=True)(symmetry=obj.symmetry)
    cfg = OmegaConf.merge(OmegaConf.load(config), overrides)
    return hydra.utils.instantiate(cfg, obj=obj, rotation=codec)


def scenes(
    name: str, batch_size: int, seed: int, num_objects: int | tuple[int, int] = 25
) -> GroundTruthBatch:
    make(CONFIGS[0], name)  # fills the object cache
    return random_scene_batch(
        _OBJECT_CACHE[name], CAMERA, batch_size, num_objects, torch.Generator().manual_seed(seed)
    )


def test_every_config_is_covered():
    assert {c.stem for c in CONFIGS} >= {"vanilla", "eve", "ap", "z", "mp", "si"}


@pytest.mark.parametrize("rotation", ROTATIONS, ids=lambda p: p.stem)
@pytest.mark.parametrize("name", OBJECTS)
@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.stem)
def test_perfect_output_recovers_every_assigned_instance(config: Path, name: str, rotation: Path):
    assert_round_trip(make(config, name, rotation), scenes(name, batch_size=3, seed=1), CAMERA)


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.stem)
def test_empty_scenes_encode_to_zero_and_decode_to_nothing(config: Path):
    param = make(config, "zbracket")
    empty = GroundTruthBatch.from_arrays(
        [
            (
                np.zeros((0, 3, 3)),
                np.zeros((0, 3)),
                np.zeros(0),
                np.zeros(0),
                np.zeros((128, 128), int),
            )
        ]
        * 2
    )
    target = param.encode(empty, CAMERA)
    assert target.shape == (2, param.out_channels, param.grid_size, param.grid_size)
    assert not target.any()
    assert [len(h) for h in param.decode(target, CAMERA)] == [0, 0]
    assert param.assigned(empty, CAMERA).shape == (0,)


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.stem)
def test_batch_of_eight_agrees_with_single_images(config: Path):
    param = make(config, "bracket")
    gt = scenes("bracket", batch_size=8, seed=2, num_objects=(0, 30))
    batch_target = param.encode(gt, CAMERA)
    batch_hyps = param.decode(batch_target, CAMERA)
    for b in range(8):
        sel = gt.batch_index == b
        single = GroundTruthBatch(
            torch.zeros(int(sel.sum()), dtype=torch.long),
            gt.R_cam_obj[sel],
            gt.t_cam_obj[sel],
            gt.visibility[sel],
            gt.instance_id[sel],
            1,
            gt.segmentation[b : b + 1],
        )
        target = param.encode(single, [CAMERA])
        assert torch.equal(target[0], batch_target[b])
        assert torch.equal(param.assigned(single, CAMERA), param.assigned(gt, CAMERA)[sel])
        hyps = param.decode(target, CAMERA)[0]
        np.testing.assert_array_equal(hyps.t, batch_hyps[b].t)
        np.testing.assert_array_equal(hyps.R, batch_hyps[b].R)


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.stem)
def test_channel_layout_and_out_channels(config: Path):
    for name, per_slot in (("bracket", 8), ("shaft", 7)):
        param = make(config, name)
        layout = param.channel_layout()
        assert param.channels_per_slot == per_slot
        assert len(layout) == param.out_channels == param.slots * per_slot
        presence = [i for i, n in enumerate(layout) if n.split("[")[0] == "p"]
        assert presence == [slot * per_slot for slot in range(param.slots)]
        assert ("phi3" in layout[per_slot - 1]) is (per_slot == 8)
    for name, per_slot in (("bracket", 11), ("shaft", 8)):
        param = make(config, name, config_dir() / "rotation" / "r6d.yaml")
        assert param.channels_per_slot == per_slot
        assert len(param.channel_layout()) == param.out_channels == param.slots * per_slot


@pytest.mark.parametrize("config", CONFIGS, ids=lambda p: p.stem)
def test_decode_respects_threshold_and_score(config: Path):
    gt = scenes("zbracket", batch_size=1, seed=3)
    param = make(config, "zbracket", threshold=0.5, score="p*v", averaging=False)
    target = param.encode(gt, CAMERA)
    grid = param.split_slots(target)
    grid[:, :, 0] *= 0.4  # every presence below tau
    assert len(param.decode(target, CAMERA)[0]) == 0
    grid[:, :, 0] /= 0.4 / 0.8
    hyps = param.decode(target, CAMERA)[0]
    assert len(hyps) > 0
    np.testing.assert_allclose(hyps.score, 0.8 * hyps.visibility, rtol=1e-6)


def test_decode_rejects_wrong_output_shape():
    param = make(CONFIGS[0], "bracket")
    with pytest.raises(ValueError, match="expected a tensor of shape"):
        param.decode(
            torch.zeros(1, param.out_channels + 1, param.grid_size, param.grid_size), CAMERA
        )


def test_rotations_for_the_loss_are_differentiable_and_match_decode():
    param = make(config_dir() / "parameterization" / "z.yaml", "zbracket")
    gt = scenes("zbracket", batch_size=2, seed=4)
    target = param.encode(gt, CAMERA).requires_grad_(True)
    R = param.decode_rotations(target)
    assert R.shape == (2, param.slots, param.grid_size, param.grid_size, 3, 3)
    R.sum().backward()
    assert target.grad is not None and target.grad.abs().sum() > 0
    hyps = param.decode(target.detach(), CAMERA)[0]
    present = param.split_slots(target.detach())[0, :, 0] > 0.5
    decoded = R.detach()[0][present].double().numpy()
    assert {tuple(np.round(r.ravel(), 5)) for r in decoded} == {
        tuple(np.round(r.ravel(), 5)) for r in hyps.R
    }



@pytest.mark.parametrize("name", ["zbracket", "shaft", "pin"])
def test_a_convention_whose_third_axis_is_not_the_symmetry_axis_is_refused(name: str):
    with pytest.raises(ValueError, match=r"rotation.convention='ZYX'.*symmetry"):
        EulerCodec(builtin_object(name).symmetry, "ZYX")
    EulerCodec(builtin_object("bracket").symmetry, "ZYX")  # fine without symmetry


def test_an_unknown_convention_names_the_key():
    with pytest.raises(ValueError, match="rotation.convention"):
        EulerCodec(builtin_object("bracket").symmetry, "ZZY")


def test_a_codec_of_another_symmetry_is_refused():
    shaft = builtin_object("shaft")
    with pytest.raises(ValueError, match="another symmetry"):
        VanillaParameterization(builtin_object("bracket"), rotation=SixDCodec(shaft.symmetry))


@pytest.mark.parametrize("name", OBJECTS)
@pytest.mark.parametrize("config", [c for c in CONFIGS if c.stem in ("eve", "ap", "si")], ids=lambda p: p.stem)
def test_cell_offset_positions_round_trip_and_reach_at_least_the_enlarged_image(config: Path, name: str):
    enlarged = make(config, name, position="enlarged")
    offset = make(config, name, config_dir() / "rotation" / "r6d.yaml", position="cell_offset")
    gt = scenes(name, batch_size=3, seed=6)
    assigned = offset.assigned(gt, CAMERA)
    assert int(assigned.sum()) >= int(enlarged.assigned(gt, CAMERA).sum())
    target = offset.encode(gt, CAMERA)
    grid = offset.split_slots(target)
    occupied = grid[:, :, 0] > 0
    # the same object in different cells: different x channels (offsets), unlike the enlarged image
    assert len(torch.unique(grid[:, :, 2][occupied])) > len(torch.unique(enlarged.split_slots(enlarged.encode(gt, CAMERA))[:, :, 2][occupied]))
    for b, h in enumerate(offset.with_decoding(averaging=False).decode(target, CAMERA)):
        sel = ((gt.batch_index == b) & assigned).numpy()
        t_gt = gt.t_cam_obj.double().numpy()[sel]
        dist = np.linalg.norm(t_gt[:, None] - h.t[None], axis=-1)
        assert dist.min(0).max() < 1e-4  # every hypothesis (one per cell) sits on an origin
        assert dist.min(1).max() < 1e-4  # every assigned instance has one


def test_min_visibility_gates_decoding_and_with_decoding_copies():
    param = make(CONFIGS[0], "zbracket", averaging=False)
    gt = scenes("zbracket", batch_size=1, seed=8)
    target = param.encode(gt, CAMERA)
    all_hyps = param.decode(target, CAMERA)[0]
    gated = param.with_decoding(min_visibility=0.5).decode(target, CAMERA)[0]
    assert len(gated) == int((all_hyps.visibility >= 0.5).sum()) < len(all_hyps)
    assert param.min_visibility == 0.0  # the original is unchanged
    tuned = param.with_decoding(score="p*v", averaging={"eps": 1.5, "cluster_score": "sum"})
    assert tuned.averaging.eps == 1.5 and tuned.averaging.cluster_score == "sum" and param.averaging is None
    with pytest.raises(ValueError, match="unknown setting"):
        param.with_decoding(grid=8)
    with pytest.raises(ValueError, match="min_visibility"):
        VanillaParameterization(builtin_object("zbracket"), min_visibility=1.5)
