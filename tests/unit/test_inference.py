"""The fast inference path gives the network's fp32 output (fused or channels-last, chunked
batches), and its settings are validated."""

from __future__ import annotations

import copy

import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from opnet.inference import InferenceSettings, _on_workers, fast_forward
from opnet.models.fused import largest_block_bytes
from opnet.paths import config_dir


def _net() -> torch.nn.Module:
    torch.manual_seed(0)
    net = instantiate(OmegaConf.load(config_dir() / "model" / "tiny.yaml"), out_channels=8, out_grid=16)
    for m in net.modules():  # non-trivial running statistics, as after training
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.2, 0.2)
            m.running_var.uniform_(0.5, 1.5)
    return net.eval()


@pytest.mark.parametrize("settings", [
    InferenceSettings(),  # the default: fused, chunks of 8 (tiny network)
    InferenceSettings(max_batch=1),
    InferenceSettings(max_batch=3, workers=2),  # chunks on two threads at once
    InferenceSettings(fused=False, max_batch=5, workers=3),
    InferenceSettings(fused=False),  # channels-last, chunks of 8
    InferenceSettings(fused=True, max_batch=8),
])  # fmt: skip
def test_fp32_paths_equal_fp32_eager_for_chunked_batches(settings: InferenceSettings) -> None:
    net = _net()
    x = torch.rand(19, 1, 128, 128)  # 19 images: chunks of 8, 8 and 3
    with torch.inference_mode():
        ref = net(x)
    out = fast_forward(copy.deepcopy(net), settings)(x)
    assert out.dtype == torch.float32 and out.shape == ref.shape
    torch.testing.assert_close(out, ref, rtol=1e-5, atol=1e-5)


def test_the_default_on_the_cpu_is_the_fused_form_and_says_so() -> None:
    net, cpu = _net(), torch.device("cpu")
    assert InferenceSettings().resolved(cpu, net) == (False, True, True)
    assert InferenceSettings().describe(cpu, net).startswith("fused fp32, channels-last, chunks of 8")  # tiny
    paper = instantiate(OmegaConf.load(config_dir() / "model" / "paper.yaml"), out_channels=8, out_grid=16)
    assert largest_block_bytes(paper) == 4 * 400 * 64 * 64  # block 1: 100 + 6 x 50 channels at 64 x 64
    assert InferenceSettings(workers=2).describe(cpu, paper).startswith("fused fp32, channels-last, chunks of 1 on 2 workers")
    assert InferenceSettings(max_batch=3).chunk(largest_block_bytes(paper)) == 3
    assert InferenceSettings("bf16", True).resolved(cpu, net) == (True, True, False)  # auto: bf16 not fused
    assert InferenceSettings(compile=True).resolved(cpu, net)[2] is False
    assert InferenceSettings().resolved(cpu, torch.nn.Conv2d(1, 1, 1))[2] is False
    with pytest.raises(ValueError, match="inference.fused=true: the fused form computes in float32"):
        InferenceSettings("bf16", fused=True).resolved(cpu, net)


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
    ({"max_batch": "big"}, "inference.max_batch='big'"),
    ({"fused": "yes"}, "inference.fused='yes'"),
    ({"workers": -1}, "inference.workers=-1"),
    ({"threads": 4}, "unknown keys"),
    ({"device_side": "yes"}, "inference.device_side='yes'"),
    ({"device_side": 1}, "inference.device_side=1"),  # a number is no switch
    ({"cuda_graph": "on"}, "inference.cuda_graph='on'"),
])  # fmt: skip
def test_bad_inference_settings_are_refused(cfg: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        InferenceSettings.from_config(cfg)


def test_settings_from_a_config() -> None:
    cfg = {"precision": "32", "fused": False, "channels_last": "auto", "compile": False, "max_batch": 4, "workers": 2}
    assert InferenceSettings.from_config(cfg) == InferenceSettings("32", "auto", False, 4, False, 2)
    assert InferenceSettings.from_config(None) == InferenceSettings()
    both = InferenceSettings.from_config({"device_side": True, "cuda_graph": False})
    assert (both.device_side, both.cuda_graph) == (True, False)


def test_device_side_and_cuda_graph_resolve_by_device() -> None:
    """auto: both on a CUDA device, neither on the CPU; a compiled forward is never captured."""
    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    auto = InferenceSettings()
    assert (auto.on_device(cpu), auto.graphed(cpu)) == (False, False)
    assert (auto.on_device(cuda), auto.graphed(cuda)) == (True, True)
    assert InferenceSettings(device_side=True).on_device(cpu) and not InferenceSettings(device_side=False).on_device(cuda)
    assert not InferenceSettings(cuda_graph=False).graphed(cuda) and not InferenceSettings(compile=True).graphed(cuda)
    assert "CUDA graph" not in auto.describe(cpu, _net()) and "on the device" not in auto.describe(cpu, _net())
    assert auto.describe(cuda, _net()).endswith("fp32, channels-last, chunks of 8, CUDA graph at batch 1, preprocessing and "
                                                "averaging on the device, predict.py's images whole as one graph on cuda")
    compiled = InferenceSettings(compile_pipeline=True).describe(cuda, _net())
    assert compiled.endswith("images whole as one graph (pre- and postprocessing compiled) on cuda")
    assert "whole" not in InferenceSettings(device_side=False).describe(cuda, _net())


@pytest.mark.parametrize(("setting", "level", "message"), [
    (True, "WARNING", "inference.cuda_graph=true: no CUDA device (cpu); batch-1 forwards run without a CUDA graph"),
    ("auto", "INFO", "inference: no CUDA device (cpu), batch-1 forwards run without a CUDA graph"),
])  # fmt: skip
def test_a_cuda_graph_on_the_cpu_falls_back_with_a_log_line(setting: object, level: str, message: str,
                                                            caplog: pytest.LogCaptureFixture) -> None:
    net = _net()
    x = torch.rand(1, 1, 128, 128)
    with torch.inference_mode():
        ref = net(x)
    with caplog.at_level("INFO", logger="opnet.inference"):
        run = fast_forward(copy.deepcopy(net), InferenceSettings(fused=False, cuda_graph=setting))
    assert [(r.levelname, r.getMessage()) for r in caplog.records] == [(level, message)]
    torch.testing.assert_close(run(x), ref, rtol=1e-5, atol=1e-5)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
@pytest.mark.parametrize("precision", ["32", "bf16"])
def test_the_cuda_graph_replays_the_forward_of_each_new_image(precision: str) -> None:
    net = _net().cuda()
    plain = fast_forward(copy.deepcopy(net), InferenceSettings(precision, cuda_graph=False))
    graphed = fast_forward(copy.deepcopy(net), InferenceSettings(precision, cuda_graph=True))
    for seed in range(3):  # the graph is captured once, then replayed on each new input
        x = torch.rand(1, 1, 128, 128, generator=torch.Generator().manual_seed(seed)).cuda()
        torch.testing.assert_close(graphed(x), plain(x), rtol=1e-4, atol=1e-4)
    x = torch.rand(3, 1, 128, 128, device="cuda")  # a larger batch runs without the graph
    torch.testing.assert_close(graphed(x), plain(x), rtol=1e-4, atol=1e-4)


def test_chunks_on_workers_keep_their_order_and_raise_errors() -> None:
    chunks = [torch.full((1,), float(i)) for i in range(7)]
    assert [int(c) for c in _on_workers(lambda c: c * 2, chunks, 3)] == [0, 2, 4, 6, 8, 10, 12]
    threads = torch.get_num_threads()

    def fail(c: torch.Tensor) -> torch.Tensor:
        if int(c) == 5:
            raise RuntimeError("chunk 5 failed")
        return c

    with pytest.raises(RuntimeError, match="chunk 5 failed"):
        _on_workers(fail, chunks, 2)
    assert torch.get_num_threads() == threads  # the caller's threads are as before
