"""Open a dataset folder whatever its layout (IPA or Siléane)."""

from __future__ import annotations

from pathlib import Path

from opnet.datasets.ipa import IPADataset
from opnet.datasets.ipa_params import PARAMETER_FILE
from opnet.datasets.sileane import CAMERA_FILE, SileaneDataset


def open_dataset(path: str | Path) -> IPADataset | SileaneDataset:
    """The dataset in ``path``: IPA if it holds ``parameter.json``, Siléane if it holds
    ``camera_params.txt`` or (ground truth only) ``gt/*.json``.

    Raises:
        FileNotFoundError: ``path`` is not a folder.
        ValueError: neither layout recognised (the message says what was looked for).
    """
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: dataset folder not found")
    if (path / PARAMETER_FILE).is_file():
        return IPADataset(path)
    gt = path / "gt"
    if (path / CAMERA_FILE).is_file() or (gt.is_dir() and any(gt.glob("*.[jJ][sS][oO][nN]"))):
        return SileaneDataset(path)
    raise ValueError(
        f"{path}: not a dataset folder: expected {PARAMETER_FILE} (Fraunhofer IPA layout) or "
        f"{CAMERA_FILE} / gt/*.json (Siléane layout)"
    )
