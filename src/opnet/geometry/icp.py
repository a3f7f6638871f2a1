"""Point-to-plane ICP: refine pose hypotheses against the depth image.

Numpy and scipy only, so that training's evaluation, ``predict.py`` and the torch-free ONNX
runtime (:mod:`opnet.deploy`) share it. Why not Open3D, the field's usual choice: its wheel is
several hundred MB with its own OpenGL stack, and one hypothesis needs only a few hundred model
points against a k-d tree of the scene points near it; this module does that and no more.

Per hypothesis (:func:`refine_pose`):

1. the scene: the camera-frame points of the depth image within ``radius`` (× the object's
   diameter) of the hypothesis's origin, with normals from the depth grid (cross product of the
   neighbouring pixels' differences); fewer than ``min_points`` -> status ``no_depth``, pose kept;
2. the model: points sampled evenly on the mesh surface with their normals (:class:`ModelCloud`,
   made once per object); each iteration uses those facing the camera at the current pose;
3. correspondences: the nearest scene point within ``max_distance`` (× diameter) of each model
   point; a Huber weight (``huber`` × diameter) on the point-to-plane residual;
4. the step: the damped Gauss-Newton solution of the linearised point-to-plane residuals
   ``(R_δ p + t_δ - q) · n_q`` for a small rotation ``ω`` and translation ``v``, plus a fiftieth of
   the point-to-point term (it holds a flat part from sliding along its plane); the damping keeps
   the directions the surface does not constrain (a revolution object's spin) where they are; a
   step turns at most 5° and is halved until it lowers the cost (none does: converged);
5. the guard, what makes it symmetry-aware: the refined pose must stay within ``max_rotation_deg``
   (the symmetry-aware angle: a step onto an equivalent twin costs nothing, a step onto a
   look-alike pose that is *not* a symmetric twin is large) and ``max_translation`` (× diameter) of
   the hypothesis, and its mean residual must not grow; otherwise status ``rejected``, pose kept.

:func:`refine_hypotheses` refines an image's hypotheses best score first within a time budget
(``budget_ms``; the rest keep their pose, status ``budget``). With ``search`` settings
(``refine=search``) each refined hypothesis then goes through the depth-agreement search of
:mod:`opnet.geometry.search` (turns and shifts ICP cannot tell apart on a flat part), is polished
by ICP again and scored by its agreement; duplicates the searches made are dropped.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from scipy.spatial import cKDTree

from opnet.geometry.pose_numpy import pose_distance, rotation_change_deg
from opnet.geometry.search import (
    SearchSettings,
    ambiguity_turns,
    facing_points,
    model_axis,
    resolve_mode,
    rodrigues,
    score_poses,
    search_any_many,
    search_poses,
    skew,
    turns,
)

#: how ICP pairs a model point with the scene: its nearest scene point (a k-d tree per hypothesis) | the
#: scene point of the pixel it projects onto (every hypothesis in one batch, several times faster)
ASSOCIATIONS = ("nearest", "projective")
#: the most threads an image's refinement may take
MAX_THREADS = 64
STATUSES = ("refined", "searched", "suppressed", "no_depth", "rejected", "budget")


@dataclass(frozen=True)
class ICPSettings:
    """ICP settings; lengths in units of the object's diameter.

    Attributes:
        iterations: Gauss-Newton steps at most.
        radius: scene points within this distance of the hypothesis's origin are used.
        max_distance: correspondences farther apart are dropped.
        huber: the Huber threshold of the point-to-plane residual.
        min_points: fewer scene points (or correspondences) than this: the pose is kept.
        max_rotation_deg: a refinement that turns the pose by more (symmetry-aware) is rejected.
        max_translation: a refinement that moves the origin by more is rejected.
        budget_ms: time for all hypotheses of one image (None: no limit).
        model_points: points sampled on the mesh surface.
        stride: use every stride-th pixel of the depth image in each direction.
        local_points: at most about this many of the scene points near a hypothesis are fitted (every k-th
            of them; 0: all): on a megapixel frame the neighbourhood of a part holds tens of thousands.
        association: nearest (each model point's nearest scene point near the hypothesis) | projective
            (the scene point of the pixel it projects onto: every hypothesis in one batch; no pull
            along a surface, so a flat part's in-plane fit is left to the search).
        polish_association: the association of the ICP that polishes the search's poses (null: ``association``).
        converged: a pose stops when its step turns less than ``converged[0]`` radians and moves less than
            ``converged[1]`` metres (default a hundredth of a degree and of a millimetre, far below what the
            metric or a gripper can tell).
        min_gain: nearest-point ICP also stops when a step lowers the cost by less than this share of it (0:
            only by ``converged`` or when no step lowers it).
        threads: an image's hypotheses are refined in this many threads when there is no time budget (each
            thread a share of them, in batches; numpy's loops and the k-d tree release the interpreter): 2 keeps
            both cores of a 2-core CPU busy, 1 refines in the calling thread. Results do not depend on it.
        search: None (ICP only), or the depth-agreement search (:mod:`opnet.geometry.search`) run
            after ICP on each hypothesis within the budget, its best pose polished by ICP again.
    """

    iterations: int = 20
    radius: float = 0.75
    max_distance: float = 0.1
    huber: float = 0.01
    min_points: int = 30
    max_rotation_deg: float = 20.0
    max_translation: float = 0.2
    budget_ms: float | None = 100.0
    model_points: int = 600
    stride: int = 1
    local_points: int = 0
    association: str = "nearest"
    polish_association: str | None = None
    converged: tuple[float, float] = (1e-4, 1e-5)
    min_gain: float = 1e-3
    threads: int = 2
    search: SearchSettings | None = None

    def __post_init__(self) -> None:
        positive = {"radius": self.radius, "max_distance": self.max_distance, "huber": self.huber,
                    "max_rotation_deg": self.max_rotation_deg, "max_translation": self.max_translation}  # fmt: skip
        for key, value in positive.items():
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise ValueError(f"icp.{key} must be a positive number, got {value!r}")
        for key in ("iterations", "min_points", "model_points", "stride", "threads"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"icp.{key} must be a positive integer, got {value!r}")
        if self.threads > MAX_THREADS:
            raise ValueError(f"icp.threads must be at most {MAX_THREADS}, got {self.threads!r}")
        if isinstance(self.local_points, bool) or not isinstance(self.local_points, int) or self.local_points < 0:
            raise ValueError(f"icp.local_points must be an integer >= 0 (0: all), got {self.local_points!r}")
        converged = self.converged
        if isinstance(converged, str | bytes) or not hasattr(converged, "__len__") or len(converged) != 2 or not all(
                isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v) and v > 0 for v in converged):
            raise ValueError(f"icp.converged must be two positive numbers [radians, metres], got {converged!r}")
        object.__setattr__(self, "converged", (float(converged[0]), float(converged[1])))
        if isinstance(self.min_gain, bool) or not isinstance(self.min_gain, int | float) or not 0 <= self.min_gain < 1:
            raise ValueError(f"icp.min_gain must be a number in [0, 1), got {self.min_gain!r}")
        for key in ("association", "polish_association"):
            value = getattr(self, key)
            if not (value in ASSOCIATIONS or (key == "polish_association" and value is None)):
                raise ValueError(f"icp.{key} must be one of {', '.join(ASSOCIATIONS)}"
                                 f"{' or null' if key == 'polish_association' else ''}, got {value!r}")
        if self.budget_ms is not None and not (np.isfinite(self.budget_ms) and self.budget_ms >= 0):
            raise ValueError(f"icp.budget_ms must be >= 0 or null, got {self.budget_ms!r}")

    @classmethod
    def from_config(cls, cfg: Any) -> ICPSettings:
        """From a mapping (a config group); unknown keys are an error naming them."""
        cfg = dict(cfg or {})
        unknown = set(cfg) - set(cls.__dataclass_fields__) | ({"search"} & set(cfg))
        if unknown:
            raise ValueError(f"icp: unknown keys {sorted(unknown)}; expected "
                             f"{', '.join(k for k in cls.__dataclass_fields__ if k != 'search')}")
        return cls(**cfg)


@dataclass(frozen=True)
class ModelCloud:
    """Points (P, 3) and outward unit normals (P, 3) on the mesh surface, model frame, metres."""

    points: np.ndarray
    normals: np.ndarray
    diameter: float

    @classmethod
    def from_mesh(cls, mesh: Any, count: int, diameter: float, seed: int = 0) -> ModelCloud:
        """``count`` points spread evenly over the surface of a trimesh (deterministic for a seed)."""
        import trimesh

        points, faces = trimesh.sample.sample_surface_even(mesh, count, seed=seed)
        if len(points) < count:  # even sampling can return fewer: top up uniformly
            extra, extra_faces = trimesh.sample.sample_surface(mesh, count - len(points), seed=seed + 1)
            points, faces = np.vstack((points, extra)), np.concatenate((faces, extra_faces))
        return cls(np.asarray(points, np.float64), np.asarray(mesh.face_normals[faces], np.float64), float(diameter))

    def posed(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The points at the pose (R, t) in the camera frame (P, 3), and which face the camera (P,)."""
        p = self.points @ R.T + t
        return p, np.sum((self.normals @ R.T) * p, -1) < 0


class _Grid(NamedTuple):
    """The strided pixel grid a :class:`SceneCloud` was made from: points and normals per pixel (NaN where
    none), which pixels have both, the pixels' image coordinates and the camera."""

    xyz: np.ndarray  # (h, w, 3)
    normals: np.ndarray  # (h, w, 3)
    ok: np.ndarray  # (h, w)
    u: np.ndarray  # (w,) image columns of the grid
    v: np.ndarray  # (h,) image rows
    fx: float
    fy: float
    cx: float
    cy: float
    stride: int


class SceneCloud:
    """The depth image as camera-frame points (N, 3) with unit normals (N, 3).

    Made from a depth image (:meth:`from_depth`), it keeps the strided pixel grid, and
    :meth:`neighbourhood` takes the points near a hypothesis from the pixels the ball projects onto:
    no k-d tree over the whole image (on a megapixel frame building one costs more than refining a
    hypothesis). ``tree``, a k-d tree over all the points, is made when first asked for.
    """

    def __init__(self, points: np.ndarray, normals: np.ndarray, grid: _Grid | None = None) -> None:
        self.points, self.normals = points, normals
        self._grid = grid
        self._tree: cKDTree | None = None

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self.points if len(self.points) else np.full((1, 3), 1e9))  # empty: one far point
        return self._tree

    @classmethod
    def from_depth(cls, depth: np.ndarray, fx: float, fy: float, cx: float, cy: float, stride: int = 1) -> SceneCloud:
        """From a z-depth image (H, W) in metres (NaN or <= 0: missing) and its intrinsics."""
        depth = np.asarray(depth, np.float64)
        if depth.ndim != 2:
            raise ValueError(f"icp: depth must be an (H, W) image, got shape {depth.shape}")
        # the strided grid first: its points, and normals from its own neighbours
        u = np.arange(0, depth.shape[1], stride, dtype=np.float64)
        v = np.arange(0, depth.shape[0], stride, dtype=np.float64)
        d = depth[::stride, ::stride]
        z = np.where(np.isfinite(d) & (d > 0), d, np.nan)
        xyz = np.stack((z * ((u - cx) / fx), z * ((v - cy) / fy)[:, None], z), -1)
        # normals from the neighbouring pixels (central differences; the border has none)
        n = np.full_like(xyz, np.nan)
        if xyz.shape[0] > 2 and xyz.shape[1] > 2:
            a = xyz[1:-1, 2:] - xyz[1:-1, :-2]  # along u
            b = xyz[2:, 1:-1] - xyz[:-2, 1:-1]  # along v
            c = n[1:-1, 1:-1]
            c[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
            c[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
            c[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
            norm = np.sqrt(np.sum(c * c, -1, keepdims=True))
            c /= np.where(norm > 0, norm, np.nan)
            c *= np.where(np.sum(c * xyz[1:-1, 1:-1], -1, keepdims=True) > 0, -1.0, 1.0)  # facing the camera
        ok = np.isfinite(n).all(-1)  # a finite normal needs the point and both neighbours each way
        return cls(xyz[ok], n[ok], _Grid(xyz, n, ok, u, v, fx, fy, cx, cy, stride))

    def neighbourhood(self, centre: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """The points within ``radius`` metres of ``centre`` (3,) and their normals, in pixel order."""
        if self._grid is None:
            idx = np.sort(np.asarray(self.tree.query_ball_point(centre, radius), dtype=np.int64))
            return self.points[idx], self.normals[idx]
        g = self._grid
        x, y, z = (float(c) for c in centre)
        rows, cols = slice(None), slice(None)
        if z - radius > 1e-9:  # the ball lies in front of the camera: its pixels lie in the box of its corners
            depths = (z - radius, z + radius)
            us = [g.fx * xx / zz + g.cx for xx in (x - radius, x + radius) for zz in depths]
            vs = [g.fy * yy / zz + g.cy for yy in (y - radius, y + radius) for zz in depths]
            cols = slice(*np.searchsorted(g.u, [min(us) - 1, max(us) + 1]))
            rows = slice(*np.searchsorted(g.v, [min(vs) - 1, max(vs) + 1]))
        window = g.xyz[rows, cols]
        inside = g.ok[rows, cols] & (np.sum((window - centre) ** 2, -1) <= radius * radius)
        return window[inside], g.normals[rows, cols][inside]


@dataclass(frozen=True)
class ICPResult:
    """A refined pose: R (3, 3), t (3,), status (one of :data:`STATUSES`), correspondences used,
    the robust fit cost before and after (metres, :func:`_cost`; NaN when not refined)."""

    R: np.ndarray
    t: np.ndarray
    status: str
    correspondences: int = 0
    residual_before: float = float("nan")
    residual_after: float = float("nan")


def _rotation(w: np.ndarray) -> np.ndarray:
    """exp of the rotation vector ``w`` (Rodrigues)."""
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return np.eye(3) + skew(w)
    return turns(w / angle, np.array([angle]))[0]


def _residuals(R: np.ndarray, t: np.ndarray, model: ModelCloud, local: tuple[cKDTree, np.ndarray, np.ndarray],
               max_distance: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Correspondences of the model points facing the camera with the scene points near the
    hypothesis (``local``: their tree, points, normals): (p (K, 3), q (K, 3), n_q (K, 3))."""
    tree, points, normals = local
    p, facing = model.posed(R, t)
    p = p[facing]
    if not len(p):
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3))
    dist, nearest = tree.query(p, distance_upper_bound=max_distance)
    ok = np.isfinite(dist)
    return p[ok], points[nearest[ok]], normals[nearest[ok]]


#: weight of the point-to-point term beside the point-to-plane one: it holds the directions a
#: flat or thin part's surface does not (sliding along a plate)
POINT_WEIGHT = 0.02
#: the largest rotation of one step (radians); a step that raises the cost is halved
MAX_STEP_RAD = np.radians(5.0)


def _weights(p: np.ndarray, q: np.ndarray, n: np.ndarray, huber: float) -> tuple[np.ndarray, np.ndarray]:
    r = np.sum((p - q) * n, -1)
    return r, np.where(np.abs(r) <= huber, 1.0, huber / np.maximum(np.abs(r), 1e-15))


def _cost(p: np.ndarray, q: np.ndarray, n: np.ndarray, huber: float) -> float:
    """Mean robust cost per correspondence: point-to-plane (Huber) + POINT_WEIGHT × point-to-point
    (metres; what a step must lower)."""
    r, w = _weights(p, q, n, huber)
    plane = np.where(w == 1.0, 0.5 * r**2, huber * (np.abs(r) - 0.5 * huber))
    return float(np.sqrt(2 * np.mean(plane + 0.5 * POINT_WEIGHT * np.sum((p - q) ** 2, -1))))


def _step(p: np.ndarray, q: np.ndarray, n: np.ndarray, huber: float) -> np.ndarray:
    """The damped Gauss-Newton step [ω, v] (6,) of the combined cost, at most MAX_STEP_RAD turned."""
    r, w = _weights(p, q, n, huber)
    J = np.hstack((np.cross(p, n), n))  # (K, 6): d r / d [ω, v]
    A = (J * w[:, None]).T @ J
    b = -(J * w[:, None]).T @ r
    # point-to-point: e = p - q, d e / d ω = -[p]x, d e / d v = I
    px, py, pz = p[:, 0], p[:, 1], p[:, 2]
    e = p - q
    # sum over points of [-[p]x, I]^T [-[p]x, I] and of [-[p]x, I]^T e, in closed form
    S = np.zeros((6, 6))
    S[:3, :3] = np.array([[np.sum(py**2 + pz**2), -np.sum(px * py), -np.sum(px * pz)],
                          [-np.sum(px * py), np.sum(px**2 + pz**2), -np.sum(py * pz)],
                          [-np.sum(px * pz), -np.sum(py * pz), np.sum(px**2 + py**2)]])  # fmt: skip
    cross_sum = skew(p.sum(0))  # -[p]x^T = [p]x
    S[:3, 3:] = cross_sum
    S[3:, :3] = cross_sum.T
    S[3:, 3:] = len(p) * np.eye(3)
    g = np.concatenate((np.cross(p, e).sum(0), e.sum(0)))
    A = A + POINT_WEIGHT * S
    b = b - POINT_WEIGHT * g
    A += 1e-6 * np.trace(A) / 6 * np.eye(6)  # damping: unconstrained directions stay put
    x = np.linalg.solve(A, b)
    angle = np.linalg.norm(x[:3])
    return x * (MAX_STEP_RAD / angle) if angle > MAX_STEP_RAD else x


def refine_pose(R: np.ndarray, t: np.ndarray, model: ModelCloud, scene: SceneCloud, space: Any,
                settings: ICPSettings = ICPSettings()) -> ICPResult:  # fmt: skip
    """Refine one pose (R (3, 3), t (3,) metres, camera frame) against ``scene`` (module docstring).

    Args:
        space: the object's pose space (``group``, ``revolution``): the guard's symmetry.
    """
    R0, t0 = np.asarray(R, np.float64), np.asarray(t, np.float64)
    D = model.diameter
    points, normals = scene.neighbourhood(t0, settings.radius * D)
    if len(points) < settings.min_points:
        return ICPResult(R0, t0, "no_depth", len(points))
    if settings.local_points and len(points) > settings.local_points:  # every k-th: a small tree, the same surface
        every = -(-len(points) // settings.local_points)
        points, normals = points[::every], normals[::every]
    # exact nearest points either way; a flat tree of larger leaves builds and answers several times faster here
    local = (cKDTree(points, leafsize=32, balanced_tree=False, compact_nodes=False), points, normals)
    max_d, huber = settings.max_distance * D, settings.huber * D
    Rc, tc = R0.copy(), t0.copy()
    p, q, n = _residuals(Rc, tc, model, local, max_d)
    if len(p) < settings.min_points:
        return ICPResult(R0, t0, "no_depth", len(p))
    before = cost = _cost(p, q, n, huber)
    for _ in range(settings.iterations):
        x = _step(p, q, n, huber)
        for _halving in range(4):  # a step that raises the cost is halved (Levenberg-style safety)
            dR = _rotation(x[:3])
            R_new, t_new = dR @ Rc, dR @ tc + x[3:]
            p_new, q_new, n_new = _residuals(R_new, t_new, model, local, max_d)
            if len(p_new) >= settings.min_points and (new_cost := _cost(p_new, q_new, n_new, huber)) <= cost:
                break
            x = x / 2
        else:
            break  # no step lowers the cost: converged (or stuck)
        gained = cost - new_cost
        Rc, tc, p, q, n, cost = R_new, t_new, p_new, q_new, n_new, new_cost
        if np.linalg.norm(x[:3]) < settings.converged[0] and np.linalg.norm(x[3:]) < settings.converged[1]:
            break
        if gained < settings.min_gain * (cost + gained):  # the cost has stopped falling
            break
    after = cost
    U, _, Vt = np.linalg.svd(Rc)  # re-orthonormalize
    Rc = U @ Vt
    moved = np.linalg.norm(tc - t0) > settings.max_translation * D
    turned = rotation_change_deg(R0, Rc, space) > settings.max_rotation_deg
    if moved or turned:
        return ICPResult(R0, t0, "rejected", len(p), before, after)
    return ICPResult(Rc, tc, "refined", len(p), before, after)


#: how far apart (metres) the hypotheses' scene neighbourhoods are laid in the one k-d tree of
#: :func:`refine_poses_nearest`: a nearest point never comes from another hypothesis's neighbourhood
APART_M = 1000.0


def _neighbourhoods(t: np.ndarray, scene: SceneCloud, settings: ICPSettings, diameter: float,
                    ) -> tuple[cKDTree, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The scene points near each hypothesis origin ``t`` (H, 3) as :func:`refine_pose` takes them (within
    ``radius``, every k-th past ``local_points``), laid :data:`APART_M` apart along x in one k-d tree: (tree,
    points (M, 3), normals (M, 3), count per hypothesis (H,))."""
    points, normals, counts = [], [], np.zeros(len(t), np.intp)
    for h, centre in enumerate(t):
        pts, nrm = scene.neighbourhood(centre, settings.radius * diameter)
        if settings.local_points and len(pts) > settings.local_points:
            every = -(-len(pts) // settings.local_points)
            pts, nrm = pts[::every], nrm[::every]
        counts[h] = len(pts)
        points.append(pts + np.array([APART_M * h, 0.0, 0.0]))
        normals.append(nrm)
    allp = np.concatenate(points) if points else np.zeros((0, 3))
    alln = np.concatenate(normals) if normals else np.zeros((0, 3))
    tree = cKDTree(allp if len(allp) else np.full((1, 3), -1e9), leafsize=32, balanced_tree=False, compact_nodes=False)
    return tree, allp, alln, counts


def refine_poses_nearest(R: np.ndarray, t: np.ndarray, model: ModelCloud, scene: SceneCloud, space: Any,
                         settings: ICPSettings = ICPSettings(), workers: int = -1) -> list[ICPResult]:  # fmt: skip
    """:func:`refine_pose` of many poses (H, 3, 3), (H, 3) at once: the same nearest points (each hypothesis's
    own neighbourhood, all in one k-d tree), cost, step, halving, stopping rules and guard, every hypothesis's
    step computed and tried in one batch (a handful of tree queries per frame instead of a dozen per
    hypothesis). Equal to :func:`refine_pose` of each pose up to rounding. ``workers``: the k-d tree's threads
    (-1: one per core)."""
    R0, t0 = np.array(R, np.float64).reshape(-1, 3, 3), np.array(t, np.float64).reshape(-1, 3)
    H, D = len(R0), model.diameter
    max_d, huber = settings.max_distance * D, settings.huber * D
    tree, points, normals, near = _neighbourhoods(t0, scene, settings, D)
    apart = np.zeros((H, 3))
    apart[:, 0] = APART_M * np.arange(H)

    def correspond(idx: np.ndarray, Rs: np.ndarray, ts: np.ndarray) -> tuple[np.ndarray, ...]:
        p, facing = facing_points(Rs, ts, model)
        if not p.shape[1]:
            return p, p.copy(), p.copy(), facing
        dist, k = tree.query((p + apart[idx, None]).reshape(-1, 3), distance_upper_bound=max_d, workers=workers)
        dist, k = dist.reshape(facing.shape), k.reshape(facing.shape)
        kept = facing & np.isfinite(dist)
        k = np.where(kept, k, 0)
        q = points[k] - apart[idx, None] if len(points) else np.zeros_like(p)
        n = normals[k] if len(normals) else np.zeros_like(p)
        return p, q, n, kept

    out: list[ICPResult | None] = [None] * H
    for h in np.flatnonzero(near < settings.min_points):
        out[h] = ICPResult(R0[h], t0[h], "no_depth", int(near[h]))
    idx = np.flatnonzero(near >= settings.min_points)
    Rc, tc = R0.copy(), t0.copy()
    cost, before, count = np.full(H, np.nan), np.full(H, np.nan), np.zeros(H, np.intp)
    x = np.zeros((H, 6))
    if len(idx):
        p, q, n, kept = correspond(idx, Rc[idx], tc[idx])
        count[idx] = kept.sum(1)
        cost[idx], x[idx] = _batched_cost_and_step(p, q, n, kept, huber)
    for h in idx[count[idx] < settings.min_points]:
        out[h] = ICPResult(R0[h], t0[h], "no_depth", int(count[h]))
    active = idx[count[idx] >= settings.min_points]
    before[active] = cost[active]
    for _ in range(settings.iterations):
        if not len(active):
            break
        pending, step = active.copy(), x[active].copy()
        took = np.zeros(H, bool)
        for _halving in range(4):  # a step that raises the cost is halved (Levenberg-style safety)
            dR = _rotations(step[:, :3])
            R_new = dR @ Rc[pending]
            t_new = np.einsum("hij,hj->hi", dR, tc[pending]) + step[:, 3:]
            p, q, n, kept = correspond(pending, R_new, t_new)
            c_new, x_new = _batched_cost_and_step(p, q, n, kept, huber)
            ok = (kept.sum(1) >= settings.min_points) & (c_new <= cost[pending])
            done = pending[ok]
            gained = cost[done] - c_new[ok]
            Rc[done], tc[done], cost[done], count[done], x[done] = R_new[ok], t_new[ok], c_new[ok], kept[ok].sum(1), \
                x_new[ok]  # fmt: skip
            took[done] = True
            small = (np.linalg.norm(step[ok, :3], axis=1) < settings.converged[0]) & \
                (np.linalg.norm(step[ok, 3:], axis=1) < settings.converged[1])  # fmt: skip
            stalled = gained < settings.min_gain * (c_new[ok] + gained)
            took[done[small | stalled]] = False  # taken, and the last: converged or the cost has stopped falling
            pending, step = pending[~ok], step[~ok] / 2
            if not len(pending):
                break
        active = active[took[active]]  # no step lowered the cost (converged or stuck), or a stopping rule
    U, _, Vt = np.linalg.svd(Rc)  # re-orthonormalize
    Rc = U @ Vt
    for h in range(H):
        if out[h] is not None:
            continue
        moved = np.linalg.norm(tc[h] - t0[h]) > settings.max_translation * D
        turned = rotation_change_deg(R0[h], Rc[h], space) > settings.max_rotation_deg
        if moved or turned:
            out[h] = ICPResult(R0[h], t0[h], "rejected", int(count[h]), float(before[h]), float(cost[h]))
        else:
            out[h] = ICPResult(Rc[h], tc[h], "refined", int(count[h]), float(before[h]), float(cost[h]))
    return out  # type: ignore[return-value]


def _project(scene: SceneCloud, p: np.ndarray, use: np.ndarray, max_distance: float) -> tuple[np.ndarray, ...]:
    """Projective correspondences of model points (H, P, 3) marked ``use`` (H, P): the scene point and normal
    of the strided pixel each projects onto, kept where it is measured and within ``max_distance``:
    (q (H, P, 3), n_q (H, P, 3), kept (H, P))."""
    g = scene._grid
    h, w = g.ok.shape
    z = p[..., 2]
    inv = np.divide(1.0, z, out=np.zeros_like(z), where=z > 0)
    j = (p[..., 0] * (g.fx * inv) + g.cx) / g.stride + 0.5  # the nearest strided pixel is floor(j)
    i = (p[..., 1] * (g.fy * inv) + g.cy) / g.stride + 0.5
    inside = use & (z > 0) & (j >= 0) & (j < w) & (i >= 0) & (i < h)
    flat = np.where(inside, i, 0).astype(np.intp) * w + np.where(inside, j, 0).astype(np.intp)
    q = g.xyz.reshape(-1, 3)[flat]
    n = g.normals.reshape(-1, 3)[flat]
    kept = inside & g.ok.reshape(-1)[flat]
    kept &= np.sum((np.where(kept[..., None], q, p) - p) ** 2, -1) <= max_distance**2
    return q, n, kept


def _batched_cost_and_step(p: np.ndarray, q: np.ndarray, n: np.ndarray, kept: np.ndarray,
                           huber: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Per hypothesis the robust cost of :func:`_cost` and the damped Gauss-Newton step of :func:`_step`
    over its kept correspondences (``p``, ``q``, ``n`` (H, P, 3), ``kept`` (H, P)): (cost (H,), step (H, 6))."""
    m = kept.astype(np.float64)
    count = np.maximum(m.sum(1), 1.0)
    e = np.where(kept[..., None], p - q, 0.0)
    nn = np.where(kept[..., None], n, 0.0)
    r = np.sum(e * nn, -1)
    a = np.abs(r)
    wgt = np.where(a <= huber, 1.0, huber / np.maximum(a, 1e-15)) * m
    plane = np.where(a <= huber, 0.5 * r**2, huber * (a - 0.5 * huber)) * m
    cost = np.sqrt(2 * (plane + 0.5 * POINT_WEIGHT * np.sum(e * e, -1)).sum(1) / count)
    pm = np.where(kept[..., None], p, 0.0)
    c = np.cross(pm, nn)
    J = np.concatenate((c, nn), -1)  # (H, P, 6)
    Jw = J * wgt[..., None]
    A = np.swapaxes(Jw, 1, 2) @ J
    b = -np.sum(Jw * r[..., None], 1)
    PP = np.swapaxes(pm, 1, 2) @ pm  # sum of p p^T
    S = np.zeros_like(A)
    S[:, :3, :3] = np.trace(PP, axis1=1, axis2=2)[:, None, None] * np.eye(3) - PP
    cross_sum = skew(pm.sum(1))
    S[:, :3, 3:], S[:, 3:, :3] = cross_sum, np.swapaxes(cross_sum, 1, 2)
    S[:, 3:, 3:] = m.sum(1)[:, None, None] * np.eye(3)
    g = np.concatenate((np.cross(pm, e).sum(1), e.sum(1)), -1)
    A = A + POINT_WEIGHT * S
    b = b - POINT_WEIGHT * g
    A += (1e-6 * np.trace(A, axis1=1, axis2=2) / 6 + 1e-30)[:, None, None] * np.eye(6)
    x = np.linalg.solve(A, b[..., None])[..., 0]
    angle = np.linalg.norm(x[:, :3], axis=1)
    x *= np.where(angle > MAX_STEP_RAD, MAX_STEP_RAD / np.maximum(angle, 1e-300), 1.0)[:, None]
    return cost, x


def _rotations(w: np.ndarray) -> np.ndarray:
    """exp of rotation vectors (H, 3) (Rodrigues)."""
    angle = np.linalg.norm(w, axis=1)
    return rodrigues(w / np.where(angle > 1e-12, angle, 1.0)[:, None], angle)


def refine_poses_projective(R: np.ndarray, t: np.ndarray, model: ModelCloud, scene: SceneCloud, space: Any,
                            settings: ICPSettings = ICPSettings()) -> list[ICPResult]:  # fmt: skip
    """:func:`refine_pose` of many poses (H, 3, 3), (H, 3) at once, with projective correspondences
    (``association: projective``): each model point facing the camera is paired with the scene point of
    the pixel it projects onto, not its nearest (no k-d tree; every hypothesis's step in one batch).
    Same cost, step and guard as :func:`refine_pose`; every step is taken."""
    if scene._grid is None:
        raise ValueError("icp: association projective needs a scene made from a depth image")
    R0, t0 = np.array(R, np.float64).reshape(-1, 3, 3), np.array(t, np.float64).reshape(-1, 3)
    H, D = len(R0), model.diameter
    max_d, huber = settings.max_distance * D, settings.huber * D

    def correspond(Rs: np.ndarray, ts: np.ndarray) -> tuple[np.ndarray, ...]:
        p, facing = facing_points(Rs, ts, model)
        q, n, kept = _project(scene, p, facing, max_d)
        return p, q, n, kept

    Rc, tc = R0.copy(), t0.copy()
    p, q, n, kept = correspond(Rc, tc)
    count = kept.sum(1)
    usable = count >= settings.min_points
    active = usable.copy()
    cost, x = _batched_cost_and_step(p, q, n, kept, huber)
    before = cost.copy()
    for _ in range(settings.iterations):
        # every step is taken (no halving: the pairs change with the pose, so the mean cost over them is no
        # fair judge of a step, and a halving rule stalls); a pose stops when its step is negligible or when
        # too few of its points find a pair
        idx = np.flatnonzero(active)
        if not len(idx):
            break
        dR = _rotations(x[idx, :3])
        R_new = dR @ Rc[idx]
        t_new = np.einsum("hij,hj->hi", dR, tc[idx]) + x[idx, 3:]
        pn, qn, nn, kn = correspond(R_new, t_new)
        cn, xn = _batched_cost_and_step(pn, qn, nn, kn, huber)
        enough = kn.sum(1) >= settings.min_points
        take = idx[enough]
        small = (np.linalg.norm(x[take, :3], axis=1) < settings.converged[0]) & \
            (np.linalg.norm(x[take, 3:], axis=1) < settings.converged[1])  # fmt: skip
        Rc[take], tc[take], cost[take], count[take], x[take] = R_new[enough], t_new[enough], cn[enough], \
            kn[enough].sum(1), xn[enough]  # fmt: skip
        active[idx[~enough]] = False
        active[take[small]] = False
    U, _, Vt = np.linalg.svd(Rc)
    Rc = U @ Vt
    out = []
    for h in range(H):
        if not usable[h]:
            out.append(ICPResult(R0[h], t0[h], "no_depth", int(kept[h].sum())))
            continue
        moved = np.linalg.norm(tc[h] - t0[h]) > settings.max_translation * D
        turned = rotation_change_deg(R0[h], Rc[h], space) > settings.max_rotation_deg
        status = "rejected" if moved or turned else "refined"
        Rh, th = (R0[h], t0[h]) if status == "rejected" else (Rc[h], tc[h])
        out.append(ICPResult(Rh, th, status, int(count[h]), float(before[h]), float(cost[h])))
    return out


def refine_hypotheses(R: np.ndarray, t: np.ndarray, score: np.ndarray, model: ModelCloud, scene: SceneCloud,
                      space: Any, settings: ICPSettings = ICPSettings(), depth: np.ndarray | None = None,
                      camera: Any = None, timings: dict[str, float] | None = None,
                      ) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:  # fmt: skip
    """Refine the hypotheses of one image, best score first, within ``settings.budget_ms``.

    Args:
        R: (N, 3, 3), t: (N, 3) metres, camera frame; score: (N,).
        depth, camera: the depth image (H, W) and its camera (fx, fy, cx, cy) the scene was made
            from; needed with ``settings.search``.
        timings: if given, the seconds of each stage are added to it (:data:`STAGES`).
    Returns:
        refined R (N, 3, 3), t (N, 3) in the input order, each one's status, and its score: the
        input's, or with ``settings.search`` the one its ``score`` setting names (a hypothesis the
        budget left unrefined: its agreement where it stands); status ``suppressed``: a duplicate
        the search made (``search.suppress``), which :func:`refine_image` leaves out.
    """
    R_out, t_out = np.array(R, np.float64, copy=True), np.array(t, np.float64, copy=True)
    score_in = np.asarray(score, np.float64)
    status = ["budget"] * len(R_out)
    search = settings.search
    if search is not None and (depth is None or camera is None):
        raise ValueError("icp: the search needs the depth image and its camera")
    mode = resolve_mode(search, model.points) if search is not None else None
    axis = model_axis(model.points, search.axis) if mode == "turn" else None
    flips = ambiguity_turns(model.points, space) if mode == "flips" else None
    merged = _merged(t_out, score_in, search.merge * model.diameter) if search is not None else np.zeros(len(t_out), bool)
    order = [int(k) for k in np.argsort(-score_in, kind="stable") if not merged[k]]
    for k in np.flatnonzero(merged):
        status[k] = "suppressed"
    polish = settings if settings.polish_association is None else \
        dataclasses.replace(settings, association=settings.polish_association)  # fmt: skip

    def refine_chunk(ks: list[int], clock: _Stages, workers: int) -> None:
        """ICP, the search and ICP again of the hypotheses ``ks``, each stage in one batch, in place."""
        first = clock("icp", _refine_many, R_out[ks], t_out[ks], model, scene, space, settings, workers)
        starts = [(R_out[k].copy(), t_out[k].copy()) for k in ks]
        for k, result in zip(ks, first, strict=True):
            R_out[k], t_out[k], status[k] = result.R, result.t, result.status
        todo = [j for j, result in enumerate(first) if search is not None and result.status != "no_depth"]
        if not todo:
            return
        found = [ks[j] for j in todo]
        clock.start()
        if mode == "turn":
            Rs, ts, _ = search_poses(R_out[found], t_out[found], model, depth, camera, axis, search)
        else:
            # from the refined pose and from the hypothesis itself: ICP may have pulled a turned hypothesis
            # further off
            Rs, ts, _ = search_any_many(np.stack([(R_out[ks[j]], starts[j][0]) for j in todo]),
                                        np.stack([(t_out[ks[j]], starts[j][1]) for j in todo]), model, depth, camera,
                                        space, search, flips)  # fmt: skip
        clock.stop("search")
        for k, result in zip(found, clock("polish", _refine_many, Rs, ts, model, scene, space, polish, workers),
                             strict=True):  # fmt: skip
            R_out[k], t_out[k], status[k] = result.R, result.t, "searched"

    if settings.budget_ms is None and settings.threads > 1 and len(order) > 1:
        # no budget: every hypothesis, a share per thread (each hypothesis's result is what it gets alone)
        parts = [order[i :: settings.threads] for i in range(min(settings.threads, len(order)))]
        clocks = [_Stages({} if timings is not None else None) for _ in parts]
        with ThreadPoolExecutor(len(parts)) as pool:
            for done in [pool.submit(refine_chunk, part, clock, 1) for part, clock in zip(parts, clocks, strict=True)]:
                done.result()
        if timings is not None:  # a stage's time: its slowest thread's (they ran side by side)
            for stage in STAGES:
                spent = [c.timings[stage] for c in clocks if stage in c.timings]
                if spent:
                    timings[stage] = timings.get(stage, 0.0) + max(spent)
    else:
        # hypotheses go in chunks, best first: all in one without a time budget; under one, a chunk at a time
        # (nearest-point ICP: one hypothesis, as the budget always counted)
        chunk = len(order) if settings.budget_ms is None else PROJECTIVE_CHUNK if settings.association == "projective" \
            else 1  # fmt: skip
        clock = _Stages(timings)
        start = time.perf_counter()
        for c0 in range(0, len(order), max(chunk, 1)):
            if settings.budget_ms is not None and (time.perf_counter() - start) * 1000 >= settings.budget_ms:
                break
            refine_chunk(order[c0 : c0 + chunk], clock, -1)
    if search is None:
        return R_out, t_out, status, score_in.copy()
    clock = _Stages(timings)
    clock.start()
    agree = np.full(len(R_out), -np.inf)
    if (~merged).any():
        agree[~merged] = score_poses(R_out[~merged], t_out[~merged], model, depth, camera, search)
    final = {"agreement": agree, "network": score_in.copy(), "product": score_in * np.maximum(agree, 0.0)}[search.score]
    if search.suppress > 0:  # duplicates: searches from nearby hypotheses that ended on one pose
        kept: list[int] = []
        for k in np.argsort(-final, kind="stable"):
            if merged[k]:
                continue
            if kept and (pose_distance(space, R_out[k], t_out[k], R_out[kept], t_out[kept])
                         < search.suppress * space.delta).any():  # fmt: skip
                status[k] = "suppressed"
            else:
                kept.append(int(k))
    clock.stop("rank")
    return R_out, t_out, status, final


#: the stages of a refinement whose seconds :func:`refine_image` can report: the scene cloud from the depth
#: image, ICP, the search, ICP of the search's poses, scoring and ranking
STAGES = ("scene", "icp", "search", "polish", "rank")


class _Stages:
    """Adds the seconds of each stage to a dict (nothing when it is None)."""

    def __init__(self, timings: dict[str, float] | None) -> None:
        self.timings, self.t0 = timings, 0.0

    def start(self) -> None:
        self.t0 = time.perf_counter()

    def stop(self, stage: str) -> None:
        if self.timings is not None:
            self.timings[stage] = self.timings.get(stage, 0.0) + time.perf_counter() - self.t0

    def __call__(self, stage: str, fn: Any, *args: Any) -> Any:
        self.start()
        out = fn(*args)
        self.stop(stage)
        return out


#: hypotheses per batch of projective ICP under a time budget
PROJECTIVE_CHUNK = 8


def _refine_many(R: np.ndarray, t: np.ndarray, model: ModelCloud, scene: SceneCloud, space: Any,
                 settings: ICPSettings, workers: int = -1) -> list[ICPResult]:  # fmt: skip
    """ICP of poses (N, 3, 3), (N, 3) in one batch, projective or nearest-point (``workers``: the k-d tree's)."""
    if settings.association == "projective":
        return refine_poses_projective(R, t, model, scene, space, settings)
    return refine_poses_nearest(R, t, model, scene, space, settings, workers)


def _merged(t: np.ndarray, score: np.ndarray, radius: float) -> np.ndarray:
    """(N,) bool: the hypotheses whose origin (N, 3) lies within ``radius`` metres of a better-scored kept
    one's (greedy, best score first; ties: the earlier); none for ``radius`` 0."""
    out = np.zeros(len(t), bool)
    if radius <= 0 or len(t) < 2:
        return out
    kept: list[int] = []
    for k in np.argsort(-np.asarray(score, np.float64), kind="stable"):
        if kept and (np.linalg.norm(t[kept] - t[k], axis=1) < radius).any():
            out[k] = True
        else:
            kept.append(int(k))
    return out


@functools.cache
def _blas_controller() -> Any:
    """threadpoolctl's controller of the loaded BLAS libraries (None without threadpoolctl), made once."""
    try:
        from threadpoolctl import ThreadpoolController
    except ImportError:  # the torch-free runtime's minimal install: BLAS as configured
        return None
    return ThreadpoolController()


def serial_blas() -> contextlib.AbstractContextManager:
    """A context in which numpy's matrix products run on one thread. The refinement's products are small (a few
    hundred points by 3 per pose): threads cost more than they give, and far more when another process keeps a
    core busy (they wait for it). On 2 cores beside a busy process the search took half the CPU time this way."""
    controller = _blas_controller()
    return contextlib.nullcontext() if controller is None else controller.limit(limits=1, user_api="blas")


def refine_image(hypotheses: Any, depth: np.ndarray, camera: Any, model: ModelCloud, space: Any,
                 settings: ICPSettings = ICPSettings(), timings: dict[str, float] | None = None,
                 ) -> tuple[Any, list[str]]:  # fmt: skip
    """The hypotheses of one image (a :class:`opnet.metrics.records.HypothesisSet`) refined against
    its depth image (metres, (H, W)) seen by ``camera`` (fx, fy, cx, cy): (a new set, statuses);
    ``timings``: the seconds of each of :data:`STAGES` added to it."""
    if depth.shape != (camera.height, camera.width):
        raise ValueError(f"icp: depth of shape {depth.shape} does not match the camera ({camera.height}, {camera.width})")
    with serial_blas():
        scene = _Stages(timings)("scene", SceneCloud.from_depth, depth, camera.fx, camera.fy, camera.cx, camera.cy,
                                 settings.stride)  # fmt: skip
        # the search scores in float32 (:func:`opnet.geometry.search.agreement`): depth to a tenth of a micron
        R, t, status, score = refine_hypotheses(hypotheses.R, hypotheses.t, hypotheses.score, model, scene, space,
                                                settings, np.asarray(depth, np.float32), camera, timings)  # fmt: skip
    keep = np.array([s != "suppressed" for s in status], bool)
    visibility = None if hypotheses.visibility is None else np.asarray(hypotheses.visibility)[keep]
    return type(hypotheses)(R[keep], t[keep], score[keep], visibility), status


@dataclass(frozen=True)
class Refiner:
    """ICP for one object: its model cloud, pose space and settings, ready for images."""

    model: ModelCloud
    space: Any
    settings: ICPSettings

    @classmethod
    def for_object(cls, obj: Any, settings: ICPSettings) -> Refiner:
        """From an :class:`opnet.objects.model.ObjectModel` (it needs its mesh)."""
        from opnet.geometry.pose_numpy import PoseSpaceArrays

        if obj.mesh is None:
            raise ValueError(f"icp: object {obj.name!r} has no mesh to refine against")
        return cls(ModelCloud.from_mesh(obj.mesh, settings.model_points, obj.diameter),
                   PoseSpaceArrays.of(obj.pose_space), settings)  # fmt: skip

    def __call__(self, hypotheses: Any, depth: np.ndarray, camera: Any,
                 timings: dict[str, float] | None = None) -> tuple[Any, list[str]]:  # fmt: skip
        """:func:`refine_image` with this object's model."""
        return refine_image(hypotheses, depth, camera, self.model, self.space, self.settings, timings)


def search_settings(budget_ms: float | None = None, fast: bool = False) -> ICPSettings:
    """The settings of ``conf/refine/search.yaml`` (ICP with a wider reach and a looser guard, then
    the search), or with ``fast`` of ``search_fast.yaml`` (the first ICP projective, ten steps, a 1 % gain
    to go on), for the runtime, which reads no config; a test keeps them equal to the configs."""
    settings = ICPSettings(max_distance=0.2, max_rotation_deg=45.0, budget_ms=budget_ms, stride=4, search=SearchSettings())
    if fast:
        settings = dataclasses.replace(settings, association="projective", polish_association="nearest", iterations=10,
                                       min_gain=0.01)  # fmt: skip
    return settings


def refine_config(name: str) -> dict[str, Any]:
    """``conf/refine/<name>.yaml`` as Hydra composes it: the files of its defaults list first, then its own keys."""
    from omegaconf import OmegaConf

    from opnet.paths import config_dir

    path = config_dir() / "refine" / f"{name}.yaml"
    if not path.is_file():
        raise ValueError(f"refine={name!r}: no {path}")
    own = OmegaConf.to_container(OmegaConf.load(path))
    defaults = own.pop("defaults", [])
    merged = OmegaConf.create()
    for entry in defaults:
        merged = OmegaConf.merge(merged, own if entry == "_self_" else refine_config(str(entry)))
    if "_self_" not in defaults:
        merged = OmegaConf.merge(merged, own)
    return OmegaConf.to_container(merged)


def model_refinement(refine: Any, recorded: str | None) -> tuple[Any, bool]:
    """The ``refine`` group of eval.py / predict.py resolved against the refinement a model records
    (:attr:`opnet.run_settings.RunSettings.refine`): ``refine=model`` (their default) is the recorded
    one's group, or none where the model records none. Returns (the group, whether it came from the model)."""
    if not refine or refine.get("method") != "model":
        return refine, False
    return ({"method": "none"} if recorded is None else refine_config(recorded)), recorded is not None


def settings_from_config(refine: Any) -> ICPSettings | None:
    """The ``refine`` config group (conf/refine/): ICP settings for ``method: icp``, ICP with the
    depth-agreement search for ``method: search`` (its settings from ``refine.search``), None for
    ``method: none`` or no group; ValueError for another method."""
    if not refine:
        return None
    method = refine.get("method", "none")
    if method == "none":
        return None
    if method == "model":
        raise ValueError("refine=model: the model's own refinement, resolved with its checkpoint (model_refinement)")
    if method not in ("icp", "search"):
        raise ValueError(f"refine.method={method!r}, expected none, icp or search")
    settings = ICPSettings.from_config(refine.get("icp"))
    if method == "search":
        settings = dataclasses.replace(settings, search=SearchSettings.from_config(refine.get("search")))
    return settings


__all__ = [
    "ASSOCIATIONS",
    "STAGES",
    "STATUSES",
    "ICPResult",
    "ICPSettings",
    "ModelCloud",
    "Refiner",
    "SceneCloud",
    "model_refinement",
    "refine_config",
    "refine_hypotheses",
    "refine_image",
    "refine_pose",
    "refine_poses_nearest",
    "refine_poses_projective",
    "rotation_change_deg",
    "search_settings",
    "settings_from_config",
]
