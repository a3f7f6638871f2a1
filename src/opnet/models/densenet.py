"""Fully convolutional DenseNet-BC backbone of OP-Net
(docs/method.md#the-papers-formulation-or-our-measured-best, paper "Setup").

The reference network (``depth=40, growth_rate=50``, 128 x 128 input, 16 x 16 output)::

    stem     Conv3x3 stride 2, 1 -> 2k channels                      128 -> 64
    block 1  6 bottleneck layers  BN-ReLU-Conv1x1(4k)-BN-ReLU-Conv3x3(k)   at 64 x 64
    trans 1  BN-ReLU-Conv1x1(x compression), AvgPool 2              64 -> 32
    block 2  6 bottleneck layers                                     at 32 x 32
    trans 2                                                          32 -> 16
    block 3  6 bottleneck layers                                     at 16 x 16
    head     BN-ReLU-Conv1x1 -> out_channels, output activation (sigmoid)

``depth`` keeps its DenseNet-BC meaning for that reference structure: ``depth = c·L + 4`` with
``L`` dense layers in total, ``c = 2`` convolutions per bottleneck layer (1 without bottleneck)
and 4 = stem + two transitions + head. **[decision]** The layer budget ``L`` is the same for
every output grid; the number of transitions follows from the grid,
``log2(in_size / stem_stride / out_grid)``, and the ``L`` layers are spread over the
``transitions + 1`` dense blocks as evenly as possible, the remainder going to the last
(coarsest, cheapest) blocks. With ``depth=40`` (L = 18):

- grid 16 (2 transitions): blocks of 6, 6, 6 layers -> 40 weighted layers;
- grid 8 (MP, 3 transitions): blocks of 4, 4, 5, 5 -> 41 weighted layers;
- grid 32 (SI, 1 transition): blocks of 9, 9 -> 39 weighted layers.

A stem stride of 4 (CPU presets) removes one transition (grid 16: two blocks); a stride of 8 feeds
a twice larger input to the same blocks (256 pixels to the 32 x 32 maps a 128-pixel input gives at
stride 4: more input pixels per part for about the same work). The stem kernel is 3 x 3 for strides
1 and 2 and ``2·stride - 1`` (7 x 7 for stride 4, 15 x 15 for 8) so that the stem still sees every
input pixel.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor, nn
from torch.utils.checkpoint import checkpoint

OUTPUT_ACTIVATIONS = ("sigmoid", "identity")
STEM_STRIDES = (1, 2, 4, 8)


def _bn_relu_conv(in_ch: int, out_ch: int, kernel: int) -> list[nn.Module]:
    return [
        nn.BatchNorm2d(in_ch),
        nn.ReLU(inplace=True),
        nn.Conv2d(in_ch, out_ch, kernel, padding=kernel // 2, bias=False),
    ]


class _DenseLayer(nn.Module):
    """One (bottleneck) layer: concatenated features in, ``growth_rate`` new channels out."""

    def __init__(self, in_ch: int, growth_rate: int, bottleneck: bool, memory_efficient: bool):
        super().__init__()
        self.memory_efficient = memory_efficient
        if bottleneck:
            self.reduce = nn.Sequential(*_bn_relu_conv(in_ch, 4 * growth_rate, 1))
            self.conv = nn.Sequential(*_bn_relu_conv(4 * growth_rate, growth_rate, 3))
        else:
            self.reduce = None
            self.conv = nn.Sequential(*_bn_relu_conv(in_ch, growth_rate, 3))

    def _first(self, *features: Tensor) -> Tensor:
        x = torch.cat(features, 1)
        return self.reduce(x) if self.reduce is not None else x

    def forward(self, features: list[Tensor]) -> Tensor:
        # The concatenation and the first BN-ReLU-conv hold activations that grow with the number of
        # input channels; recomputing them in the backward pass is the memory-efficient DenseNet.
        if self.memory_efficient and self.training and any(f.requires_grad for f in features):
            x = checkpoint(self._first, *features, use_reentrant=False)
        else:
            x = self._first(*features)
        return self.conv(x)


class _DenseBlock(nn.Module):
    def __init__(
        self, n_layers: int, in_ch: int, growth_rate: int, bottleneck: bool, memory_efficient: bool
    ):
        super().__init__()
        self.layers = nn.ModuleList(
            _DenseLayer(in_ch + i * growth_rate, growth_rate, bottleneck, memory_efficient)
            for i in range(n_layers)
        )
        self.out_channels = in_ch + n_layers * growth_rate

    def forward(self, x: Tensor) -> Tensor:
        features = [x]
        for layer in self.layers:
            features.append(layer(features))
        return torch.cat(features, 1)


def dense_layer_budget(depth: int, bottleneck: bool) -> int:
    """Total number of dense layers ``L`` of a DenseNet(-BC) of ``depth`` (``depth = c·L + 4``).

    Raises:
        ValueError: when ``depth - 4`` is not a positive multiple of the convolutions per layer.
    """
    per_layer = 2 if bottleneck else 1
    if depth <= 4 or (depth - 4) % per_layer:
        raise ValueError(
            f"DenseNetBC: depth={depth} does not match the block structure: expected depth = "
            f"{per_layer}·L + 4 with L >= 1 dense layers (bottleneck={bottleneck}), e.g. 40"
        )
    return (depth - 4) // per_layer


def split_layers(total: int, n_blocks: int) -> list[int]:
    """Spread ``total`` dense layers over ``n_blocks`` blocks, the remainder to the last blocks."""
    base, rest = divmod(total, n_blocks)
    return [base + (i >= n_blocks - rest) for i in range(n_blocks)]


def num_transitions(in_size: int, stem_stride: int, out_grid: int) -> int:
    """Transitions (each halves the resolution) from ``in_size / stem_stride`` down to ``out_grid``.

    Raises:
        ValueError: when the grid cannot be reached by halving.
    """
    if stem_stride not in STEM_STRIDES:
        raise ValueError(f"DenseNetBC: stem_stride={stem_stride}, expected one of {STEM_STRIDES}")
    if in_size <= 0 or out_grid <= 0 or in_size % stem_stride:
        raise ValueError(
            f"DenseNetBC: in_size={in_size} must be a positive multiple of stem_stride={stem_stride}"
            f" and out_grid={out_grid} positive"
        )
    ratio = in_size // stem_stride / out_grid
    n = round(math.log2(ratio)) if ratio >= 1 else -1
    if n < 0 or 2**n != ratio:
        raise ValueError(
            f"DenseNetBC: out_grid={out_grid} is not reachable from in_size={in_size} with "
            f"stem_stride={stem_stride}: in_size / stem_stride = {in_size / stem_stride} must be "
            f"out_grid times a power of two"
        )
    return n


class DenseNetBC(nn.Module):
    """Fully convolutional DenseNet-BC mapping a normalized depth image to the OP-Net output grid.

    Args:
        out_channels: channels of the output grid (the parameterization's feature-vector layout).
        out_grid: output side ``S`` (16 vanilla/EVE/AP/Z, 8 MP, 32 SI).
        in_size: input side in pixels (128 in the paper).
        depth: DenseNet-BC depth of the reference 3-block network, ``depth = c·L + 4``.
        growth_rate: ``k``, channels added per dense layer.
        compression: channel factor of the transitions (``θ`` of DenseNet-BC), in (0, 1].
        stem_stride: stride of the stem convolution (1, 2, 4 or 8).
        bottleneck: use the 1x1 bottleneck (4k channels) before each 3x3 convolution ("B").
        output_activation: ``"sigmoid"`` (every target channel lies in [0, 1]) or ``"identity"``.
        in_channels: input channels (1 for depth).
        memory_efficient: recompute concatenations in the backward pass (torch.utils.checkpoint).
        channels_last: keep weights and activations in the channels-last (NHWC) memory format,
            which oneDNN's CPU convolutions run faster (scripts/bench/model_stats.py --train measures it).
        fp32_stem: under autocast, run the stem convolution in float32 and hand its output to the first
            dense block in float32 (its batch norms and concatenations stay float32; the block's convolutions
            cast after the norm). Without it the stem reads the depth rounded to bf16, in steps of up to 1/256
            of the working range (about 1 mm at a 0.25 m range, 3 mm at 0.83 m), as much as the relief by which
            a part's spin shows. A no-op without autocast (float32 training and inference).

    Under autocast (bf16 mixed precision) the head and the output activation run in float32: a
    bf16 sigmoid would quantize positions to 1/256 of their range (millimetres at bin scale).
    """

    def __init__(
        self,
        out_channels: int,
        out_grid: int = 16,
        in_size: int = 128,
        depth: int = 40,
        growth_rate: int = 50,
        compression: float = 0.5,
        stem_stride: int = 2,
        bottleneck: bool = True,
        output_activation: str = "sigmoid",
        in_channels: int = 1,
        memory_efficient: bool = False,
        channels_last: bool = False,
        fp32_stem: bool = False,
    ):
        super().__init__()
        if out_channels < 1 or in_channels < 1 or growth_rate < 1:
            raise ValueError(
                f"DenseNetBC: out_channels={out_channels}, in_channels={in_channels} and "
                f"growth_rate={growth_rate} must be positive"
            )
        if not 0.0 < compression <= 1.0:
            raise ValueError(f"DenseNetBC: compression={compression}, expected a value in (0, 1]")
        if output_activation not in OUTPUT_ACTIVATIONS:
            raise ValueError(
                f"DenseNetBC: output_activation={output_activation!r}, expected one of {OUTPUT_ACTIVATIONS}"
            )
        n_trans = num_transitions(in_size, stem_stride, out_grid)
        budget = dense_layer_budget(depth, bottleneck)
        if budget < n_trans + 1:
            raise ValueError(
                f"DenseNetBC: depth={depth} gives {budget} dense layers, fewer than the "
                f"{n_trans + 1} dense blocks needed for out_grid={out_grid}"
            )
        self.out_channels, self.out_grid, self.in_size = out_channels, out_grid, in_size
        self.in_channels = in_channels
        self.output_activation = output_activation
        self.fp32_stem = bool(fp32_stem)
        self.block_layers = split_layers(budget, n_trans + 1)

        stem_kernel = max(3, 2 * stem_stride - 1)
        channels = 2 * growth_rate
        self.stem = nn.Conv2d(
            in_channels,
            channels,
            stem_kernel,
            stride=stem_stride,
            padding=stem_kernel // 2,
            bias=False,
        )
        stages: list[nn.Module] = []
        for i, n_layers in enumerate(self.block_layers):
            block = _DenseBlock(n_layers, channels, growth_rate, bottleneck, memory_efficient)
            stages.append(block)
            channels = block.out_channels
            if i < n_trans:
                reduced = max(1, math.floor(channels * compression))
                stages.append(nn.Sequential(*_bn_relu_conv(channels, reduced, 1), nn.AvgPool2d(2)))
                channels = reduced
        self.features = nn.Sequential(*stages)
        self.head = nn.Sequential(
            nn.BatchNorm2d(channels), nn.ReLU(inplace=True), nn.Conv2d(channels, out_channels, 1)
        )
        self.num_weighted_layers = (
            1 + sum(self.block_layers) * (2 if bottleneck else 1) + n_trans + 1
        )
        self._init_weights()
        self.channels_last = bool(channels_last)
        if self.channels_last:
            self.to(memory_format=torch.channels_last)

    def _init_weights(self) -> None:
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, nonlinearity="relu")
                if m.bias is not None:
                    nn.init.zeros_(m.bias)
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.ones_(m.weight)
                nn.init.zeros_(m.bias)

    @property
    def head_conv(self) -> nn.Conv2d:
        """The final 1x1 convolution (its bias holds the per-channel output prior)."""
        return self.head[-1]

    @torch.no_grad()
    def set_head_bias(self, channels: Sequence[int], value: float) -> None:
        """Set the head bias (pre-activation logit) of ``channels`` to ``value``.

        E.g. ``set_head_bias([0], -3.0)`` starts the presence channel at sigmoid(-3) ≈ 0.05,
        close to the fraction of occupied cells, which stabilizes early training.

        Raises:
            ValueError: when a channel index is outside ``[0, out_channels)``.
        """
        index = list(channels)
        bad = [c for c in index if not 0 <= c < self.out_channels]
        if bad:
            raise ValueError(
                f"DenseNetBC.set_head_bias: channels {bad} outside [0, {self.out_channels})"
            )
        self.head_conv.bias[index] = float(value)

    def forward_logits(self, x: Tensor) -> Tensor:
        """Head output before the output activation, (B, out_channels, S, S) float32."""
        if x.ndim != 4 or x.shape[1] != self.in_channels:
            raise ValueError(
                f"DenseNetBC: input has shape {tuple(x.shape)}, expected "
                f"(B, {self.in_channels}, {self.in_size}, {self.in_size})"
            )
        if self.channels_last:
            x = x.contiguous(memory_format=torch.channels_last)
        if self.fp32_stem:
            with torch.autocast(device_type=x.device.type, enabled=False):
                stem = self.stem(x.float())
        else:
            stem = self.stem(x)
        features = self.features(stem)
        with torch.autocast(device_type=x.device.type, enabled=False):
            return self.head(features.float()).contiguous()

    def forward(self, x: Tensor) -> Tensor:
        """Normalized depth (B, in_channels, in_size, in_size) float32 in [0, 1] to the output grid.

        Returns:
            (B, out_channels, out_grid, out_grid) float32, in [0, 1] with the sigmoid activation.
        """
        y = self.forward_logits(x)
        return torch.sigmoid(y) if self.output_activation == "sigmoid" else y


__all__ = ["DenseNetBC", "dense_layer_budget", "num_transitions", "split_layers"]
