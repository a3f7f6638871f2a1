"""scripts/bench/bench_infer.py: which forward rows a device gets, and that every one reaches the table."""

from __future__ import annotations

import csv
import importlib.util
from pathlib import Path

import pytest
import torch

from opnet.studies.presets import load_model_preset
from opnet.paths import REPO_ROOT

spec = importlib.util.spec_from_file_location("bench_infer", REPO_ROOT / "scripts" / "bench" / "bench_infer.py")
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)

CUDA_ROWS = ["forward bf16", "forward bf16 channels-last", "forward bf16 CUDA graph"]


def test_a_cuda_device_gets_the_cuda_graph_rows_and_the_cpu_does_not() -> None:
    """Selected by device type alone: nothing is built, so no GPU is needed to check it."""
    model = load_model_preset("tiny", out_channels=8, out_grid=16)
    cpu = list(bench.forward_variants(torch.device("cpu"), model))
    cuda = list(bench.forward_variants(torch.device("cuda"), model))
    assert cpu[:2] == cuda[:2] == ["forward fp32 eager", "forward fp32 channels-last"]
    assert "forward fused fp32 (default)" in cpu and "forward fp32 (default)" in cuda  # no fused form on a GPU
    assert cuda[-3:] == CUDA_ROWS and not set(CUDA_ROWS) & set(cpu)
    assert "forward bf16 channels-last compiled" in bench.forward_variants(torch.device("cuda"), model, compile=True)


def test_every_selected_variant_is_a_row_of_the_table_and_csv(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    """main() times what forward_variants selects: the CUDA rows, built here by CPU stand-ins under
    their names, appear in the printed table and the CSV (they once were never timed at all)."""
    built: list[str] = []

    def stand_in(name: str) -> bench.Variant:
        def make(model: torch.nn.Module, x: torch.Tensor) -> object:
            built.append(name)
            return lambda: model.eval()(x)

        return make

    for name in CUDA_ROWS:
        monkeypatch.setitem(bench.CUDA_VARIANTS, name, stand_in(name))
    select = bench.forward_variants
    monkeypatch.setattr(bench, "forward_variants", lambda device, model, compile=False: select(
        torch.device("cuda"), model, compile))
    out = tmp_path / "infer.csv"
    bench.main(["--model", "tiny", "--device", "cpu", "--batches", "1", "--repeats", "1", "--parameterizations", "",
                "--no-onnx", "--out", str(out)])
    assert built == CUDA_ROWS
    with out.open() as f:
        stages = [row["stage"] for row in csv.DictReader(f)]
    printed = capsys.readouterr().out
    for name in CUDA_ROWS:
        assert stages.count(name) == 1
        assert f"    1 {name:<38}" in printed
