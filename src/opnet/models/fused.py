"""Inference form of :class:`~opnet.models.densenet.DenseNetBC`: the same function, less work.

A trained DenseNet-BC in eval mode is rewritten for CPU inference (``inference.fused``, on by
default for float32; ``scripts/bench/bench_infer.py`` measures each step):

- **One buffer per dense block.** Each layer writes its ``growth_rate`` new channels into its
  slice of a preallocated channels-last block buffer and reads the first ``c`` channels of it,
  instead of concatenating all earlier features anew for every layer (the ``torch.cat`` of the
  training graph copies O(L²) activations per block).
- **BN-ReLU before a 1x1 convolution is one clamp.** ``relu(s·x + t) = s·clamp(x, lo, hi) + t``
  per channel (``lo = -t/s`` where ``s > 0``, ``hi = -t/s`` where ``s < 0``), and ``s`` and ``t``
  fold into the convolution's weights and bias, which a 1x1 convolution (no zero padding) allows.
  One pass over the block's features per layer instead of three (concatenate, normalize, ReLU).
- **The BN after the bottleneck convolution is folded into it**, its ReLU fused into the oneDNN
  convolution.
- **Prepacked oneDNN convolutions.** Where PyTorch ships oneDNN (``torch.ops.mkldnn``) the
  weights are reordered once into oneDNN's blocked layout (eager PyTorch reorders them on every
  call); elsewhere ``F.conv2d``, the same arithmetic.
- **Output channels to the vector width.** oneDNN's AVX-512 kernels compute output channels in
  blocks of 16, and a 3x3 convolution to 50 channels is slower than one to 64 (4.6 vs 4.1 ms at
  64 x 64 here) or to 48 (3.0 ms). The paper network's 50 = 48 + 2: the 48 as one convolution, the
  last 2 as a 1x1 convolution to 18 channels (one per tap and channel) summed over the 9 shifts
  (3.5 ms together); other widths are padded with zero filters to a multiple of 16.
- **Transitions pool first.** ``AvgPool2d(2)`` after a 1x1 convolution equals the convolution of
  the pooled input (both linear; one acts on pixels, the other on channels): a quarter of the work.

The output equals the reference network's to float32 rounding (``tests/unit/test_fused.py``);
``scripts/bench/check_inference.py`` compares the poses with the fp32 eager path. Training keeps the
plain module: this form has no gradients and no batch statistics.
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from opnet.models.densenet import DenseNetBC, _DenseBlock, _DenseLayer

#: output channels of the 3x3 convolutions are padded to a multiple of this (oneDNN's AVX-512
#: channel block; 64 channels ran faster than 50 here) unless split (SPLIT_REST)
CHANNEL_BLOCK = 16
#: a 3x3 convolution whose output channels exceed a multiple of CHANNEL_BLOCK by at most this many
#: runs split (see _ThreeByThree) on feature maps of at least SPLIT_SIDE pixels a side (measured
#: here, 50 = 48 + 2 channels: 3.5 vs 4.1 ms padded at 64 x 64, 0.93 vs 1.03 ms at 32 x 32, but
#: 0.31 vs 0.27 ms at 16 x 16)
SPLIT_REST = 4
SPLIT_SIDE = 32


def mkldnn_ops_available() -> bool:
    """Whether this PyTorch build has oneDNN's fused, prepacked convolution operators."""
    try:
        ops = torch.ops.mkldnn
        return (
            torch.backends.mkldnn.is_available()
            and hasattr(ops, "_convolution_pointwise")
            and hasattr(ops, "_reorder_convolution_weight")
        )
    except (AttributeError, RuntimeError):
        return False


def bn_affine(bn: nn.BatchNorm2d) -> tuple[Tensor, Tensor]:
    """(scale, shift) with ``bn(x) == x * scale + shift`` in eval mode, float64, shape (C,)."""
    scale = bn.weight.detach().double() / torch.sqrt(bn.running_var.double() + bn.eps)
    shift = bn.bias.detach().double() - bn.running_mean.double() * scale
    return scale, shift


class PackedConv(nn.Module):
    """A convolution (+ bias, + optional ReLU) whose weights are prepacked for oneDNN once.

    The packed copy is made at the first call (for its input shape; other shapes still compute
    correctly) and dropped by a move or cast. Falls back to ``F.conv2d`` without oneDNN operators,
    or for inputs that are not float32 on the CPU.
    """

    def __init__(self, weight: Tensor, bias: Tensor | None, stride: int = 1, padding: int = 0,
                 relu: bool = False, use_mkldnn: bool = True):
        super().__init__()
        self.register_buffer("weight", weight.detach().float().contiguous())
        self.register_buffer("bias", None if bias is None else bias.detach().float().contiguous())
        self.stride, self.padding, self.relu = stride, padding, relu
        self.use_mkldnn = use_mkldnn and mkldnn_ops_available()
        self._packed: Tensor | None = None

    def forward(self, x: Tensor) -> Tensor:
        p, s = [self.padding] * 2, [self.stride] * 2
        if self.use_mkldnn and x.device.type == "cpu" and x.dtype == torch.float32:
            if self._packed is None:
                self._packed = torch.ops.mkldnn._reorder_convolution_weight(self.weight, p, s, [1, 1], 1, list(x.shape))
            attr = "relu" if self.relu else "none"
            return torch.ops.mkldnn._convolution_pointwise(x, self._packed, self.bias, p, s, [1, 1], 1, attr, [], "")
        b = None if self.bias is None else self.bias.to(x.dtype)
        y = F.conv2d(x, self.weight.to(x.dtype), b, stride=s, padding=p)
        return F.relu_(y) if self.relu else y

    def _apply(self, fn, recurse=True):  # a move or cast invalidates the packed copy
        self._packed = None
        return super()._apply(fn, recurse)


class _Clamp(nn.Module):
    """``clamp(x, lo, hi)`` per channel: the pre-activation BN-ReLU with its affine folded away."""

    def __init__(self, lo: Tensor, hi: Tensor):
        super().__init__()
        self.one_sided = bool(torch.isinf(hi).all())
        self.register_buffer("lo", lo.float().view(1, -1, 1, 1))
        self.register_buffer("hi", hi.float().view(1, -1, 1, 1))

    def forward(self, x: Tensor) -> Tensor:
        if self.one_sided:  # every BN scale positive (the usual case): one bound
            return torch.maximum(x, self.lo)
        if torch.jit.is_tracing():  # ONNX's Clip takes scalar bounds only
            return torch.minimum(torch.maximum(x, self.lo), self.hi)
        return torch.clamp(x, self.lo, self.hi)


def fold_bn_relu_into_1x1(bn: nn.BatchNorm2d, weight: Tensor, bias: Tensor | None) -> tuple[_Clamp, Tensor, Tensor]:
    """``conv1x1(relu(bn(x)))`` as ``conv1x1'(clamp(x))``: (the clamp, the new weight, the new bias).

    With ``s, t`` the BN's scale and shift, ``relu(s·x + t) = s·clamp(x, lo, hi) + t`` where
    ``lo = -t/s`` for ``s > 0`` and ``hi = -t/s`` for ``s < 0``; a channel with ``s = 0`` is the
    constant ``relu(t)``. So ``W·relu(s·x + t) = (W·diag(s))·clamp(x) + W·t'``.
    """
    s, t = bn_affine(bn)
    w = weight.detach().double()[:, :, 0, 0]
    bound = torch.where(s != 0, -t / torch.where(s != 0, s, torch.ones_like(s)), torch.zeros_like(s))
    inf = torch.full_like(s, math.inf)
    lo = torch.where(s > 0, bound, -inf)
    hi = torch.where(s < 0, bound, inf)
    t_eff = torch.where(s != 0, t, t.clamp_min(0))
    new_w = (w * s.view(1, -1))[:, :, None, None]
    new_b = w @ t_eff + (0 if bias is None else bias.detach().double())
    return _Clamp(lo, hi), new_w, new_b


def _padded(weight: Tensor, block: int) -> Tensor:
    out = weight.shape[0]
    padded = -(-out // block) * block
    if padded == out:
        return weight
    return torch.cat([weight, weight.new_zeros(padded - out, *weight.shape[1:])])


class _Affine(nn.Module):
    """``relu(x * scale + shift)``: a BN-ReLU that cannot be folded (before a padded 3x3 convolution)."""

    def __init__(self, bn: nn.BatchNorm2d):
        super().__init__()
        scale, shift = bn_affine(bn)
        self.register_buffer("scale", scale.float().view(1, -1, 1, 1))
        self.register_buffer("shift", shift.float().view(1, -1, 1, 1))

    def forward(self, x: Tensor) -> Tensor:
        return torch.addcmul(self.shift, x, self.scale).relu_()


class _ThreeByThree(nn.Module):
    """The 3x3 convolution of a dense layer, written into its slice of the block buffer.

    ``growth`` = ``main`` + ``rest`` with ``main`` a multiple of ``block``. Three forms, all the
    same convolution: ``rest = 0`` as it is; a small ``rest`` (<= ``SPLIT_REST``) on feature maps of
    at least ``SPLIT_SIDE`` pixels a side as a ``main``-channel 3x3 convolution plus the ``rest``
    channels as one 1x1 convolution to ``9·rest`` channels (one per tap and channel) summed over
    the nine shifts; otherwise with zero filters padded up to a multiple of ``block``. For the
    paper network (50 = 48 + 2) at 64 x 64: 3.5 ms split, 4.1 ms padded to 64, 4.6 ms as it is.
    """

    def __init__(self, weight: Tensor, padding: int, side: int, block: int, use_mkldnn: bool):
        super().__init__()
        growth, k = weight.shape[0], weight.shape[-1]
        self.growth, self.main = growth, growth - growth % max(block, 1)
        rest = growth - self.main
        self.split = 0 < rest <= SPLIT_REST and self.main > 0 and side >= SPLIT_SIDE and k == 3 and padding == 1
        self.taps: PackedConv | None = None
        if self.split:
            self.conv = PackedConv(weight[: self.main], None, padding=padding, use_mkldnn=use_mkldnn)
            taps = weight[self.main :].permute(2, 3, 0, 1).reshape(k * k * rest, -1, 1, 1)  # (ky, kx, c)
            self.taps = PackedConv(taps, None, use_mkldnn=use_mkldnn)
        else:
            self.conv = PackedConv(_padded(weight, block), None, padding=padding, use_mkldnn=use_mkldnn)

    def forward(self, h: Tensor, out: Tensor | None = None) -> Tensor:
        """The ``growth`` new channels of ``h``, written into ``out`` when given (a buffer slice)."""
        if self.taps is None:
            y = self.conv(h)[:, : self.growth]
            return y if out is None else out.copy_(y)
        main = self.conv(h)
        if out is None:
            return torch.cat([main, self._tap_sum(h, None)], 1)
        out[:, : self.main] = main
        self._tap_sum(h, out[:, self.main :])
        return out

    def _tap_sum(self, h: Tensor, out: Tensor | None) -> Tensor:
        """The last ``rest`` channels: the 1x1 convolution to one channel per tap, summed over the
        nine shifts (zero padding of the 3x3 convolution = the padded tap maps)."""
        rest = self.growth - self.main
        hh, ww = h.shape[-2:]
        t = F.pad(self.taps(h), (1, 1, 1, 1))
        first, second = t[:, 0:rest, 0:hh, 0:ww], t[:, rest : 2 * rest, 0:hh, 1 : ww + 1]
        acc = first + second if out is None else torch.add(first, second, out=out)
        for tap in range(2, 9):
            dy, dx = divmod(tap, 3)
            acc.add_(t[:, tap * rest : (tap + 1) * rest, dy : dy + hh, dx : dx + ww])
        return acc


class _FusedLayer(nn.Module):
    def __init__(self, layer: _DenseLayer, use_mkldnn: bool, block: int, side: int):
        super().__init__()
        bn2, _, conv2 = layer.conv
        self.pre: nn.Module
        self.reduce: nn.Module
        if layer.reduce is not None:
            bn1, _, conv1 = layer.reduce
            self.pre, w1, b1 = fold_bn_relu_into_1x1(bn1, conv1.weight, conv1.bias)
            s2, t2 = bn_affine(bn2)  # the BN after the 1x1 convolution, folded into it
            self.reduce = PackedConv(w1 * s2.view(-1, 1, 1, 1), b1 * s2 + t2, relu=True, use_mkldnn=use_mkldnn)
        else:  # BN-ReLU-Conv3x3: the 3x3's zero padding forbids the clamp fold
            self.pre, self.reduce = _Affine(bn2), nn.Identity()
        self.growth = conv2.out_channels
        self.conv = _ThreeByThree(conv2.weight.detach(), conv2.padding[0], side, block, use_mkldnn)

    def forward(self, features: Tensor, out: Tensor | None = None) -> Tensor:
        """The new channels from the block's features so far (written into ``out`` when given)."""
        return self.conv(self.reduce(self.pre(features)), out)


class _FusedBlock(nn.Module):
    def __init__(self, block: _DenseBlock, use_mkldnn: bool, channel_block: int, side: int, concat: bool):
        super().__init__()
        self.layers = nn.ModuleList(_FusedLayer(layer, use_mkldnn, channel_block, side) for layer in block.layers)
        self.out_channels = block.out_channels
        self.concat = concat

    def forward(self, x: Tensor) -> Tensor:
        if self.concat:  # out-of-place, for export: each layer's channels appended
            for layer in self.layers:
                x = torch.cat([x, layer(x)], 1)
            return x
        b, c, h, w = x.shape
        buf = torch.empty(b, self.out_channels, h, w, dtype=x.dtype, device=x.device,
                          memory_format=torch.channels_last)
        buf[:, :c] = x
        for layer in self.layers:
            layer(buf[:, :c], buf[:, c : c + layer.growth])
            c += layer.growth
        return buf


class _FusedTransition(nn.Module):
    """BN-ReLU, Conv1x1, AvgPool 2 as clamp, AvgPool 2, Conv1x1 (folded weights)."""

    def __init__(self, seq: nn.Sequential, use_mkldnn: bool):
        super().__init__()
        bn, _, conv, _pool = seq
        self.pre, w, b = fold_bn_relu_into_1x1(bn, conv.weight, conv.bias)
        self.conv = PackedConv(w, b, use_mkldnn=use_mkldnn)

    def forward(self, x: Tensor) -> Tensor:
        return self.conv(F.avg_pool2d(self.pre(x), 2))


def stages_with_sides(net: DenseNetBC) -> list[tuple[nn.Module, int]]:
    """Each stage of ``net.features`` (dense block or transition) with the side of its input maps."""
    side, out = net.in_size // net.stem.stride[0], []
    for stage in net.features:
        out.append((stage, side))
        if not isinstance(stage, _DenseBlock):
            side //= 2
    return out


def largest_block_bytes(net: DenseNetBC) -> int:
    """Bytes of the largest dense block's float32 features (its buffer) for one image."""
    return max((4 * stage.out_channels * side * side for stage, side in stages_with_sides(net)
                if isinstance(stage, _DenseBlock)), default=0)


class FusedDenseNet(nn.Module):
    """Inference-only rewrite of a :class:`DenseNetBC` (see the module docstring).

    Takes the network's current (eval-mode) weights and batch-norm statistics; later changes to
    ``net`` are not seen. Output: the same (B, out_channels, S, S) float32 grid as ``net(x)``.
    ``block_bytes_per_image``: the largest block buffer of one image (sets the chunk size).

    Args:
        net: the trained network.
        use_mkldnn: use oneDNN's prepacked, fused convolutions where this build has them.
        channel_block: pad the 3x3 convolutions' output channels to a multiple of this (1: none).
        concat: concatenate each layer's channels out of place instead of writing into block
            buffers (slower here; for tracing into ONNX, see :func:`export_form`).
    """

    def __init__(self, net: DenseNetBC, use_mkldnn: bool = True, channel_block: int = CHANNEL_BLOCK,
                 concat: bool = False):
        super().__init__()
        if not isinstance(net, DenseNetBC):
            raise TypeError(f"FusedDenseNet: expected a DenseNetBC, got {type(net).__name__}")
        self.in_channels, self.in_size = net.in_channels, net.in_size
        self.out_channels, self.out_grid = net.out_channels, net.out_grid
        self.output_activation = net.output_activation
        stem = net.stem
        self.stem = PackedConv(stem.weight, stem.bias, stem.stride[0], stem.padding[0], use_mkldnn=use_mkldnn)
        self.stages = nn.ModuleList(
            _FusedBlock(stage, use_mkldnn, channel_block, side, concat) if isinstance(stage, _DenseBlock)
            else _FusedTransition(stage, use_mkldnn)
            for stage, side in stages_with_sides(net)
        )
        self.block_bytes_per_image = largest_block_bytes(net)
        bn, _, conv = net.head
        self.head_pre, w, b = fold_bn_relu_into_1x1(bn, conv.weight, conv.bias)
        self.head = PackedConv(w, b, use_mkldnn=use_mkldnn)
        self.eval()

    def forward(self, x: Tensor) -> Tensor:
        if x.ndim != 4 or x.shape[1] != self.in_channels:
            raise ValueError(
                f"FusedDenseNet: input has shape {tuple(x.shape)}, expected "
                f"(B, {self.in_channels}, {self.in_size}, {self.in_size})"
            )
        h = self.stem(x.float().contiguous(memory_format=torch.channels_last))
        for stage in self.stages:
            h = stage(h)
        y = self.head(self.head_pre(h)).contiguous()
        return torch.sigmoid(y) if self.output_activation == "sigmoid" else y


def export_form(net: torch.nn.Module) -> torch.nn.Module:
    """The network to trace into ONNX: a DenseNetBC's fused arithmetic in plain operators (no oneDNN
    operators, no buffer writes), which ONNX Runtime also runs faster (docs/deployment.md "Inference speed");
    any other module as it is."""
    if not isinstance(net, DenseNetBC):
        return net
    return FusedDenseNet(net, use_mkldnn=False, concat=True)


__all__ = [
    "CHANNEL_BLOCK", "FusedDenseNet", "PackedConv", "bn_affine", "export_form", "fold_bn_relu_into_1x1", "largest_block_bytes",
    "mkldnn_ops_available",
]
