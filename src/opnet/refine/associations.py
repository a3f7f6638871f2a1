"""ICP of many poses at once, by the two ways of pairing a model point with the scene
(``icp.association``): :func:`refine_poses_nearest` (its nearest scene point near the hypothesis, every
hypothesis's neighbourhood in one k-d tree) and :func:`refine_poses_projective` (the scene point of the pixel
it projects onto). The cost, the step and the guard are those of :func:`opnet.refine.icp.refine_pose`."""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from opnet.geometry.pose_numpy import rotation_change_deg
from opnet.refine.agreement import facing_points
from opnet.refine.clouds import ModelCloud, SceneCloud
from opnet.refine.icp import ICPResult, _batched_cost_and_step, _rotations
from opnet.refine.settings import ICPSettings


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


__all__ = ["refine_poses_nearest", "refine_poses_projective"]
