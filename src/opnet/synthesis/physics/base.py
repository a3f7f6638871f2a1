"""Rigid-body drops into the bin: the rules of a cycle, independent of the physics engine.

:class:`BinSimulator` holds the rules below; an engine supplies a handful of primitives (make the
world, add / remove / place a body, step, read velocities and poses, save and restore the state).
The engines (:mod:`~opnet.synthesis.physics.mujoco_engine`,
:mod:`~opnet.synthesis.physics.pybullet_engine`) import this module and nothing else of the
package; :func:`~opnet.synthesis.physics.make_simulator` picks one by name.

Defaults (120 Hz, angular damping 0.5 so round parts stop rocking) settle a 20-part pile in about
60-90 steps per drop.

A cycle (IPA style): scene 0 is the empty bin; then parts are dropped one at a time and the pile
is recorded after each drop has settled.

Rules (values in :class:`SceneConfig`):
- Spawn: orientation uniform on SO(3); x, y uniform over the bin floor shrunk by the part's radius
  about its origin (so no wall can be hit); height such that the lowest possible point is
  ``drop_gap`` above the current pile top (highest body AABB). The spawn is checked against every
  body with ``getClosestPoints``; on contact it is resampled (and raised after a few failures).
- Settling: step until, at ``settle_checks`` consecutive checks (every ``check_every`` steps, after
  the free-fall time of ``drop_gap``), every part moves slower than ``settle_linear`` and
  ``settle_angular``; at ``settle_time_cap`` simulated seconds the pile is recorded anyway (counted
  in :attr:`CycleStats.unsettled`).
- Leaving the bin: if after a drop any part's centre of mass is outside the inner walls (or below
  the floor), the world is restored to its state before the drop and the drop is made again with
  fresh random numbers, up to ``max_redrops`` times; after that the whole cycle restarts with the
  random stream where it is, up to ``max_cycle_restarts`` times. So every recorded scene holds
  exactly as many parts as drops, all in the bin.
- Determinism: each cycle starts from ``resetSimulation`` with deterministic overlapping pairs,
  and every random number comes from the cycle's generator, so a cycle's result does not depend
  on what the client simulated before (any worker count, any order).
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Self

import numpy as np

from opnet.synthesis.collision import CollisionModel
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.layout import CycleLayout, Rig, homogeneous, inverse_pose, random_rotation

GRAVITY = 9.81
_SPAWN_TRIES = 20


@dataclass
class CycleStats:
    """Bookkeeping of one simulated cycle (for the generation report)."""

    redrops: int = 0
    unsettled: int = 0
    restarts: int = 0
    steps: int = 0


@dataclass
class CycleStates:
    """The piles of one cycle.

    Attributes:
        T_world_obj: ``T_world_obj[n]`` is the (n, 4, 4) float64 model-to-world poses of the parts
            after n drops (n = 0 .. drops), metres, in drop order.
        stats: what it took.
    """

    T_world_obj: list[np.ndarray]
    stats: CycleStats = field(default_factory=CycleStats)


class PileError(ValueError, RuntimeError):
    """The settings cannot make a pile of this part (a user error: one line naming what to change, not a
    traceback; a RuntimeError too, as it was)."""


class _DropFailed(Exception):
    """A drop kept pushing parts out of the bin."""


class BinSimulator(ABC):
    """Drops parts into a bin, one cycle at a time (the engine-independent rules).

    Make one with :func:`~opnet.synthesis.physics.make_simulator`. Bodies are integer handles of
    the engine.

    Args:
        rig: the bin and camera set-up (only the bin and the part radius are used).
        collision: the part's collision shape and mass properties.
        cfg: physics settings.
    """

    def __init__(self, rig: Rig, collision: CollisionModel, cfg: SceneConfig) -> None:
        self.rig, self.collision, self.cfg = rig, collision, cfg
        self._T_world_bin = np.eye(4)
        # model frame -> inertial frame (centre of mass, principal axes) of a part: the engines'
        # bodies live in the inertial frame
        self._T_model_inertial = homogeneous(collision.R_model_inertial, collision.com)
        self._T_inertial_model = inverse_pose(self._T_model_inertial)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- what an engine supplies -------------------------------------------------------------
    @abstractmethod
    def close(self) -> None:
        """Free the engine (idempotent)."""

    @abstractmethod
    def _make_world(self, layout: CycleLayout, drops: int) -> None:
        """An empty world: ground plane, the bin at ``layout.T_world_bin``, room for ``drops`` parts."""

    @abstractmethod
    def _new_body(self) -> int:
        """Add a part (placed later with :meth:`set_pose`); returns its handle."""

    @abstractmethod
    def _remove_body(self, body: int) -> None:
        """Take a part out of the world again."""

    @abstractmethod
    def set_pose(self, body: int, T_world_obj: np.ndarray) -> None:
        """Place a part's model frame at ``T_world_obj`` (4, 4), at rest."""

    @abstractmethod
    def poses(self, bodies: list[int]) -> np.ndarray:
        """(N, 4, 4) float64 model-to-world poses of ``bodies``, metres."""

    @abstractmethod
    def _aabbs(self, bodies: list[int]) -> list[tuple[np.ndarray, np.ndarray]]:
        """World axis-aligned boxes (low (3,), high (3,)) of ``bodies``."""

    @abstractmethod
    def _touches(self, body: int, bodies: list[int]) -> bool:
        """Whether ``body`` overlaps or touches the bin or any of ``bodies``."""

    @abstractmethod
    def _step(self) -> None:
        """One time step of ``cfg.time_step``."""

    @abstractmethod
    def _max_speeds_sq(self, bodies: list[int]) -> tuple[float, float]:
        """(max squared linear speed, max squared angular speed) over ``bodies``."""

    @abstractmethod
    def _coms(self, bodies: list[int]) -> np.ndarray:
        """(N, 3) centres of mass of ``bodies`` in the world, metres."""

    @abstractmethod
    def _save(self) -> object:
        """A snapshot of the world's dynamic state."""

    @abstractmethod
    def _restore(self, state: object) -> None:
        """Go back to ``state`` (bodies added since must have been removed)."""

    def _discard(self, state: object) -> None:
        """Forget ``state``."""

    # ---- a cycle -----------------------------------------------------------------------------
    def simulate(self, layout: CycleLayout, drops: int, rng: np.random.Generator) -> CycleStates:
        """Drop ``drops`` parts into the bin placed at ``layout.T_world_bin``.

        Raises:
            PileError: parts kept leaving the bin through every allowed restart (the bin is
                too small or the drop too violent for this part: enlarge ``bin_inner``).
        """
        stats = CycleStats()
        for restart in range(self.cfg.max_cycle_restarts + 1):
            stats.restarts = restart
            try:
                return CycleStates(self._simulate_once(layout, drops, rng, stats), stats)
            except _DropFailed:
                continue
        raise PileError(
            f"parts kept leaving the bin after {self.cfg.max_redrops} re-drops in each of "
            f"{self.cfg.max_cycle_restarts + 1} attempts; enlarge the bin (scene.bin_inner, "
            f"now {self.rig.bin.inner:.3f} m) or raise the walls (scene.bin_wall_height)"
        )

    def _simulate_once(self, layout: CycleLayout, drops: int, rng: np.random.Generator, stats: CycleStats) -> list[np.ndarray]:
        self._build_world(layout, drops)
        bodies: list[int] = []
        piles = [np.zeros((0, 4, 4))]
        for _ in range(drops):
            state = self._save()
            for _attempt in range(self.cfg.max_redrops):
                body = self._spawn(bodies, rng)
                settled, steps = self._settle([*bodies, body])
                stats.steps += steps
                if self._all_inside([*bodies, body]):
                    stats.unsettled += not settled
                    bodies.append(body)
                    break
                stats.redrops += 1
                self._remove_body(body)
                self._restore(state)
            else:
                self._discard(state)
                raise _DropFailed
            self._discard(state)
            piles.append(self.poses(bodies))
        return piles

    def _build_world(self, layout: CycleLayout, drops: int) -> None:
        self._T_world_bin = layout.T_world_bin
        # parts spawn above the foreign pieces on the floor as above the pile (opnet.synthesis.clutter)
        self._floor_top = max([0.0, *(2.0 * p.half[2] for p in layout.clutter)])
        self._make_world(layout, drops)

    # ---- one drop ----------------------------------------------------------------------------
    def _spawn(self, bodies: list[int], rng: np.random.Generator) -> int:
        r = self.rig.object_radius
        boxes = self._aabbs(bodies)
        reach = np.maximum(np.array(self.rig.bin.sides) / 2.0 - r, 0.0)
        body = self._new_body()
        for attempt in range(_SPAWN_TRIES):
            x, y = rng.uniform(-reach, reach)
            R = random_rotation(rng)
            xw, yw = (self._T_world_bin @ np.array([x, y, 0.0, 1.0]))[:2]
            # the pile top under the spawn column (parts elsewhere cannot be hit on the way down)
            top = max([self._floor_top, *(hi[2] for lo, hi in boxes if lo[0] < xw + r and hi[0] > xw - r and lo[1] < yw + r and hi[1] > yw - r)])
            z = top + r + self.cfg.drop_gap + r * (attempt // 5)
            self.set_pose(body, self._T_world_bin @ homogeneous(R, np.array([x, y, z])))
            if not self._touches(body, bodies):
                return body
        return body  # keep the last, highest try: the solver separates a marginal overlap

    def _settle(self, bodies: list[int]) -> tuple[bool, int]:
        """Step until the pile rests or the time cap; returns (settled, steps taken)."""
        cfg = self.cfg
        fall = math.sqrt(2.0 * (cfg.drop_gap + 0.002) / GRAVITY)
        first_check = math.ceil(fall / cfg.time_step)
        cap = max(math.ceil(cfg.settle_time_cap / cfg.time_step), first_check + 1)
        calm = 0
        for step in range(1, cap + 1):
            self._step()
            if step < first_check or step % cfg.check_every:
                continue
            lin, ang = self._max_speeds_sq(bodies)
            calm = calm + 1 if lin < cfg.settle_linear**2 and ang < cfg.settle_angular**2 else 0
            if calm >= cfg.settle_checks:
                return True, step
        return False, cap

    def _all_inside(self, bodies: list[int]) -> bool:
        com_world = self._coms(bodies)
        T_bin_world = inverse_pose(self._T_world_bin)
        com_bin = com_world @ T_bin_world[:3, :3].T + T_bin_world[:3, 3]
        return bool(self.rig.bin.inside(com_bin).all())
