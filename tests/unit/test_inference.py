"""The fast inference path gives the network's fp32 output (channels-last, chunked batches), and
its settings are validated."""

from __future__ import annotations

import copy

import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from opnet.inference import InferenceSettings, fast_forward
from opnet.paths import config_dir


def _net() -> torch.nn.Module:
    torch.manual_seed(0)
    net = instantiate(OmegaConf.load(config_dir() / "model" / "tiny.yaml"), out_channels=8, out_grid=16)
    for m in net.modules():  # non-trivial running statistics, as after training
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.2, 0.2)
            m.running_var.uniform_(0.5, 1.5)
    return net.eval()


def test_default_path_equals_fp32_eager_for_chunked_batches() -> None:
    net = _net()
    x = torch.rand(19, 1, 128, 128)  # 19 images: chunks of 8, 8 and 3
    with torch.inference_mode():
        ref = net(x)
    out = fast_forward(copy.deepcopy(net), InferenceSettings())(x)
    assert out.dtype == torch.float32 and out.shape == ref.shape
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-5)


def test_bf16_path_is_close_but_not_exact() -> None:
    net = _net()
    x = torch.rand(2, 1, 128, 128)
    with torch.inference_mode():
        ref = net(x)
    out = fast_forward(copy.deepcopy(net), InferenceSettings("bf16", True))(x)
    assert out.dtype == torch.float32
    assert (out - ref).abs().max() < 0.1 * ref.abs().max()


@pytest.mark.parametrize(("cfg", "message"), [
    ({"precision": "fp16"}, "inference.precision='fp16'"),
    ({"channels_last": "yes"}, "inference.channels_last='yes'"),
    ({"max_batch": 0}, "inference.max_batch=0"),
    ({"threads": 4}, "unknown keys"),
])  # fmt: skip
def test_bad_inference_settings_are_refused(cfg: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        InferenceSettings.from_config(cfg)
