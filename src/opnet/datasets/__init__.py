"""Dataset records, readers and writers (Fraunhofer IPA and Siléane layouts), and their ground
truth as Siléane JSON. The command line converter is ``python -m opnet.datasets.convert``."""

from opnet.datasets.autodetect import open_dataset
from opnet.datasets.ground_truth import record_to_ground_truth, write_sileane_ground_truth
from opnet.datasets.ipa import IPADataset, read_ipa_scene, write_ipa_scene
from opnet.datasets.ipa_params import IPAParameters, read_parameters, write_parameters
from opnet.datasets.record import SceneRecord
from opnet.datasets.sileane import SileaneDataset, read_camera_params

__all__ = [
    "IPADataset",
    "IPAParameters",
    "SceneRecord",
    "SileaneDataset",
    "open_dataset",
    "read_camera_params",
    "read_ipa_scene",
    "read_parameters",
    "record_to_ground_truth",
    "write_ipa_scene",
    "write_parameters",
    "write_sileane_ground_truth",
]
