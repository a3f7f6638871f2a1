"""Locations the library needs without Hydra: the repository root and the reference data folder."""

from __future__ import annotations

import os
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]


def shared_dir() -> Path:
    """The project's reference data folder: $OPNET_SHARED, else ``<repo>/../shared``. May not exist."""
    env = os.environ.get("OPNET_SHARED")
    return Path(env) if env else REPO_ROOT.parent / "shared"


def config_dir() -> Path:
    """The Hydra config folder ``conf/`` of the repository."""
    return REPO_ROOT / "conf"
