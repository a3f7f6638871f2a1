"""The pybullet engine of :class:`~opnet.synthesis.physics.BinSimulator` (``scene.physics=pybullet``).

DIRECT mode, one client per simulator. Parts are maximal-coordinate rigid bodies
(``useMaximalCoordinates``: 2-3x faster than pybullet's default multibodies for piles of
single-link parts); pybullet reports their inertial (centre of mass, principal axes) frame, which
:meth:`PybulletSimulator.poses` converts back to the model frame. Each cycle starts from
``resetSimulation`` with deterministic overlapping pairs, so a cycle's result does not depend on
what the client simulated before. Redrops go back with ``saveState`` / ``restoreState``.
"""

from __future__ import annotations

import numpy as np

from opnet._stdio import quiet_c_output

with quiet_c_output():  # pybullet prints its build time on import, once per process
    import pybullet as pb

from opnet.geometry.rotations import matrix_to_quaternion
from opnet.synthesis.collision import CollisionModel
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.layout import CycleLayout, Rig, homogeneous
from opnet.synthesis.physics.base import GRAVITY, BinSimulator


def _xyzw(R: np.ndarray) -> list[float]:
    w, x, y, z = matrix_to_quaternion(np.asarray(R, dtype=np.float64))
    return [float(x), float(y), float(z), float(w)]


class PybulletSimulator(BinSimulator):
    """:class:`BinSimulator` on pybullet (see the module docstring)."""

    def __init__(self, rig: Rig, collision: CollisionModel, cfg: SceneConfig) -> None:
        super().__init__(rig, collision, cfg)
        self._client = pb.connect(pb.DIRECT)  # pybullet reports the inertial frame of a body
        self._static: list[int] = []

    def close(self) -> None:
        if self._client is not None and pb.isConnected(self._client):
            pb.disconnect(self._client)
        self._client = None

    def _make_world(self, layout: CycleLayout, drops: int) -> None:
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

    def _remove_body(self, body: int) -> None:
        pb.removeBody(body, physicsClientId=self._client)

    def set_pose(self, body: int, T_world_obj: np.ndarray) -> None:
        T = T_world_obj @ self._T_model_inertial
        pb.resetBasePositionAndOrientation(body, T[:3, 3].tolist(), _xyzw(T[:3, :3]), physicsClientId=self._client)
        pb.resetBaseVelocity(body, [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=self._client)

    def poses(self, bodies: list[int]) -> np.ndarray:
        out = np.zeros((len(bodies), 4, 4))
        for i, body in enumerate(bodies):
            pos, quat = pb.getBasePositionAndOrientation(body, physicsClientId=self._client)
            R = np.asarray(pb.getMatrixFromQuaternion(quat), dtype=np.float64).reshape(3, 3)
            out[i] = homogeneous(R, np.asarray(pos)) @ self._T_inertial_model
        return out

    def _aabbs(self, bodies: list[int]) -> list[tuple[np.ndarray, np.ndarray]]:
        return [tuple(np.asarray(v) for v in pb.getAABB(b, physicsClientId=self._client)) for b in bodies]

    def _touches(self, body: int, bodies: list[int]) -> bool:
        c = self._client
        pb.performCollisionDetection(physicsClientId=c)
        others = self._static[1:] + bodies  # the ground plane is below the floor
        return any(pb.getClosestPoints(body, o, 0.0, physicsClientId=c) for o in others)

    def _step(self) -> None:
        pb.stepSimulation(physicsClientId=self._client)

    def _max_speeds_sq(self, bodies: list[int]) -> tuple[float, float]:
        lin, ang = 0.0, 0.0
        for b in bodies:
            v, w = pb.getBaseVelocity(b, physicsClientId=self._client)
            lin, ang = max(lin, v[0] ** 2 + v[1] ** 2 + v[2] ** 2), max(ang, w[0] ** 2 + w[1] ** 2 + w[2] ** 2)
        return lin, ang

    def _coms(self, bodies: list[int]) -> np.ndarray:
        return np.array([pb.getBasePositionAndOrientation(b, physicsClientId=self._client)[0] for b in bodies]).reshape(-1, 3)

    def _save(self) -> int:
        return pb.saveState(physicsClientId=self._client)

    def _restore(self, state: object) -> None:
        pb.restoreState(stateId=state, physicsClientId=self._client)

    def _discard(self, state: object) -> None:
        pb.removeState(state, physicsClientId=self._client)
