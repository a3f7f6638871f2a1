"""Locations the library needs without Hydra: the repository root, the reference data folder and
the user cache."""

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


def user_cache_dir() -> Path:
    """$OPNET_CACHE, else ``~/.cache/opnet`` (collision hulls, caches of read-only datasets)."""
    env = os.environ.get("OPNET_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "opnet"


def best_checkpoint(run_dir: str | Path) -> Path | None:
    """The checkpoint a train.py run's test scored: the best validation AP
    (``checkpoints/epoch*-ap*.ckpt``), else ``checkpoints/last.ckpt``, else None."""
    folder = Path(run_dir) / "checkpoints"
    best = sorted(folder.glob("epoch*-ap*.ckpt"))
    last = folder / "last.ckpt"
    return best[-1] if best else last if last.is_file() else None
