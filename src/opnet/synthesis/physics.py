"""Rigid-body drops into the bin with pybullet (DIRECT mode, one client per simulator).

Parts are maximal-coordinate rigid bodies (``useMaximalCoordinates``: 2-3x faster than pybullet's
default multibodies for piles of single-link parts); pybullet reports their inertial (centre of
mass, principal axes) frame, which :meth:`BinSimulator.poses` converts back to the model frame.
Defaults (120 Hz, 10 solver iterations, angular damping 0.5 so round parts stop rocking) settle a
20-part pile in about 60-90 steps per drop.

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
from dataclasses import dataclass, field
from typing import Self

import numpy as np

from opnet._stdio import quiet_c_output

with quiet_c_output():  # pybullet prints its build time on import, once per process
    import pybullet as pb

from opnet.geometry.rotations import matrix_to_quaternion
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


class _DropFailed(Exception):
    """A drop kept pushing parts out of the bin."""


def _xyzw(R: np.ndarray) -> list[float]:
    w, x, y, z = matrix_to_quaternion(np.asarray(R, dtype=np.float64))
    return [float(x), float(y), float(z), float(w)]


class BinSimulator:
    """Drops parts into a bin, one cycle at a time.

    Args:
        rig: the bin and camera set-up (only the bin and the part radius are used).
        collision: the part's collision shape and mass properties.
        cfg: physics settings.
    """

    def __init__(self, rig: Rig, collision: CollisionModel, cfg: SceneConfig) -> None:
        self.rig, self.collision, self.cfg = rig, collision, cfg
        self._client = pb.connect(pb.DIRECT)
        # link (model) frame -> inertial frame of a part; pybullet reports the inertial frame
        self._T_model_inertial = homogeneous(collision.R_model_inertial, collision.com)
        self._T_inertial_model = inverse_pose(self._T_model_inertial)

    def close(self) -> None:
        """Disconnect the pybullet client (idempotent)."""
        if self._client is not None and pb.isConnected(self._client):
            pb.disconnect(self._client)
        self._client = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- a cycle -----------------------------------------------------------------------------
    def simulate(self, layout: CycleLayout, drops: int, rng: np.random.Generator) -> CycleStates:
        """Drop ``drops`` parts into the bin placed at ``layout.T_world_bin``.

        Raises:
            RuntimeError: parts kept leaving the bin through every allowed restart (the bin is
                too small or the drop too violent for this part: enlarge ``bin_inner``).
        """
        stats = CycleStats()
        for restart in range(self.cfg.max_cycle_restarts + 1):
            stats.restarts = restart
            try:
                return CycleStates(self._simulate_once(layout, drops, rng, stats), stats)
            except _DropFailed:
                continue
        raise RuntimeError(
            f"parts kept leaving the bin after {self.cfg.max_redrops} re-drops in each of "
            f"{self.cfg.max_cycle_restarts + 1} attempts; enlarge the bin (scene.bin_inner, "
            f"now {self.rig.bin.inner:.3f} m) or raise the walls (scene.bin_wall_height)"
        )

    def _simulate_once(self, layout: CycleLayout, drops: int, rng: np.random.Generator, stats: CycleStats) -> list[np.ndarray]:
        self._build_world(layout)
        bodies: list[int] = []
        piles = [np.zeros((0, 4, 4))]
        for _ in range(drops):
            state = pb.saveState(physicsClientId=self._client)
            for _attempt in range(self.cfg.max_redrops):
                body = self._spawn(bodies, rng)
                settled, steps = self._settle([*bodies, body])
                stats.steps += steps
                if self._all_inside([*bodies, body]):
                    stats.unsettled += not settled
                    bodies.append(body)
                    break
                stats.redrops += 1
                pb.removeBody(body, physicsClientId=self._client)
                pb.restoreState(stateId=state, physicsClientId=self._client)
            else:
                pb.removeState(state, physicsClientId=self._client)
                raise _DropFailed
            pb.removeState(state, physicsClientId=self._client)
            piles.append(self.poses(bodies))
        return piles

    # ---- world -------------------------------------------------------------------------------
    def _build_world(self, layout: CycleLayout) -> None:
        c, cfg = self._client, self.cfg
        pb.resetSimulation(physicsClientId=c)
        pb.setPhysicsEngineParameter(
            fixedTimeStep=cfg.time_step, numSolverIterations=cfg.solver_iterations,
            deterministicOverlappingPairs=1, physicsClientId=c,
        )
        pb.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=c)
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=c)
        ground = [0.0, 0.0, -self.rig.bin.thickness]
        self._static = [pb.createMultiBody(0.0, plane, -1, ground, useMaximalCoordinates=True, physicsClientId=c)]
        for half, centre in self.rig.bin.boxes():
            T = layout.T_world_bin @ homogeneous(np.eye(3), centre)
            shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half.tolist(), physicsClientId=c)
            self._static.append(
                pb.createMultiBody(0.0, shape, -1, T[:3, 3].tolist(), _xyzw(T[:3, :3]), useMaximalCoordinates=True, physicsClientId=c)
            )
        for body in self._static:
            self._set_contact(body)
        self._T_world_bin = layout.T_world_bin
        col = self.collision
        if col.mode == "vhacd":
            self._shape = pb.createCollisionShape(pb.GEOM_MESH, fileName=str(col.obj_file), physicsClientId=c)
        else:
            self._shape = pb.createCollisionShape(pb.GEOM_MESH, vertices=col.vertices.tolist(), physicsClientId=c)

    def _set_contact(self, body: int) -> None:
        cfg = self.cfg
        pb.changeDynamics(
            body, -1, lateralFriction=cfg.friction, rollingFriction=cfg.rolling_friction,
            spinningFriction=cfg.rolling_friction, restitution=cfg.restitution, linearDamping=cfg.linear_damping,
            angularDamping=cfg.angular_damping, physicsClientId=self._client,
        )

    def _new_body(self) -> int:
        c, col = self._client, self.collision
        body = pb.createMultiBody(
            col.mass, self._shape, -1, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0],
            baseInertialFramePosition=col.com.tolist(),
            baseInertialFrameOrientation=_xyzw(col.R_model_inertial), useMaximalCoordinates=True, physicsClientId=c,
        )
        self._set_contact(body)
        return body

    # ---- poses -------------------------------------------------------------------------------
    def set_pose(self, body: int, T_world_obj: np.ndarray) -> None:
        """Place a part's model frame at ``T_world_obj`` (4, 4), at rest."""
        T = T_world_obj @ self._T_model_inertial
        pb.resetBasePositionAndOrientation(body, T[:3, 3].tolist(), _xyzw(T[:3, :3]), physicsClientId=self._client)
        pb.resetBaseVelocity(body, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=self._client)

    def poses(self, bodies: list[int]) -> np.ndarray:
        """(N, 4, 4) float64 model-to-world poses of ``bodies``, metres."""
        out = np.zeros((len(bodies), 4, 4))
        for i, body in enumerate(bodies):
            pos, quat = pb.getBasePositionAndOrientation(body, physicsClientId=self._client)
            R = np.asarray(pb.getMatrixFromQuaternion(quat), dtype=np.float64).reshape(3, 3)
            out[i] = homogeneous(R, np.asarray(pos)) @ self._T_inertial_model
        return out

    # ---- one drop ----------------------------------------------------------------------------
    def _spawn(self, bodies: list[int], rng: np.random.Generator) -> int:
        c, r = self._client, self.rig.object_radius
        boxes = [pb.getAABB(b, physicsClientId=c) for b in bodies]
        reach = max(self.rig.bin.inner / 2.0 - r, 0.0)
        body = self._new_body()
        others = self._static[1:] + bodies  # the ground plane is below the floor
        for attempt in range(_SPAWN_TRIES):
            x, y = rng.uniform(-reach, reach, 2)
            R = random_rotation(rng)
            xw, yw = (self._T_world_bin @ np.array([x, y, 0.0, 1.0]))[:2]
            # the pile top under the spawn column (parts elsewhere cannot be hit on the way down)
            top = max([0.0, *(hi[2] for lo, hi in boxes if lo[0] < xw + r and hi[0] > xw - r and lo[1] < yw + r and hi[1] > yw - r)])
            z = top + r + self.cfg.drop_gap + r * (attempt // 5)
            self.set_pose(body, self._T_world_bin @ homogeneous(R, np.array([x, y, z])))
            pb.performCollisionDetection(physicsClientId=c)
            if not any(pb.getClosestPoints(body, o, 0.0, physicsClientId=c) for o in others):
                return body
        return body  # keep the last, highest try: the solver separates a marginal overlap

    def _settle(self, bodies: list[int]) -> tuple[bool, int]:
        """Step until the pile rests or the time cap; returns (settled, steps taken)."""
        c, cfg = self._client, self.cfg
        fall = math.sqrt(2.0 * (cfg.drop_gap + 0.002) / GRAVITY)
        first_check = math.ceil(fall / cfg.time_step)
        cap = max(math.ceil(cfg.settle_time_cap / cfg.time_step), first_check + 1)
        calm = 0
        for step in range(1, cap + 1):
            pb.stepSimulation(physicsClientId=c)
            if step < first_check or step % cfg.check_every:
                continue
            lin, ang = 0.0, 0.0
            for b in bodies:
                v, w = pb.getBaseVelocity(b, physicsClientId=c)
                lin, ang = max(lin, v[0] ** 2 + v[1] ** 2 + v[2] ** 2), max(ang, w[0] ** 2 + w[1] ** 2 + w[2] ** 2)
            calm = calm + 1 if lin < cfg.settle_linear**2 and ang < cfg.settle_angular**2 else 0
            if calm >= cfg.settle_checks:
                return True, step
        return False, cap

    def _all_inside(self, bodies: list[int]) -> bool:
        com_world = np.array([pb.getBasePositionAndOrientation(b, physicsClientId=self._client)[0] for b in bodies])
        T_bin_world = inverse_pose(self._T_world_bin)
        com_bin = com_world @ T_bin_world[:3, :3].T + T_bin_world[:3, 3]
        return bool(self.rig.bin.inside(com_bin).all())
