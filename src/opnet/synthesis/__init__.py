"""Synthetic bin-picking data: physics drops (pybullet), rendering (pyrender), IPA-layout writer.

In memory: :class:`CycleGenerator` (``BinSimulator`` + ``SceneRenderer``) makes the
:class:`~opnet.datasets.record.SceneRecord` of every scene of a cycle. On disk:
:func:`generate_dataset` writes a resumable, deterministic Fraunhofer-IPA-layout dataset.
"""

from opnet.synthesis.config import SceneConfig
from opnet.synthesis.cycle import CycleGenerator, CycleResult, cycle_rngs
from opnet.synthesis.generate import GenerationReport, generate_dataset
from opnet.synthesis.layout import BinGeometry, CycleLayout, Rig, make_rig
from opnet.synthesis.physics import BinSimulator, CycleStates
from opnet.synthesis.rendering import RenderedScene, SceneRenderer
from opnet.synthesis.writer import read_generation

__all__ = [
    "BinGeometry",
    "BinSimulator",
    "CycleGenerator",
    "CycleLayout",
    "CycleResult",
    "CycleStates",
    "GenerationReport",
    "RenderedScene",
    "Rig",
    "SceneConfig",
    "SceneRenderer",
    "cycle_rngs",
    "generate_dataset",
    "make_rig",
    "read_generation",
]
