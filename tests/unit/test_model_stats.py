"""Backbone statistics: the FLOP convention, the paper network's size, the preset table."""

from __future__ import annotations

import pytest
import torch

from opnet.models.stats import (
    count_parameters,
    forward_ms_per_image,
    gflops_per_image,
    train_images_per_s,
)
from opnet.studies.presets import load_model_preset, preset_stats


def test_flop_convention_is_two_per_multiply_add() -> None:
    conv = torch.nn.Conv2d(1, 4, 3, padding=1, bias=False)
    macs = 4 * 9 * 32 * 32
    assert gflops_per_image(conv, 32) == pytest.approx(2 * macs / 1e9)


def test_paper_preset_matches_method_md_and_cpu_presets_are_cheaper() -> None:
    rows = {r.preset: r for r in preset_stats(["paper", "small", "tiny"], [16], timing=False)}
    paper = rows["paper"]
    assert abs(paper.parameters - 3.0e6) / 3.0e6 < 0.10, paper.parameters
    assert abs(paper.gflops - 10.0) / 10.0 < 0.10, paper.gflops
    assert paper.ms_batch1 is None and paper.train_images_per_s is None
    assert rows["tiny"].gflops < rows["small"].gflops < paper.gflops / 10


def test_timings_are_positive_for_tiny() -> None:
    model = load_model_preset("tiny", out_channels=8, out_grid=16)
    assert count_parameters(model) > 0
    assert forward_ms_per_image(model, batch=2, repeats=1) > 0
    assert train_images_per_s(model, batch=2, steps=1) > 0


def test_unknown_preset_names_the_file() -> None:
    with pytest.raises(ValueError, match="nosuch.yaml"):
        load_model_preset("nosuch", 8, 16)


def test_probe_inputs_are_made_on_the_models_device() -> None:
    """A model on another device than the CPU is measured there (a CUDA model crashed on CPU probes);
    the meta device stands in for a GPU: its tensors have shapes and a device but no data."""
    torch.manual_seed(0)
    model = torch.nn.Sequential(torch.nn.Conv2d(1, 4, 3, padding=1, bias=False), torch.nn.ReLU())
    on_cpu = gflops_per_image(model, 32)
    model.to(torch.device("meta"))
    seen: list[torch.device] = []
    model.register_forward_pre_hook(lambda module, args: seen.append(args[0].device))
    measurements = {
        "gflops": lambda: gflops_per_image(model, 32),
        "forward": lambda: forward_ms_per_image(model, batch=2, in_size=32, repeats=1),
        "training": lambda: train_images_per_s(model, batch=2, in_size=32, steps=1),
    }
    values = {}
    for name, measure in measurements.items():
        seen.clear()
        values[name] = measure()
        assert seen and set(seen) == {torch.device("meta")}, (name, seen)
    assert values["gflops"] == pytest.approx(on_cpu)  # counted as on the CPU
    assert values["forward"] > 0 and values["training"] > 0
