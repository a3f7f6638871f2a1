"""Output parameterizations of OP-Net: encode ground truth into the output grid, decode network
outputs into pose hypotheses (docs/method.md#the-six-parameterizations). Select one with the Hydra config group
``conf/parameterization/`` (``_target_`` names the class).

Names are imported on first use (PEP 562): the averaging loads without PyTorch (opnet.deploy).
"""

from __future__ import annotations

from opnet._lazy import lazy_exports

_WHERE = {
    "APParameterization": "ap",
    "PoseAveraging": "averaging",
    "dbscan_labels": "averaging",
    "GroundTruthBatch": "base",
    "Parameterization": "base",
    "EVEParameterization": "eve",
    "MPParameterization": "mp",
    "SIParameterization": "si",
    "VanillaParameterization": "vanilla",
    "ZParameterization": "z",
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, _WHERE)
