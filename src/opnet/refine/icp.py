"""Point-to-plane ICP of one pose against the depth image: its cost, its step and its guard.

Why not Open3D, the field's usual choice: its wheel is several hundred MB with its own OpenGL
stack, and one hypothesis needs only a few hundred model points against a k-d tree of the scene
points near it; this module does that and no more.

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

The batched ICP of many poses at once (:mod:`opnet.refine.associations`) takes the same cost and
step from :func:`_batched_cost_and_step`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from opnet.geometry.pose_numpy import rodrigues, rotation_change_deg, skew, turns
from opnet.refine.clouds import ModelCloud, SceneCloud
from opnet.refine.settings import ICPSettings

#: what became of a hypothesis: ICP's refined, no_depth and rejected, and the refinement's searched,
#: unpolished (searched, its agreement too low to be polished: ``search.polish_share``), suppressed (a duplicate)
#: and budget (left as it was when the time ran out)
STATUSES = ("refined", "searched", "unpolished", "suppressed", "no_depth", "rejected", "budget")


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


__all__ = ["STATUSES", "ICPResult", "refine_pose"]
