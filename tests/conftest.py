"""Shared fixtures: the optional reference data folder, and headless rendering."""

from __future__ import annotations

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
