"""The physics of the generator: the drop rules and the engines that run them (``scene.physics``).

- :mod:`~opnet.synthesis.physics.base`: :class:`BinSimulator`, the rules of a cycle independent of
  the engine, and what a cycle returns (:class:`CycleStates`, :class:`CycleStats`).
- ``mujoco`` (default; :mod:`~opnet.synthesis.physics.mujoco_engine`): wheels for CPython
  3.10-3.14, maintained. Concave parts collide as a CoACD convex decomposition.
- ``pybullet`` (:mod:`~opnet.synthesis.physics.pybullet_engine`; the ``pybullet`` extra, wheels for
  CPython 3.11 only, last release January 2025): the engine of the datasets made before MuJoCo;
  concave parts as pybullet's V-HACD. Kept so that those datasets resume byte for byte.

:data:`ENGINES` maps a name to its engine; an engine's module (and its package) is imported only
when :func:`make_simulator` is asked for that engine. The engines import :mod:`.base` and nothing
else of this package, so the package has no import circle.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from opnet._deps import require
from opnet.synthesis.collision import CollisionModel
from opnet.synthesis.config import PHYSICS_ENGINES, SceneConfig
from opnet.synthesis.layout import Rig
from opnet.synthesis.physics.base import GRAVITY, BinSimulator, CycleStates, CycleStats


@dataclass(frozen=True)
class Engine:
    """A physics engine of the generator.

    Attributes:
        package: the module it needs installed (checked before its own module is imported).
        install: how to get that package, for the error message.
        load: imports the engine's module and returns its :class:`BinSimulator` subclass.
    """

    package: str
    install: str
    load: Callable[[], type[BinSimulator]]


def _mujoco() -> type[BinSimulator]:
    from opnet.synthesis.physics.mujoco_engine import MujocoSimulator

    return MujocoSimulator


def _pybullet() -> type[BinSimulator]:
    from opnet.synthesis.physics.pybullet_engine import PybulletSimulator

    return PybulletSimulator


#: name (``scene.physics``) -> engine; the names are :data:`opnet.synthesis.config.PHYSICS_ENGINES`
ENGINES: dict[str, Engine] = {
    "mujoco": Engine("mujoco", "pip install mujoco", _mujoco),
    "pybullet": Engine("pybullet", "pip install 'opnet[pybullet]' (CPython 3.11 wheels only), "
                                   "or use scene.physics=mujoco", _pybullet),
}


def make_simulator(rig: Rig, collision: CollisionModel, cfg: SceneConfig) -> BinSimulator:
    """The simulator of the engine ``cfg.physics`` names (a key of :data:`ENGINES`).

    Raises:
        MissingDependencyError: that engine's package is not installed.
        ValueError: no engine has that name.
    """
    engine = ENGINES.get(cfg.physics)
    if engine is None:
        raise ValueError(f"scene.physics={cfg.physics!r}: unknown physics engine; expected one of {PHYSICS_ENGINES}")
    require(engine.package, f"scene.physics={cfg.physics}", engine.install)
    return engine.load()(rig, collision, cfg)


__all__ = ["ENGINES", "GRAVITY", "BinSimulator", "CycleStates", "CycleStats", "Engine", "make_simulator"]
