"""Shared fixtures: the optional reference data folder, and headless rendering."""

from __future__ import annotations

import errno
import os
from pathlib import Path
from typing import Any

import pytest

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from hypothesis import settings  # noqa: E402

from opnet.paths import shared_dir  # noqa: E402

# Property tests draw the same examples on every run (CI must not turn red by the luck of a draw);
# HYPOTHESIS_PROFILE=explore draws new ones when hunting for counter-examples.
settings.register_profile("deterministic", derandomize=True, print_blob=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))


def pytest_configure(config: pytest.Config) -> None:
    """Under pytest-xdist each of the n workers, and every process a test starts, computes with its
    share of the cores (OpenMP / BLAS threads), unless OMP_NUM_THREADS is set already: n workers each
    spinning threads on every core oversubscribe the machine (two tiny trainings side by side on two
    cores took 40 s each with two threads, 13.5 s with one)."""
    workers = getattr(config.option, "numprocesses", None)
    if workers in ("auto", "logical"):
        workers = os.cpu_count()
    if isinstance(workers, int) and workers > 1:
        os.environ.setdefault("OMP_NUM_THREADS", str(max(1, (os.cpu_count() or 1) // workers)))


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The tests marked ``slow`` run first, in their order, then the rest in theirs, so that the run ends on short
    ones (a minute-long test handed out last leaves the other workers idle for that minute). Every worker sorts
    the same way, as xdist requires."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log: Any) -> Any:
    """Under ``-n`` (xdist's default, ``--dist load``), work stealing: a worker that runs out takes half of what
    another still has queued. xdist's ``load`` hands each worker a fixed block of consecutive tests first, so
    the block holding the slow tests (first, above) would be one worker's alone while the other idles at the
    end. An explicit other ``--dist`` is left as asked."""
    if config.getvalue("dist") != "load":
        return None
    from xdist.scheduler import WorkStealingScheduling

    return WorkStealingScheduling(config, log)


@pytest.fixture(scope="session")
def shared() -> Path:
    """``../shared`` (or $OPNET_SHARED); skips the test when the reference data is absent."""
    path = shared_dir()
    if not (path / "data").is_dir():
        pytest.skip(f"reference data not found at {path} (set OPNET_SHARED to its location)")
    return path


@pytest.fixture(scope="session")
def meshes_dir(shared: Path) -> Path:
    return shared / "data" / "meshes"


@pytest.fixture(scope="session")
def bunny_sample(shared: Path) -> Path:
    return shared / "data" / "sileane_bunny_sample"


class FullDisk:
    """A file object whose writes fail as on a full disk: in place of ``os.fdopen`` in
    :mod:`opnet.fileio.atomic` (``monkeypatch.setattr(atomic.os, "fdopen", FullDisk)``)."""

    def __init__(self, fd: int, mode: str = "wb") -> None:
        os.close(fd)

    def __enter__(self) -> FullDisk:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def write(self, data: bytes) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def small_builtin_dataset(root: Path, name: str, cycles: int, drops: int, seed: int, **scene: Any) -> Path:
    """Generate a small IPA-layout dataset of a built-in object at 128 x 128 (other ``SceneConfig``
    fields in ``scene``) under ``root``."""
    from opnet.objects import builtin_object
    from opnet.synthesis import SceneConfig, generate_dataset

    generate_dataset(builtin_object(name), root, cycles=cycles, drops=drops, workers=1, seed=seed,
                     scene=SceneConfig(resolution=128, **scene), progress=False, previews=0,
                     object_config={"name": name, "builtin": name})  # fmt: skip
    return root


@pytest.fixture(scope="session")
def builtin_dataset(tmp_path_factory: pytest.TempPathFactory):
    """A factory: ``builtin_dataset(name, cycles, drops, seed)`` -> the dataset's root folder."""

    def make(name: str, cycles: int, drops: int, seed: int) -> Path:
        return small_builtin_dataset(tmp_path_factory.mktemp(name) / name, name, cycles, drops, seed)

    return make


def compose_cfg(name: str, overrides: list[str]) -> Any:
    """The composed Hydra config ``conf/<name>.yaml`` with ``overrides`` (no Hydra run)."""
    from hydra import compose, initialize_config_dir

    from opnet.paths import config_dir

    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        return compose(config_name=name, overrides=overrides)


def tiny_train_cfg(data: Path, out: Path, extra: list[str]) -> Any:
    """A train config of the tiny network on ``data`` (2 steps), writing into ``out``."""
    from omegaconf import OmegaConf

    cfg = compose_cfg("train", [
        "model=tiny", "object=zbracket", f"data.root={data}", "data.generate=null", "data.batch_size=4",
        "data.val_fraction=0.25", "data.test_fraction=0.25", "logger=tensorboard",
        "trainer.max_epochs=1", "+trainer.limit_train_batches=2", "+trainer.limit_val_batches=1",
        "trainer.enable_progress_bar=false", "example_predictions=1", *extra,
    ])  # fmt: skip
    OmegaConf.update(cfg, "paths.output_dir", str(out), force_add=True)
    return cfg


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """4 cycles x 4 drops of the built-in zbracket at 128 x 128."""
    return small_builtin_dataset(tmp_path_factory.mktemp("data") / "zbracket_tiny", "zbracket", 4, 4, 0)


@pytest.fixture(scope="session")
def checkpoint(tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``last.ckpt`` of 2 training steps of the tiny vanilla network on :func:`tiny_dataset`, in fp32:
    ``precision: auto`` would train in bf16 on CPUs that compute it natively, whose kernels differ between
    CPU kinds (AVX512-BF16 against AMX), and the tests that read this model's hypotheses must see the same
    model on every machine CI may run on."""
    from opnet.cli import train as train_cli

    out = tmp_path_factory.mktemp("ckpt_run")
    train_cli.run(tiny_train_cfg(tiny_dataset, out, ["parameterization=vanilla", "test=false",
                                                     "trainer.precision=32"]))
    return out / "checkpoints" / "last.ckpt"


@pytest.fixture(autouse=True)
def _grad_mode_left_as_found():
    """A test (or the code it calls) that turns autograd off for the process fails here, by name,
    instead of every later test in its worker that needs gradients."""
    import torch

    before = torch.is_grad_enabled()
    yield
    after = torch.is_grad_enabled()
    torch.set_grad_enabled(before)
    assert after == before, "autograd left switched off: use torch.no_grad() as a context or decorator"
