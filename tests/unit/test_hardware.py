"""The hardware decisions of a training: on a CUDA GPU the fp32 matrix products use the tensor
cores (Lightning warns otherwise); a CPU run keeps PyTorch's full fp32 precision."""

from __future__ import annotations

from typing import Any

import pytest
import torch

from opnet.cli import train as train_cli
from opnet.hardware import configure_matmul_precision, on_cuda
from conftest import compose_cfg


@pytest.fixture
def matmul_precision(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The values passed to ``torch.set_float32_matmul_precision`` (the process's own stays as it is)."""
    calls: list[str] = []
    monkeypatch.setattr(torch, "get_float32_matmul_precision", lambda: "highest")
    monkeypatch.setattr(torch, "set_float32_matmul_precision", calls.append)
    return calls


@pytest.mark.parametrize(("accelerator", "cuda_available", "expected"), [
    ("gpu", False, True), ("cuda", False, True), ("auto", True, True),
    ("auto", False, False), ("cpu", True, False),
])  # fmt: skip
def test_tensor_cores_exactly_where_the_run_is_on_cuda(accelerator: str, cuda_available: bool, expected: bool,
                                                       matmul_precision: list[str],
                                                       monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: cuda_available)
    assert on_cuda(accelerator) is expected
    assert configure_matmul_precision(accelerator) is expected
    assert matmul_precision == (["high"] if expected else [])


def test_a_precision_the_process_chose_is_kept(matmul_precision: list[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(torch, "get_float32_matmul_precision", lambda: "medium")
    assert not configure_matmul_precision("gpu") and matmul_precision == []


@pytest.mark.parametrize(("trainer", "expected"), [("gpu", ["high"]), ("cpu", [])])
def test_the_trainer_of_train_py_sets_it_for_a_gpu_only(trainer: str, expected: list[str], matmul_precision: list[str],
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """build_trainer, where train.py resolves accelerator and precision (the Trainer itself is not
    made: there is no GPU to give it)."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(train_cli, "instantiate", lambda cfg, **kwargs: {"cfg": cfg, **kwargs})
    cfg = compose_cfg("train", [f"trainer={trainer}", "~callbacks", "~logger"])
    made: Any = train_cli.build_trainer(cfg)
    assert made["cfg"].accelerator == trainer
    assert matmul_precision == expected


@pytest.mark.parametrize(("forced", "bf16"), [("0", False), ("1", True)])
def test_the_environment_runs_auto_as_another_kind_of_cpu_would(forced: str, bf16: bool,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """``OPNET_CPU_BF16`` makes every ``auto`` precision, training's and inference's, what a CPU with
    (1) or without (0) native bf16 computes, whatever this CPU is (the suite is run both ways)."""
    from opnet.hardware import CPU_BF16_ENV, cpu_has_native_bf16, resolve_precision
    from opnet.inference import InferenceSettings

    monkeypatch.setenv(CPU_BF16_ENV, forced)
    assert cpu_has_native_bf16() is bf16
    assert resolve_precision("auto", "cpu") == ("bf16-mixed" if bf16 else "32-true")
    assert InferenceSettings("auto").resolved(torch.device("cpu"))[0] is bf16


def test_a_bad_value_of_the_environment_is_named(monkeypatch: pytest.MonkeyPatch) -> None:
    from opnet.hardware import CPU_BF16_ENV, cpu_has_native_bf16

    monkeypatch.setenv(CPU_BF16_ENV, "yes")
    with pytest.raises(ValueError, match=r"^OPNET_CPU_BF16='yes': expected 0 \(no native bf16: fp32\) or 1, or unset$"):
        cpu_has_native_bf16()
