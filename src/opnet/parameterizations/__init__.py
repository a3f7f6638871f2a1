"""Output parameterizations of OP-Net: encode ground truth into the output grid, decode network
outputs into pose hypotheses (method.md §3-§6). Select one with the Hydra config group
``conf/parameterization/`` (``_target_`` names the class)."""

from opnet.parameterizations.ap import APParameterization
from opnet.parameterizations.averaging import PoseAveraging, dbscan_labels
from opnet.parameterizations.base import GroundTruthBatch, Parameterization
from opnet.parameterizations.eve import EVEParameterization
from opnet.parameterizations.mp import MPParameterization
from opnet.parameterizations.si import SIParameterization
from opnet.parameterizations.vanilla import VanillaParameterization
from opnet.parameterizations.z import ZParameterization

__all__ = [
    "APParameterization",
    "EVEParameterization",
    "GroundTruthBatch",
    "MPParameterization",
    "Parameterization",
    "PoseAveraging",
    "SIParameterization",
    "VanillaParameterization",
    "ZParameterization",
    "dbscan_labels",
]
