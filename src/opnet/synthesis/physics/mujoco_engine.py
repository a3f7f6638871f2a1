"""The MuJoCo engine of :class:`~opnet.synthesis.physics.BinSimulator` (``scene.physics=mujoco``, the default).

One compiled model per number of drops: the ground plane, the bin (a static body whose pose is set
per cycle) and ``drops`` free bodies. A part not yet dropped is *parked*: its geoms collide with
nothing (contype = conaffinity = 0) and gravity is compensated (``gravcomp`` 1), so it rests where
it is and costs the solver nothing; a drop activates the next parked part. Every cycle starts from
``mj_resetData`` with all parts parked, so a cycle does not depend on what was simulated before;
redrops go back to a copy of (qpos, qvel, the solver's warm start, time). MuJoCo is deterministic
on one thread.

Choices, measured against pybullet on the same piles (``scripts/bench/bench_physics.py``):
- Body frame = the part's inertial frame (centre of mass, principal axes), with the mass and
  principal moments of :mod:`opnet.synthesis.collision` given exactly; the model frame is
  recovered in :meth:`MujocoSimulator.poses`. The convex parts of the decomposition (or the hull)
  are mesh geoms; MuJoCo collides their convex hulls, with several contacts per pair
  (``multiccd``) so that parts lying flat rest still.
- Damping: ``linear_damping`` / ``angular_damping`` c mean "loses the fraction c of its velocity per
  second" as in Bullet; they become joint damping of rate -ln(1 - c) times the mass (translation)
  and the principal moments (rotation), integrated implicitly (``implicitfast``).
- Contacts are MuJoCo's soft contacts with a time constant of two steps (the stiffest the step
  allows): in a settled 75-part bunny pile the contacts are 0.02 mm deep (median), 0.2 mm at most.
- Not used: rolling friction (``condim`` 6) made a ring-screw pile 43 % slower to simulate;
  MuJoCo's sleeping islands would save the time of buried parts but need waking rules this code
  does not have yet.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from opnet.geometry.rotations import matrix_to_quaternion, quaternion_to_matrix
from opnet.synthesis.collision import CollisionModel, convex_parts
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.layout import CycleLayout, Rig
from opnet.synthesis.physics.base import GRAVITY, BinSimulator

#: where parked parts wait (metres below the ground, one metre apart): far from everything
_PARK_DEPTH = 10.0


def _floats(values: np.ndarray) -> str:
    return " ".join(f"{float(v):.10g}" for v in np.ravel(values))


def _wxyz(R: np.ndarray) -> np.ndarray:
    return np.asarray(matrix_to_quaternion(np.asarray(R, dtype=np.float64)), dtype=np.float64)


def _clutter_geoms(pieces: tuple) -> str:
    """MuJoCo geoms of the foreign pieces on the floor (:mod:`opnet.synthesis.clutter`), in the bin
    body (its frame is the bin frame)."""
    out = []
    for p in pieces:
        disc = p.shape == "disc"
        size = _floats([p.half[0], p.half[2]] if disc else p.half)
        out.append(f'<geom type="{"cylinder" if disc else "box"}" size="{size}" pos="{_floats(p.T_bin_piece[:3, 3])}" '
                   f'quat="{_floats(_wxyz(p.T_bin_piece[:3, :3]))}"/>')
    return "".join(out)


def damping_rate(fraction_per_second: float) -> float:
    """Bullet's damping c (velocity times (1 - c) per second) as a continuous rate, 1/s."""
    return -math.log(max(1.0 - float(fraction_per_second), 1e-9))


class MujocoSimulator(BinSimulator):
    """:class:`BinSimulator` on MuJoCo (see the module docstring)."""

    def __init__(self, rig: Rig, collision: CollisionModel, cfg: SceneConfig) -> None:
        super().__init__(rig, collision, cfg)
        if collision.mode == "vhacd" and collision.obj_file is not None:
            parts = convex_parts(collision.obj_file)
        else:
            parts = [collision.vertices]
        # hull vertices in the body (inertial) frame
        to_inertial = self._T_inertial_model
        self._parts = [p @ to_inertial[:3, :3].T + to_inertial[:3, 3] for p in parts]
        self._points = np.concatenate(self._parts)
        self._models: dict[int, mujoco.MjModel] = {}
        self.model: mujoco.MjModel | None = None
        self.data: mujoco.MjData | None = None
        self._active = 0

    def close(self) -> None:
        self._models.clear()
        self.model = self.data = None

    # ---- the model -----------------------------------------------------------------------------
    def _xml(self, drops: int, clutter: tuple = ()) -> str:
        cfg, col, b = self.cfg, self.collision, self.rig.bin
        meshes = "".join(f'<mesh name="part{k}" vertex="{_floats(p)}"/>' for k, p in enumerate(self._parts))
        boxes = "".join(f'<geom type="box" size="{_floats(half)}" pos="{_floats(centre)}"/>' for half, centre in b.boxes())
        geoms = "".join(f'<geom type="mesh" mesh="part{k}" contype="0" conaffinity="0"/>' for k in range(len(self._parts)))
        inertial = f'<inertial pos="0 0 0" mass="{col.mass:.10g}" diaginertia="{_floats(col.inertia)}"/>'
        bodies = "".join(
            f'<body name="p{i}" pos="{_floats(self._parked(i)[:3])}" gravcomp="1"><freejoint/>{inertial}{geoms}</body>'
            for i in range(drops)
        )
        dt = cfg.time_step
        return (
            '<mujoco model="bin"><compiler angle="radian" boundmass="1e-9" boundinertia="1e-12"/>'
            f'<option timestep="{dt:.10g}" gravity="0 0 {-GRAVITY}" integrator="implicitfast" '
            f'iterations="{max(int(cfg.solver_iterations), 1)}" ls_iterations="10"><flag multiccd="enable"/></option>'
            f'<default><geom friction="{cfg.friction:.10g} {cfg.rolling_friction:.10g} {cfg.rolling_friction:.10g}" '
            f'condim="3" solref="{2.0 * dt:.10g} 1"/></default>'
            f"<asset>{meshes}</asset>"
            f'<worldbody><geom name="ground" type="plane" size="0 0 1" pos="0 0 {-b.thickness:.10g}"/>'
            f'<body name="bin">{boxes}{_clutter_geoms(clutter)}</body>{bodies}</worldbody></mujoco>'
        )

    def _parked(self, i: int) -> np.ndarray:
        return np.array([float(i), 0.0, -_PARK_DEPTH, 1.0, 0.0, 0.0, 0.0])

    def _compile(self, drops: int, clutter: tuple = ()) -> mujoco.MjModel:
        """The model of ``drops`` parts (cached) or, with foreign pieces on the floor, of this pile."""
        if clutter or drops not in self._models:
            model = mujoco.MjModel.from_xml_string(self._xml(drops, clutter))
            cfg, col = self.cfg, self.collision
            lin, ang = damping_rate(cfg.linear_damping), damping_rate(cfg.angular_damping)
            for dof in self._addresses(model, drops)[1]:
                model.dof_damping[dof:dof + 3] = lin * col.mass
                model.dof_damping[dof + 3:dof + 6] = ang * np.asarray(col.inertia)
            if clutter:
                return model
            self._models[drops] = model
        return self._models[drops]

    @staticmethod
    def _body_id(model: mujoco.MjModel, i: int) -> int:
        return 2 + i  # world 0, bin 1, then the parts in order

    @classmethod
    def _addresses(cls, model: mujoco.MjModel, drops: int) -> tuple[np.ndarray, np.ndarray]:
        """(qpos address, dof address) of each part's free joint."""
        joints = model.body_jntadr[[cls._body_id(model, i) for i in range(drops)]].astype(int)
        return model.jnt_qposadr[joints].astype(int), model.jnt_dofadr[joints].astype(int)

    def _make_world(self, layout: CycleLayout, drops: int) -> None:
        model = self._compile(drops, layout.clutter)
        T = layout.T_world_bin
        model.body_pos[1] = T[:3, 3]
        model.body_quat[1] = _wxyz(T[:3, :3])
        self.model = model
        self.data = mujoco.MjData(model)
        self._qpos, self._dof = self._addresses(model, drops)
        self._geoms = [np.flatnonzero(model.geom_bodyid == self._body_id(model, i)) for i in range(drops)]
        self._ground = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "ground")
        for body in range(drops):  # the cached model may hold the last cycle's active parts
            self._set_active(body, False)
        self._active = 0
        mujoco.mj_forward(model, self.data)

    def _set_active(self, body: int, on: bool) -> None:
        m = self.model
        g = self._geoms[body]
        b = self._body_id(m, body)
        m.geom_contype[g] = m.geom_conaffinity[g] = int(on)
        m.body_contype[b] = m.body_conaffinity[b] = int(on)  # the broad phase filters bodies first
        m.body_gravcomp[b] = 0.0 if on else 1.0

    # ---- bodies ----------------------------------------------------------------------------------
    def _new_body(self) -> int:
        body = self._active
        if body >= len(self._geoms):
            raise RuntimeError(f"more parts dropped than the {len(self._geoms)} the world was made for")
        self._active += 1
        self._set_active(body, True)
        return body

    def _remove_body(self, body: int) -> None:
        if body != self._active - 1:
            raise RuntimeError("only the last dropped part can be taken out again")
        self._active -= 1
        self._set_active(body, False)
        a = self._qpos[body]
        self.data.qpos[a:a + 7] = self._parked(body)
        d = self._dof[body]
        self.data.qvel[d:d + 6] = 0.0

    def set_pose(self, body: int, T_world_obj: np.ndarray) -> None:
        T = T_world_obj @ self._T_model_inertial
        a, d = self._qpos[body], self._dof[body]
        self.data.qpos[a:a + 3] = T[:3, 3]
        self.data.qpos[a + 3:a + 7] = _wxyz(T[:3, :3])
        self.data.qvel[d:d + 6] = 0.0

    def _inertial_poses(self, bodies: list[int]) -> tuple[np.ndarray, np.ndarray]:
        idx = self._qpos[np.asarray(bodies, dtype=int)]
        q = self.data.qpos
        pos = np.stack([q[a:a + 3] for a in idx]) if len(idx) else np.zeros((0, 3))
        quat = np.stack([q[a + 3:a + 7] for a in idx]) if len(idx) else np.zeros((0, 4))
        return pos, np.asarray(quaternion_to_matrix(quat), dtype=np.float64).reshape(-1, 3, 3)

    def poses(self, bodies: list[int]) -> np.ndarray:
        pos, R = self._inertial_poses(bodies)
        T = np.zeros((len(bodies), 4, 4))
        T[:, :3, :3], T[:, :3, 3], T[:, 3, 3] = R, pos, 1.0
        return T @ self._T_inertial_model

    def _coms(self, bodies: list[int]) -> np.ndarray:
        return self._inertial_poses(bodies)[0]

    def _aabbs(self, bodies: list[int]) -> list[tuple[np.ndarray, np.ndarray]]:
        pos, R = self._inertial_poses(bodies)
        out = []
        for t, r in zip(pos, R, strict=True):
            world = self._points @ r.T + t
            out.append((world.min(0), world.max(0)))
        return out

    def _touches(self, body: int, bodies: list[int]) -> bool:
        m, d = self.model, self.data
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        mine = set(self._geoms[body].tolist())
        for c in d.contact[: d.ncon]:
            g1, g2 = int(c.geom1), int(c.geom2)
            if (g1 in mine) != (g2 in mine) and self._ground not in (g1, g2) and c.dist <= 0.0:
                return True  # parked parts collide with nothing, so the other geom is the bin or a part
        return False

    # ---- time ------------------------------------------------------------------------------------
    def _step(self) -> None:
        mujoco.mj_step(self.model, self.data)

    def _max_speeds_sq(self, bodies: list[int]) -> tuple[float, float]:
        if not bodies:
            return 0.0, 0.0
        v = np.stack([self.data.qvel[d:d + 6] for d in self._dof[np.asarray(bodies, dtype=int)]])
        return float((v[:, :3] ** 2).sum(1).max()), float((v[:, 3:] ** 2).sum(1).max())

    def _save(self) -> tuple[np.ndarray, ...]:
        d = self.data
        return d.qpos.copy(), d.qvel.copy(), d.qacc_warmstart.copy(), np.array(d.time)

    def _restore(self, state: object) -> None:
        d = self.data
        qpos, qvel, warm, time = state  # type: ignore[misc]
        d.qpos[:], d.qvel[:], d.qacc_warmstart[:] = qpos, qvel, warm
        d.time = float(time)
