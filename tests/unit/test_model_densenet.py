"""DenseNet-BC backbone: output grids, the paper network's size, gradients, options, errors."""

from __future__ import annotations

import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from opnet.models.densenet import DenseNetBC, dense_layer_budget, num_transitions, split_layers
from opnet.paths import config_dir

TINY = {"depth": 16, "growth_rate": 8, "stem_stride": 4}


def _tiny(**kwargs: object) -> DenseNetBC:
    torch.manual_seed(0)
    return DenseNetBC(**{"out_channels": 8, **TINY, **kwargs})


@pytest.mark.parametrize(
    ("grid", "blocks", "weighted"), [(16, [6, 6, 6], 40), (8, [4, 4, 5, 5], 41), (32, [9, 9], 39)]
)
def test_paper_layer_distribution(grid: int, blocks: list[int], weighted: int) -> None:
    model = DenseNetBC(8, out_grid=grid)
    assert model.block_layers == blocks
    assert model.num_weighted_layers == weighted


@pytest.mark.parametrize("grid", [8, 16, 32])
@pytest.mark.parametrize("stem_stride", [2, 4])
def test_output_shape_for_each_grid(grid: int, stem_stride: int) -> None:
    model = _tiny(out_grid=grid, out_channels=24, stem_stride=stem_stride).eval()
    with torch.no_grad():
        y = model(torch.rand(2, 1, 128, 128))
    assert y.shape == (2, 24, grid, grid)
    assert y.dtype == torch.float32
    assert float(y.min()) >= 0.0 and float(y.max()) <= 1.0


def test_paper_network_shape_and_initial_logits() -> None:
    torch.manual_seed(0)
    model = DenseNetBC(8).eval()
    with torch.no_grad():
        logits = model.forward_logits(torch.rand(1, 1, 128, 128))
    assert logits.shape == (1, 8, 16, 16)
    # Kaiming init + BN keep the head's logits O(1): the sigmoid is neither saturated nor flat
    assert 0.1 < float(logits.std()) < 10.0


def test_paper_parameter_count_near_3m() -> None:
    n = sum(p.numel() for p in DenseNetBC(8).parameters())
    assert abs(n - 3.0e6) / 3.0e6 < 0.10, n


def test_gradients_reach_every_parameter() -> None:
    model = _tiny(out_grid=16).train()
    y = model(torch.rand(3, 1, 128, 128))
    (y - 0.3).square().mean().backward()
    missing = [
        name for name, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0
    ]
    assert not missing


def test_memory_efficient_matches_plain() -> None:
    plain, efficient = _tiny(), _tiny(memory_efficient=True)
    efficient.load_state_dict(plain.state_dict())
    x = torch.rand(2, 1, 64, 64, requires_grad=True)  # fully convolutional: any multiple of 32
    outs, grads = [], []
    for model in (plain, efficient):
        y = model.train()(x)
        (gx,) = torch.autograd.grad(y.square().sum(), x)
        outs.append(y.detach())
        grads.append(gx)
    torch.testing.assert_close(outs[0], outs[1])
    torch.testing.assert_close(grads[0], grads[1])


def test_channels_last_gives_same_output() -> None:
    model = _tiny().eval()
    x = torch.rand(2, 1, 128, 128)
    with torch.no_grad():
        ref = model(x)
        model = model.to(memory_format=torch.channels_last)
        out = model(x.to(memory_format=torch.channels_last))
    torch.testing.assert_close(out, ref, atol=1e-5, rtol=1e-4)


def test_identity_activation_returns_logits_and_sigmoid_wraps_them() -> None:
    model = _tiny(output_activation="identity").eval()
    x = torch.rand(1, 1, 128, 128)
    with torch.no_grad():
        logits = model(x)
        model.output_activation = "sigmoid"
        torch.testing.assert_close(model(x), torch.sigmoid(logits))
    assert float(logits.min()) < 0.0  # really unbounded


def test_set_head_bias_sets_presence_prior() -> None:
    model = _tiny(out_channels=16).eval()
    torch.nn.init.zeros_(model.head_conv.weight)
    model.set_head_bias([0, 8], -3.0)
    with torch.no_grad():
        y = model(torch.rand(1, 1, 128, 128))
    prior = torch.sigmoid(torch.tensor(-3.0))
    torch.testing.assert_close(y[:, [0, 8]], prior.expand(1, 2, 16, 16))
    torch.testing.assert_close(y[:, 1], torch.full((1, 16, 16), 0.5))
    with pytest.raises(ValueError, match="outside"):
        model.set_head_bias([16], 0.0)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"depth": 41}, "depth=41"),
        ({"depth": 4}, "depth=4"),
        ({"out_grid": 12}, "not reachable"),
        ({"out_grid": 256}, "not reachable"),
        ({"stem_stride": 3}, "stem_stride"),
        ({"in_size": 130, "stem_stride": 4}, "multiple of stem_stride"),
        ({"output_activation": "tanh"}, "output_activation"),
        ({"compression": 0.0}, "compression"),
        ({"out_channels": 0}, "out_channels"),
        ({"depth": 6, "out_grid": 8}, "dense blocks"),
    ],
)
def test_invalid_arguments_raise(kwargs: dict, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        DenseNetBC(**{"out_channels": 8, **kwargs})


def test_wrong_input_shape_names_expected_shape() -> None:
    with pytest.raises(ValueError, match=r"\(B, 1, 128, 128\)"):
        _tiny()(torch.rand(1, 3, 128, 128))


def test_helpers() -> None:
    assert dense_layer_budget(40, bottleneck=True) == 18
    assert dense_layer_budget(40, bottleneck=False) == 36
    assert split_layers(18, 4) == [4, 4, 5, 5]
    assert num_transitions(128, 2, 16) == 2 and num_transitions(128, 4, 32) == 0


@pytest.mark.parametrize("preset", ["paper", "small", "tiny"])
def test_model_presets_instantiate_without_output_keys(preset: str) -> None:
    cfg = OmegaConf.load(config_dir() / "model" / f"{preset}.yaml")
    assert cfg._target_ == "opnet.models.densenet.DenseNetBC"
    assert "out_channels" not in cfg and "out_grid" not in cfg
    model = instantiate(cfg, out_channels=24, out_grid=8)
    assert isinstance(model, DenseNetBC) and model.out_grid == 8


def test_a_stride_8_stem_feeds_twice_the_input_to_the_same_blocks() -> None:
    """256 pixels at stem stride 8 reach the 32 x 32 maps 128 pixels reach at stride 4: the same blocks and
    transitions (every weight but the stem's), the output grids of the 128-pixel network, and a stem that
    still sees every input pixel (15 x 15 kernel)."""
    for grid in (8, 16, 32):
        wide = _tiny(out_grid=grid, out_channels=24, stem_stride=8, in_size=256).eval()
        plain = _tiny(out_grid=grid, out_channels=24, stem_stride=4, in_size=128).eval()
        assert wide.block_layers == plain.block_layers and wide.stem.kernel_size == (15, 15)
        rest = lambda m: sum(p.numel() for n, p in m.named_parameters() if not n.startswith("stem"))  # noqa: E731
        assert rest(wide) == rest(plain)
        with torch.no_grad():
            assert wide(torch.rand(1, 1, 256, 256)).shape == (1, 24, grid, grid)


def test_fp32_stem_reads_depth_finer_than_bf16_under_autocast() -> None:
    """Under bf16 autocast a plain stem reads the depth rounded to 1/256 of its value: a 0.3 mm step on a
    0.25 m working range (0.0012 of it, under half of bf16's spacing of 1/256 at 0.7) vanishes; the float32
    stem passes it on."""
    torch.manual_seed(0)
    plain = DenseNetBC(out_channels=4, out_grid=16, depth=16, growth_rate=12, stem_stride=4).eval()
    fp32 = DenseNetBC(out_channels=4, out_grid=16, depth=16, growth_rate=12, stem_stride=4, fp32_stem=True).eval()
    fp32.load_state_dict(plain.state_dict())
    flat = torch.full((1, 1, 128, 128), 179 / 256)  # 0.699, a bf16 value
    relief = flat.clone()
    relief[..., 40:80, 40:80] += 0.0012
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16):
        plain_gap = (plain(relief) - plain(flat)).abs().max().item()
        out = fp32(relief)
        fp32_gap = (out - fp32(flat)).abs().max().item()
    assert plain_gap == 0.0
    assert fp32_gap > 0.0
    assert out.dtype == torch.float32 and out.shape == (1, 4, 16, 16)
    with torch.no_grad():  # without autocast the two are one network
        assert torch.equal(plain(relief), fp32(relief))
