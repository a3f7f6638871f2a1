"""Point-to-plane ICP: refine pose hypotheses against the depth image (issue 26).

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

import dataclasses
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from opnet.geometry.pose_numpy import pose_distance, rotation_change_deg
from opnet.geometry.search import (
    SearchSettings,
    ambiguity_turns,
    model_axis,
    pose_agreement,
    resolve_mode,
    search_any,
    search_pose,
    turns,
)

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
    search: SearchSettings | None = None

    def __post_init__(self) -> None:
        positive = {"radius": self.radius, "max_distance": self.max_distance, "huber": self.huber,
                    "max_rotation_deg": self.max_rotation_deg, "max_translation": self.max_translation}  # fmt: skip
        for key, value in positive.items():
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise ValueError(f"icp.{key} must be a positive number, got {value!r}")
        for key in ("iterations", "min_points", "model_points", "stride"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"icp.{key} must be a positive integer, got {value!r}")
        if isinstance(self.local_points, bool) or not isinstance(self.local_points, int) or self.local_points < 0:
            raise ValueError(f"icp.local_points must be an integer >= 0 (0: all), got {self.local_points!r}")
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


@dataclass
class SceneCloud:
    """The depth image as camera-frame points (N, 3) with unit normals (N, 3) and a k-d tree."""

    points: np.ndarray
    normals: np.ndarray
    tree: cKDTree

    @classmethod
    def from_depth(cls, depth: np.ndarray, fx: float, fy: float, cx: float, cy: float, stride: int = 1) -> SceneCloud:
        """From a z-depth image (H, W) in metres (NaN or <= 0: missing) and its intrinsics."""
        depth = np.asarray(depth, np.float64)
        if depth.ndim != 2:
            raise ValueError(f"icp: depth must be an (H, W) image, got shape {depth.shape}")
        # the strided grid first: its points, and normals from its own neighbours
        v, u = np.mgrid[0 : depth.shape[0] : stride, 0 : depth.shape[1] : stride].astype(np.float64)
        d = depth[::stride, ::stride]
        z = np.where(np.isfinite(d) & (d > 0), d, np.nan)
        xyz = np.stack(((u - cx) * z / fx, (v - cy) * z / fy, z), -1)
        # normals from the neighbouring pixels (central differences where both exist)
        du = np.full_like(xyz, np.nan)
        dv = np.full_like(xyz, np.nan)
        du[:, 1:-1] = xyz[:, 2:] - xyz[:, :-2]
        dv[1:-1] = xyz[2:] - xyz[:-2]
        n = np.cross(du, dv)
        norm = np.linalg.norm(n, axis=-1, keepdims=True)
        n = n / np.where(norm > 0, norm, np.nan)
        n = np.where((np.sum(n * xyz, -1, keepdims=True) > 0), -n, n)  # facing the camera
        ok = np.isfinite(xyz).all(-1) & np.isfinite(n).all(-1)
        points, normals = xyz[ok], n[ok]
        return cls(points, normals, cKDTree(points if len(points) else np.full((1, 3), 1e9)))  # empty: one far point


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


def _skew(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _rotation(w: np.ndarray) -> np.ndarray:
    """exp of the rotation vector ``w`` (Rodrigues)."""
    angle = float(np.linalg.norm(w))
    if angle < 1e-12:
        return np.eye(3) + _skew(w)
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
    cross_sum = _skew(p.sum(0))  # -[p]x^T = [p]x
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
    idx = np.asarray(scene.tree.query_ball_point(t0, settings.radius * D), dtype=np.int64)
    if len(idx) < settings.min_points:
        return ICPResult(R0, t0, "no_depth", len(idx))
    if settings.local_points and len(idx) > settings.local_points:  # every k-th: a small tree, the same surface
        idx = np.sort(idx)[:: -(-len(idx) // settings.local_points)]
    local = (cKDTree(scene.points[idx]), scene.points[idx], scene.normals[idx])
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
        Rc, tc, p, q, n, cost = R_new, t_new, p_new, q_new, n_new, new_cost
        if np.linalg.norm(x[:3]) < 1e-6 and np.linalg.norm(x[3:]) < 1e-7:
            break
    after = cost
    U, _, Vt = np.linalg.svd(Rc)  # re-orthonormalize
    Rc = U @ Vt
    moved = np.linalg.norm(tc - t0) > settings.max_translation * D
    turned = rotation_change_deg(R0, Rc, space) > settings.max_rotation_deg
    if moved or turned:
        return ICPResult(R0, t0, "rejected", len(p), before, after)
    return ICPResult(Rc, tc, "refined", len(p), before, after)


def refine_hypotheses(R: np.ndarray, t: np.ndarray, score: np.ndarray, model: ModelCloud, scene: SceneCloud,
                      space: Any, settings: ICPSettings = ICPSettings(), depth: np.ndarray | None = None,
                      camera: Any = None) -> tuple[np.ndarray, np.ndarray, list[str], np.ndarray]:  # fmt: skip
    """Refine the hypotheses of one image, best score first, within ``settings.budget_ms``.

    Args:
        R: (N, 3, 3), t: (N, 3) metres, camera frame; score: (N,).
        depth, camera: the depth image (H, W) and its camera (fx, fy, cx, cy) the scene was made
            from; needed with ``settings.search``.
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
    start = time.perf_counter()
    for k in np.argsort(-score_in, kind="stable"):
        if merged[k]:
            status[k] = "suppressed"
            continue
        if settings.budget_ms is not None and (time.perf_counter() - start) * 1000 >= settings.budget_ms:
            break
        start_R, start_t = R_out[k].copy(), t_out[k].copy()
        result = refine_pose(R_out[k], t_out[k], model, scene, space, settings)
        R_out[k], t_out[k], status[k] = result.R, result.t, result.status
        if search is not None and result.status != "no_depth":
            if mode == "turn":
                Rs, ts, _ = search_pose(R_out[k], t_out[k], model, depth, camera, axis, search)
            else:
                # from the refined pose and from the hypothesis itself: ICP may have pulled a turned
                # hypothesis further off
                Rs, ts, _ = search_any(np.stack((R_out[k], start_R)), np.stack((t_out[k], start_t)), model, depth,
                                       camera, space, search, flips)  # fmt: skip
            polished = refine_pose(Rs, ts, model, scene, space, settings)
            R_out[k], t_out[k], status[k] = polished.R, polished.t, "searched"
    if search is None:
        return R_out, t_out, status, score_in.copy()
    agree = np.array([pose_agreement(Rk, tk, model, depth, camera, search) if not m else -np.inf
                      for Rk, tk, m in zip(R_out, t_out, merged, strict=True)])
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
    return R_out, t_out, status, final


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


def refine_image(hypotheses: Any, depth: np.ndarray, camera: Any, model: ModelCloud, space: Any,
                 settings: ICPSettings = ICPSettings()) -> tuple[Any, list[str]]:  # fmt: skip
    """The hypotheses of one image (a :class:`opnet.metrics.records.HypothesisSet`) refined against
    its depth image (metres, (H, W)) seen by ``camera`` (fx, fy, cx, cy): (a new set, statuses)."""
    if depth.shape != (camera.height, camera.width):
        raise ValueError(f"icp: depth of shape {depth.shape} does not match the camera ({camera.height}, {camera.width})")
    scene = SceneCloud.from_depth(depth, camera.fx, camera.fy, camera.cx, camera.cy, settings.stride)
    R, t, status, score = refine_hypotheses(hypotheses.R, hypotheses.t, hypotheses.score, model, scene, space,
                                            settings, np.asarray(depth, np.float64), camera)  # fmt: skip
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

    def __call__(self, hypotheses: Any, depth: np.ndarray, camera: Any) -> tuple[Any, list[str]]:
        """:func:`refine_image` with this object's model."""
        return refine_image(hypotheses, depth, camera, self.model, self.space, self.settings)


def search_settings(budget_ms: float | None = None) -> ICPSettings:
    """The settings of ``conf/refine/search.yaml`` (ICP with a wider reach and a looser guard, then
    the search; a test keeps the two equal), for the runtime, which reads no config."""
    return ICPSettings(max_distance=0.2, max_rotation_deg=45.0, budget_ms=budget_ms, stride=2, search=SearchSettings())


def settings_from_config(refine: Any) -> ICPSettings | None:
    """The ``refine`` config group (conf/refine/): ICP settings for ``method: icp``, ICP with the
    depth-agreement search for ``method: search`` (its settings from ``refine.search``), None for
    ``method: none`` or no group; ValueError for another method."""
    if not refine:
        return None
    method = refine.get("method", "none")
    if method == "none":
        return None
    if method not in ("icp", "search"):
        raise ValueError(f"refine.method={method!r}, expected none, icp or search")
    settings = ICPSettings.from_config(refine.get("icp"))
    if method == "search":
        settings = dataclasses.replace(settings, search=SearchSettings.from_config(refine.get("search")))
    return settings


__all__ = ["STATUSES", "ICPResult", "ICPSettings", "ModelCloud", "Refiner", "SceneCloud", "refine_hypotheses",
           "refine_image", "refine_pose", "rotation_change_deg", "search_settings", "settings_from_config"]
