"""Dataset records, readers and writers (Fraunhofer IPA and Siléane layouts), and their ground
truth as Siléane JSON. The command line converter is ``python -m opnet.datasets.convert``.

Names are imported on first use (PEP 562): the readers load without PyTorch (opnet.deploy).
"""

from __future__ import annotations

from opnet._lazy import lazy_exports

_WHERE = {
    "open_dataset": "autodetect",
    "record_to_ground_truth": "ground_truth",
    "write_sileane_ground_truth": "ground_truth",
    "IPADataset": "ipa",
    "read_ipa_scene": "ipa",
    "write_ipa_scene": "ipa",
    "IPAParameters": "ipa_params",
    "read_parameters": "ipa_params",
    "write_parameters": "ipa_params",
    "SceneRecord": "record",
    "SileaneDataset": "sileane",
    "read_camera_params": "sileane",
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _WHERE)
