"""Synthetic bin-picking data: physics drops (MuJoCo or pybullet), rendering (pyrender), IPA-layout writer.

In memory: :class:`CycleGenerator` (``BinSimulator`` + ``SceneRenderer``) makes the
:class:`~opnet.datasets.record.SceneRecord` of every scene of a cycle. On disk:
:func:`generate_dataset` writes a resumable, deterministic Fraunhofer-IPA-layout dataset.

Names are imported on first use: ``generate_dataset`` on a dataset that is already complete,
``SceneConfig`` and ``read_generation`` load neither a physics engine nor pyrender (a training
box without them can use data generated elsewhere).
"""

from opnet._lazy import lazy_exports

_WHERE = {
    "BinGeometry": "layout",
    "BinSimulator": "physics",
    "make_simulator": "physics",
    "CycleGenerator": "cycle",
    "CycleLayout": "layout",
    "CycleResult": "cycle",
    "CycleStates": "physics",
    "GenerationReport": "generate",
    "RenderedScene": "rendering",
    "Rig": "layout",
    "SceneConfig": "config",
    "SceneRenderer": "rendering",
    "cycle_rngs": "cycle",
    "generate_dataset": "generate",
    "make_rig": "layout",
    "read_generation": "writer",
}

__getattr__, __dir__, __all__ = lazy_exports(__name__, _WHERE)
