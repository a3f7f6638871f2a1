"""Open a dataset folder whatever its layout (IPA or Siléane)."""

from __future__ import annotations

from pathlib import Path

from opnet.datasets.bop import BOPDataset, is_bop_split
from opnet.datasets.ipa import IPADataset
from opnet.datasets.ipa_params import PARAMETER_FILE
from opnet.datasets.sileane import CAMERA_FILE, SileaneDataset


def open_dataset(path: str | Path, object_id: int | None = None,
                 clip: tuple[float, float] | None = None) -> IPADataset | SileaneDataset | BOPDataset:
    """The dataset in ``path``: IPA if it holds ``parameter.json``, Siléane if it holds
    ``camera_params.txt`` or (ground truth only) ``gt/*.json``, BOP if it is a split folder of
    scene folders (``XXXXXX/scene_gt.json``; ``object_id`` selects the object, ``clip`` the
    working range in metres).

    Raises:
        FileNotFoundError: nothing at ``path``.
        ValueError: ``path`` is a file, or neither layout is recognised (the message says what was looked for).
    """
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ValueError(f"{path}: a file, not a dataset folder; give the folder that holds the dataset")
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: dataset folder not found")
    if (path / PARAMETER_FILE).is_file():
        return IPADataset(path)
    if is_bop_split(path):
        if object_id is None:
            raise ValueError(f"{path}: a BOP split folder: set the object to train on (data.object_id=<obj_id>)")
        return BOPDataset(path, object_id, clip=clip)
    gt = path / "gt"
    if (path / CAMERA_FILE).is_file() or (gt.is_dir() and any(gt.glob("*.[jJ][sS][oO][nN]"))):
        return SileaneDataset(path)
    raise ValueError(
        f"{path}: not a dataset folder: expected {PARAMETER_FILE} (Fraunhofer IPA layout) or "
        f"{CAMERA_FILE} / gt/*.json (Siléane layout) or XXXXXX/scene_gt.json scene folders (a BOP split)"
    )
