"""The fused inference form of the DenseNet-BC computes the network's function (to float32
rounding) for every preset, grid and batch-norm state, with and without oneDNN's operators."""

from __future__ import annotations

import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf
from torch import nn

from opnet.models.densenet import DenseNetBC
from opnet.models.fused import (
    FusedDenseNet,
    PackedConv,
    export_form,
    fold_bn_relu_into_1x1,
    mkldnn_ops_available,
)
from opnet.paths import config_dir


def _trained_like(net: DenseNetBC, seed: int = 0, signs: bool = True) -> DenseNetBC:
    """Batch norms as after training: non-trivial statistics, scales of both signs and some zero."""
    g = torch.Generator().manual_seed(seed)
    for m in net.modules():
        if isinstance(m, nn.BatchNorm2d):
            n = m.num_features
            m.running_mean.copy_(torch.rand(n, generator=g) * 0.4 - 0.2)
            m.running_var.copy_(torch.rand(n, generator=g) + 0.5)
            m.weight.data.copy_(torch.rand(n, generator=g) * (3 if signs else 1.5) - (1.5 if signs else 0) + 0.05)
            m.bias.data.copy_(torch.rand(n, generator=g) * 0.4 - 0.2)
            if signs:
                m.weight.data[::7] = 0.0  # a dead channel: relu(t), constant
    return net.eval()


def _net(preset: str, grid: int = 16, out: int = 8, **kw) -> DenseNetBC:
    torch.manual_seed(0)
    cfg = OmegaConf.load(config_dir() / "model" / f"{preset}.yaml")
    return _trained_like(instantiate(cfg, out_channels=out, out_grid=grid, **kw))


def _close(a: torch.Tensor, b: torch.Tensor) -> None:
    torch.testing.assert_close(a, b, rtol=1e-5, atol=2e-6)


@pytest.mark.parametrize(("preset", "grid", "kw"), [
    ("tiny", 16, {}),
    ("small", 16, {}),
    ("small", 8, {}),
    ("small", 32, {}),
    ("tiny", 16, {"bottleneck": False, "depth": 10}),
    ("tiny", 16, {"output_activation": "identity"}),
    ("tiny", 16, {"growth_rate": 18}),  # 16 + 2 channels: the split 3x3 convolution at 32 x 32
    ("small", 16, {"in_size": 256, "stem_stride": 8}),  # the 15 x 15 stem of a twice larger input
])  # fmt: skip
def test_fused_equals_the_network(preset: str, grid: int, kw: dict) -> None:
    net = _net(preset, grid, **kw)
    side = kw.get("in_size", 128)
    x = torch.rand(3, 1, side, side, generator=torch.Generator().manual_seed(1))
    x[0, 0, :20] = 0.0  # missing-depth rows, as the preprocessing leaves them
    with torch.inference_mode():
        ref = net(x)
    fused = FusedDenseNet(net)
    out = fused(x)
    assert out.shape == ref.shape and out.dtype == torch.float32
    _close(out, ref)
    _close(FusedDenseNet(net, use_mkldnn=False)(x), ref)  # the plain-PyTorch fallback
    _close(FusedDenseNet(net, channel_block=1)(x), ref)  # no channel padding
    _close(FusedDenseNet(net, use_mkldnn=False, concat=True)(x), ref)  # the export form


def test_fused_paper_network_equals_it() -> None:
    net = _net("paper", 16, out=9)
    x = torch.rand(2, 1, 128, 128, generator=torch.Generator().manual_seed(2))
    with torch.inference_mode():
        ref = net(x)
    _close(FusedDenseNet(net)(x), ref)


def test_folding_bn_relu_into_a_1x1_convolution_is_exact() -> None:
    torch.manual_seed(3)
    bn = nn.BatchNorm2d(6).eval()
    bn.running_mean.uniform_(-1, 1)
    bn.running_var.uniform_(0.2, 2)
    bn.weight.data = torch.tensor([1.3, -0.7, 0.0, 0.0, 2.0, -1e-6])  # both signs, zero, tiny
    bn.bias.data = torch.tensor([0.2, 0.5, 0.4, -0.4, -0.1, 0.3])
    conv = nn.Conv2d(6, 4, 1, bias=True)
    x = torch.randn(2, 6, 5, 5) * 3
    with torch.no_grad():
        ref = conv(torch.relu(bn(x)))
        clamp, w, b = fold_bn_relu_into_1x1(bn, conv.weight, conv.bias)
        out = nn.functional.conv2d(clamp(x), w.float(), b.float())
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-6)
    assert not clamp.one_sided  # negative scales need the upper bound


def test_a_fused_network_runs_any_batch_size_and_refuses_bad_input() -> None:
    net = _net("tiny")
    fused = FusedDenseNet(net)
    with torch.inference_mode():
        for b in (1, 5):  # weights packed for the first shape still serve another batch size
            x = torch.rand(b, 1, 128, 128)
            _close(fused(x), net(x))
    with pytest.raises(ValueError, match="expected"):
        fused(torch.rand(1, 2, 128, 128))
    with pytest.raises(TypeError, match="DenseNetBC"):
        FusedDenseNet(nn.Conv2d(1, 1, 1))


def test_fused_form_snapshots_weights_and_holds_no_gradients() -> None:
    net = _net("tiny")
    fused = FusedDenseNet(net)
    assert not any(p.requires_grad for p in fused.parameters())
    x = torch.rand(1, 1, 128, 128)
    before = fused(x)
    with torch.no_grad():
        net.head_conv.bias.add_(1.0)  # a later change of the network is not seen
    torch.testing.assert_close(fused(x), before)


@pytest.mark.skipif(not mkldnn_ops_available(), reason="this PyTorch build has no oneDNN operators")
def test_packed_convolution_matches_conv2d_and_repacks_after_a_move() -> None:
    torch.manual_seed(4)
    w, b = torch.randn(20, 7, 3, 3), torch.randn(20)
    conv = PackedConv(w, b, stride=2, padding=1, relu=True)
    x = torch.randn(2, 7, 17, 17).contiguous(memory_format=torch.channels_last)
    ref = torch.relu(nn.functional.conv2d(x, w, b, stride=2, padding=1))
    torch.testing.assert_close(conv(x), ref, rtol=1e-5, atol=1e-5)
    assert conv._packed is not None
    conv.float()
    assert conv._packed is None
    torch.testing.assert_close(conv(x), ref, rtol=1e-5, atol=1e-5)


def test_three_by_three_forms_are_chosen_by_width_and_side() -> None:
    tiny = FusedDenseNet(_net("tiny", growth_rate=18))
    split = [[layer.conv.split for layer in stage.layers] for stage in tiny.stages if hasattr(stage, "layers")]
    assert split == [[True] * 3, [False] * 3]  # stem stride 4: blocks at 32 and 16 a side
    paper = FusedDenseNet(_net("paper", out=9))
    sides = [[layer.conv.split for layer in stage.layers] for stage in paper.stages if hasattr(stage, "layers")]
    assert sides == [[True] * 6, [True] * 6, [False] * 6]  # 64 and 32 a side split, 16 padded to 64
    assert paper.stages[-1].layers[0].conv.conv.weight.shape[0] == 64


def test_the_export_form_runs_in_onnx_runtime_as_the_network(tmp_path) -> None:
    ort = pytest.importorskip("onnxruntime")
    net = _net("tiny", growth_rate=18)  # the split 3x3 convolution, BN scales of both signs
    x = torch.rand(2, 1, 128, 128, generator=torch.Generator().manual_seed(5))
    with torch.no_grad():
        ref = net(x)
        torch.onnx.export(export_form(net), x, str(tmp_path / "net.onnx"), input_names=["x"], opset_version=17,
                          dynamo=False)
    out = ort.InferenceSession(str(tmp_path / "net.onnx"), providers=["CPUExecutionProvider"]).run(None, {"x": x.numpy()})[0]
    _close(torch.from_numpy(out), ref)
    assert export_form(nn.Conv2d(1, 1, 1)).__class__ is nn.Conv2d  # other networks as they are
