"""Shared fixtures: the optional reference data folder, and headless rendering."""

from __future__ import annotations

import os
from pathlib import Path

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
