"""Depth-agreement search around a pose hypothesis: the refinement ICP cannot do.

Point-to-plane ICP fits a surface, so it cannot tell a flat part from the part turned about its
normal or slid along its plane: on the real IPD frames (steel T-plates on an expanded-metal basket)
the network's hypotheses lie within a centimetre of the plates but often with the T pointing the
wrong way, and ICP keeps them there. What does tell them apart is the depth image itself: at the
right pose the sensor measures the part's surface where the model says it is; at a turned pose
part of the model lies over the basket's holes, where the sensor sees *through* the model.

Per hypothesis (:func:`search_pose`):

1. the model points facing the camera, turned about the part's axis (``axis``: ``auto`` = the
   principal axis of least spread of the model's points, the normal of a flat part) through the
   pose's origin in steps of ``turn_step_deg`` all the way round, and shifted across that axis on a
   square grid of ``± shift`` (× diameter) in steps of ``shift_step``;
2. each candidate scored by its **agreement** with the depth image (:func:`agreement`): the
   fraction of its points whose measured depth lies within ``tolerance`` (× diameter) of the
   model's, minus ``see_through_weight`` × the fraction the sensor measures *behind* the model
   (free space the part would fill); points the sensor misses or sees occluded count neither way;
3. the best candidate is returned with its agreement (:class:`opnet.refine.pipeline.Refiner` then
   polishes it by ICP, with ``score: agreement`` ranks the hypotheses by it, and drops those that
   ended within ``suppress`` × δ of a better one: duplicates).

The search deliberately visits poses that are *not* symmetric twins of the hypothesis: it is a
verification against the measured depth, not a local fit (ICP's guard still holds for ICP).

That is ``mode: turn``, for flat parts. Any other part (``mode: flips``; ``auto`` picks ``turn`` for a
part whose least principal spread is under a quarter of the next, else ``flips``) is searched over the
ambiguities a network makes with a compact part (:func:`ambiguity_turns`: the 24 turns that map its
principal axes onto one another, less those its symmetry makes equivalent: end over end, upside
down, a quarter turn), each about the part's centroid; the ``keep`` best by agreement then go through
a local search (:func:`local_search`: turns of ``local_deg`` about the camera's axes and shifts of
``local_shift`` along them, every candidate's 13 moves scored in one batch, the steps halved when no
move helps, ``local_rounds`` rounds).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from opnet.geometry.pose_numpy import axis_permutations, rodrigues, turns
from opnet.refine.agreement import _dtype, agreement_xyz, facing_xyz, score_poses
from opnet.refine.settings import AXES, SearchSettings

#: ``mode: auto`` searches turns about the normal of a part whose least principal spread is under this
#: share of the next (a flat part), the ambiguity turns of any other
FLAT_RATIO = 0.25


def model_axis(points: np.ndarray, axis: str = "auto") -> np.ndarray:
    """The unit axis (3,) of the model frame the search turns about: a named axis, or (``auto``) the
    principal axis of least spread of ``points`` (P, 3) (the normal of a flat part)."""
    if axis != "auto":
        return np.eye(3)[AXES.index(axis) - 1]
    centred = points - points.mean(0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    return vectors[:, 0]


def _offsets(step: float, reach: float) -> np.ndarray:
    """Shifts -k step .. k step (k steps within ``reach``), the smallest first: no shift wins ties."""
    k = int(np.floor(reach / step + 1e-9))
    values = np.arange(-k, k + 1) * step
    return values[np.argsort(np.abs(values), kind="stable")]


def _anchored(scores: np.ndarray, away: np.ndarray, diameter: float, settings: SearchSettings) -> np.ndarray:
    """Agreements ``scores`` (..., M) less ``settings.anchor`` × the distance (× diameter) each candidate's
    origin moved from the hypothesis's (``away``: (..., M, 3) metres): on a pile of plates the depth agrees as
    well with a pose slid across two of them, and the network's position breaks the tie. Callers skip it (and
    the distances) when the anchor is 0."""
    return scores - settings.anchor * np.linalg.norm(away, axis=-1) / diameter


#: candidate points scored per batch of the turn search (bounds its memory: about 100 MB)
BATCH_POINTS = 1_500_000


def _best_of(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any, n: np.ndarray,
             angles: np.ndarray, offsets: np.ndarray, frame: tuple[np.ndarray, np.ndarray], settings: SearchSettings,
             keep: int = 1, origin: np.ndarray | None = None, stride: int = 1,
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """For each of N poses (N, 3, 3), (N, 3): the ``keep`` best among its turns by ``angles`` (A,) radians
    about its axis ``n`` (N, 3) through t and its shifts ``offsets[i] e1 + offsets[j] e2`` (metres; ``frame``:
    e1, e2 (N, 3)); the best shift of each turn only, best first (ties: the earlier angle, the smaller shift).
    Scored by :func:`_anchored` from ``origin`` (N, 3) (None: t), on every ``stride``-th of each candidate's model
    points facing the camera. Returns that score (N, keep), R (N, keep, 3, 3), t (N, keep, 3), angle (N, keep)."""
    e1, e2 = frame
    N, A = len(R), len(angles)
    shifts = (offsets[None, :, None, None] * e1[:, None, None] + offsets[None, None, :, None] * e2[:, None, None])
    shifts = shifts.reshape(N, -1, 3)  # (N, M, 3), row-major (i, j)
    away = shifts if origin is None else shifts + (t - origin)[:, None]  # (N, M, 3): how far each candidate moved
    Rs = (rodrigues(n[:, None], angles[None]) @ R[:, None]).reshape(-1, 3, 3)  # (N A, 3, 3)
    x, y, z, facing = (c[:, ::stride] for c in facing_xyz(Rs, np.repeat(t, A, 0), model, _dtype(depth)))  # (N A, K)
    M, P = shifts.shape[1], x.shape[1]
    best_score, best_shift = np.empty(N * A), np.empty(N * A, np.intp)
    rows = max(1, BATCH_POINTS // max(M * P, 1))
    D = model.diameter
    for r0 in range(0, N * A, rows):
        sl = slice(r0, r0 + rows)
        sh = shifts[np.arange(N * A)[sl] // A][:, :, None]  # (r, M, 1, 3)
        valid = np.broadcast_to(facing[sl, None], (len(sh), M, P))
        scores = agreement_xyz(x[sl, None] + sh[..., 0], y[sl, None] + sh[..., 1], z[sl, None] + sh[..., 2], valid,
                               depth, camera, settings.tolerance * D, settings.see_through_weight)  # fmt: skip
        if settings.anchor:
            scores = _anchored(scores, away[np.arange(N * A)[sl] // A], D, settings)
        best_shift[sl] = scores.argmax(1)
        best_score[sl] = scores[np.arange(len(scores)), best_shift[sl]]
    best_score, best_shift = best_score.reshape(N, A), best_shift.reshape(N, A)
    order = np.argsort(-best_score, axis=1, kind="stable")[:, :keep]  # stable: ties keep the earlier angle
    h = np.arange(N)[:, None]
    Rk = Rs.reshape(N, A, 3, 3)[h, order]
    tk = t[:, None] + shifts[h, best_shift[h, order]]
    return best_score[h, order], Rk, tk, angles[order]


def search_pose(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any, axis: np.ndarray,
                settings: SearchSettings) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """The best pose among the turns and shifts of (R, t) (module docstring) and its agreement:
    :func:`search_poses` of one pose."""
    Rb, tb, score = search_poses(np.asarray(R)[None], np.asarray(t)[None], model, depth, camera, axis, settings)
    return Rb[0], tb[0], float(score[0])


def search_poses(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any, axis: np.ndarray,
                 settings: SearchSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The best pose among the turns and shifts of each of the poses (N, 3, 3), (N, 3) (module docstring), all
    scored in batches; each pose's result is what it would be alone.

    With ``coarse`` > 1 the grid is first searched at ``coarse`` times its steps, then (``fine: grid``) at its
    own steps around the three best coarse turns (± one coarse step of turn and shift each way), or
    (``fine: local``) by a pattern search from them.

    Args:
        R (N, 3, 3), t (N, 3): the poses (camera frame, metres). model: a :class:`opnet.refine.clouds.ModelCloud`.
        depth: (H, W) z-depth (metres, NaN missing) seen by ``camera`` (fx, fy, cx, cy).
        axis: the model-frame axis to turn about (:func:`model_axis`).
    Returns:
        R (N, 3, 3), t (N, 3), agreement (N,) of each pose's best candidate (the first of equals: no turn, no
        shift, if it ties; less the ``anchor`` setting's penalty for moving, if any).
    """
    R, t = np.asarray(R, np.float64).reshape(-1, 3, 3), np.asarray(t, np.float64).reshape(-1, 3)
    D, s = model.diameter, settings
    n = R @ axis  # (N, 3): the axis in the camera frame, through the origin t
    helper = np.eye(3)[np.argmin(np.abs(n), axis=1)]
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    frame = (e1, np.cross(n, e1))
    if s.coarse <= 1:
        angles = np.radians(np.arange(0.0, 360.0 - 1e-9, s.turn_step_deg))
        score, Rb, tb, _ = _best_of(R, t, model, depth, camera, n, angles, _offsets(s.shift_step * D, s.shift * D),
                                    frame, s)  # fmt: skip
        return Rb[:, 0], tb[:, 0], score[:, 0]
    turn, step = s.turn_step_deg * s.coarse, s.shift_step * s.coarse
    angles = np.radians(np.arange(0.0, 360.0 - 1e-9, turn))
    coarse = _best_of(R, t, model, depth, camera, n, angles, _offsets(step * D, s.shift * D), frame, s, keep=3,
                      stride=s.coarse_stride)
    if s.fine == "local":
        return _refine_turns(coarse[:3], t, model, depth, camera, n, frame, np.radians(turn) / 2, step * D / 2, s)
    out_R, out_t, out_s = R.copy(), t.copy(), np.full(len(R), -np.inf)
    for c in range(coarse[0].shape[1]):  # around each of the three best coarse turns, the first best of equals
        angle = coarse[3][:, c]
        for h in range(len(R)):
            fine = np.radians(np.arange(-turn, turn + 1e-9, s.turn_step_deg)) + angle[h]
            fine = fine[np.argsort(np.abs(fine - angle[h]), kind="stable")]  # the coarse turn first: it wins ties
            score, Rb, tb, _ = _best_of(R[h : h + 1], coarse[2][h : h + 1, c], model, depth, camera, n[h : h + 1],
                                        fine, _offsets(s.shift_step * D, step * D), (e1[h : h + 1], frame[1][h : h + 1]),
                                        s, origin=t[h : h + 1])  # fmt: skip
            if score[0, 0] > out_s[h]:
                out_R[h], out_t[h], out_s[h] = Rb[0, 0], tb[0, 0], score[0, 0]
    return out_R, out_t, out_s


def _refine_turns(starts: tuple[np.ndarray, np.ndarray, np.ndarray], origin: np.ndarray, model: Any, depth: np.ndarray,
                  camera: Any,
                  n: np.ndarray, frame: tuple[np.ndarray, np.ndarray], turn: float, shift: float,
                  settings: SearchSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """``fine: local``: from each pose's coarse best (``starts``: agreement (N, S), R (N, S, 3, 3), t (N, S, 3))
    a pattern search of six moves (a turn of ``turn`` radians about its axis ``n`` (N, 3) either way, a shift of
    ``shift`` metres either way along each of ``frame`` (N, 3) each), every start's moves scored in one batch; a
    start whose best is to stay halves its steps; a pose's starts go on until all its steps are below half the
    grid's own; scored by :func:`_anchored` from the hypotheses' origins ``origin`` (N, 3). Each pose's best (the
    first start of equals): R (N, 3, 3), t (N, 3), that score (N,)."""
    score, R, t = (np.array(a, np.float64) for a in starts)
    N, S = score.shape
    steps_r, steps_t = np.full((N, S), turn), np.full((N, S), shift)
    stop_r, stop_t = np.radians(settings.turn_step_deg) / 2, settings.shift_step * model.diameter / 2
    e1, e2 = frame
    while True:
        live = np.flatnonzero((steps_r >= stop_r).any(1) | (steps_t >= stop_t).any(1))
        if not len(live):
            break
        L = len(live)
        dR = np.broadcast_to(np.eye(3), (L, S, 7, 3, 3)).copy()  # stay, turn +-, shifts +- e1, e2
        dR[:, :, 1] = rodrigues(n[live, None], steps_r[live])
        dR[:, :, 2] = rodrigues(n[live, None], -steps_r[live])
        dv = np.zeros((L, S, 7, 3))
        for j, e in enumerate((e1[live], -e1[live], e2[live], -e2[live])):
            dv[:, :, 3 + j] = steps_t[live][..., None] * e[:, None]
        Rn = dR @ R[live][:, :, None]
        tn = t[live][:, :, None] + dv  # turns about the axis through the pose's origin, as the grid's
        sc = np.empty((L, S, 7))
        sc[..., 0] = score[live]  # staying keeps its score: only the moves are scored
        sc[..., 1:] = score_poses(Rn[:, :, 1:].reshape(-1, 3, 3), tn[:, :, 1:].reshape(-1, 3), model, depth, camera,
                                  settings).reshape(L, S, 6)  # fmt: skip
        if settings.anchor:
            sc[..., 1:] = _anchored(sc[..., 1:], tn[:, :, 1:] - origin[live, None, None], model.diameter, settings)
        best = sc.argmax(-1)
        stay = best == 0
        sr, st = steps_r[live], steps_t[live]
        sr[stay] /= 2
        st[stay] /= 2
        steps_r[live], steps_t[live] = sr, st
        li, si = np.meshgrid(np.arange(L), np.arange(S), indexing="ij")
        R[live], t[live], score[live] = Rn[li, si, best], tn[li, si, best], sc[li, si, best]
    k = np.argmax(score, axis=1)
    h = np.arange(N)
    return R[h, k], t[h, k], score[h, k]


def is_flat(points: np.ndarray) -> bool:
    """The least principal spread of ``points`` (P, 3) is under :data:`FLAT_RATIO` of the next."""
    centred = points - points.mean(0)
    spread = np.sqrt(np.maximum(np.linalg.eigvalsh(centred.T @ centred), 0.0))
    return bool(spread[0] < FLAT_RATIO * spread[1])


def resolve_mode(settings: SearchSettings, points: np.ndarray) -> str:
    """``turn`` or ``flips`` for a part's model points (``auto``: by :func:`is_flat`)."""
    if settings.mode != "auto":
        return settings.mode
    return "turn" if is_flat(points) else "flips"


def _equivalent(space: Any, A: np.ndarray, B: np.ndarray, tol_deg: float = 10.0) -> bool:
    """Two model-frame rotations are the same pose of the part (under its symmetry, within ``tol_deg``: the
    principal axes of sampled points lie a degree or two off a symmetry axis; the turns are 90 apart)."""
    from opnet.geometry.pose_numpy import rotation_change_deg

    return rotation_change_deg(A, B, space) < tol_deg


def ambiguity_turns(points: np.ndarray, space: Any) -> tuple[np.ndarray, np.ndarray]:
    """The model-frame turns (C, 3, 3) a hypothesis is tried under (module docstring), the identity first,
    and the centroid (3,) they turn about: the 24 rotations mapping the principal axes of ``points`` onto
    one another, less those the part's symmetry (``space``: group, revolution) makes equivalent to one
    kept before."""
    centre = points.mean(0)
    _, A = np.linalg.eigh((points - centre).T @ (points - centre))
    kept: list[np.ndarray] = []
    for C in axis_permutations():
        G = A @ C @ A.T
        if not any(_equivalent(space, K, G) for K in kept):
            kept.append(G)
    return np.array(kept), centre


def _moves(step_rad: np.ndarray, step_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The local search's 13 moves per pose: (C, 13, 3, 3) camera-frame turns by ``step_rad`` (C,) and
    (C, 13, 3) shifts by ``step_m`` (C,); no move first."""
    C = len(step_rad)
    R = np.broadcast_to(np.eye(3), (C, 13, 3, 3)).copy()
    v = np.zeros((C, 13, 3))
    for k in range(3):
        axis = np.eye(3)[k]
        R[:, 1 + 2 * k] = turns(axis, step_rad)
        R[:, 2 + 2 * k] = turns(axis, -step_rad)
        v[:, 7 + 2 * k] = step_m[:, None] * axis
        v[:, 8 + 2 * k] = -step_m[:, None] * axis
    return R, v


def local_search(R: np.ndarray, t: np.ndarray, centre: np.ndarray, model: Any, depth: np.ndarray, camera: Any,
                 settings: SearchSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Pattern search from poses (C, 3, 3), (C, 3): per round every pose's 13 moves (turns about the
    camera axes through the part's centroid ``centre`` (model frame), shifts along them) scored in one
    batch; each pose takes its best move, the steps halve for a pose whose best is to stay. Returns the
    poses and their agreements (C,)."""
    R, t = np.array(R, np.float64), np.array(t, np.float64)
    C = len(R)
    step_r = np.full(C, np.radians(settings.local_deg))
    step_t = np.full(C, settings.local_shift * model.diameter)
    score = score_poses(R, t, model, depth, camera, settings)
    rows = np.arange(C)
    for _ in range(settings.local_rounds):
        dR, dv = _moves(step_r, step_t)
        c = R @ centre + t  # the centroid in the camera frame (C, 3)
        Rn = dR @ R[:, None]
        tn = np.einsum("cmij,cj->cmi", dR, t - c) + c[:, None] + dv
        s = np.empty((C, 13))
        s[:, 0] = score  # staying keeps its score: only the moves are scored
        s[:, 1:] = score_poses(Rn[:, 1:].reshape(-1, 3, 3), tn[:, 1:].reshape(-1, 3), model, depth, camera,
                               settings).reshape(C, 12)  # fmt: skip
        best = s.argmax(1)  # ties: the first, i.e. no move
        stay = best == 0
        step_r[stay] /= 2
        step_t[stay] /= 2
        R, t, score = Rn[rows, best], tn[rows, best], s[rows, best]
    return R, t, score


def search_any(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any, space: Any,
               settings: SearchSettings, turns_and_centre: tuple[np.ndarray, np.ndarray] | None = None,
               ) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """``mode: flips`` from one pose (3, 3), (3,) or several starts (S, 3, 3), (S, 3): :func:`search_any_many`
    of one hypothesis; the best pose and its agreement."""
    R, t = np.asarray(R, np.float64).reshape(1, -1, 3, 3), np.asarray(t, np.float64).reshape(1, -1, 3)
    Rb, tb, score = search_any_many(R, t, model, depth, camera, space, settings, turns_and_centre)
    return Rb[0], tb[0], float(score[0])


def search_any_many(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any, space: Any,
                    settings: SearchSettings, turns_and_centre: tuple[np.ndarray, np.ndarray] | None = None,
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """``mode: flips`` (module docstring) for N hypotheses of S starts each, (N, S, 3, 3), (N, S, 3), every
    stage of all of them in one batch: the ambiguity turns of every start scored at twice the tolerance (a
    turned hypothesis is a few degrees and millimetres out), each hypothesis's ``keep`` best searched
    locally; per hypothesis the best pose and its agreement (its first start itself unless beaten). Each
    hypothesis's result is what it gets alone.

    Args:
        turns_and_centre: :func:`ambiguity_turns` of the model (made once per object by the caller).
    Returns:
        R (N, 3, 3), t (N, 3), agreement (N,).
    """
    R, t = np.asarray(R, np.float64), np.asarray(t, np.float64)
    N, S = R.shape[:2]
    G, centre = turns_and_centre if turns_and_centre is not None else ambiguity_turns(model.points, space)
    C = len(G)
    Rc = (R[:, :, None] @ G).reshape(N, S * C, 3, 3)  # turned about the centroid, which stays
    tc = ((np.einsum("nsij,j->nsi", R, centre) + t)[:, :, None] - (R[:, :, None] @ G) @ centre).reshape(N, S * C, 3)
    loose = dataclasses.replace(settings, tolerance=2.0 * settings.tolerance)
    score = score_poses(Rc.reshape(-1, 3, 3), tc.reshape(-1, 3), model, depth, camera, loose).reshape(N, S * C)
    here = score_poses(R[:, 0], t[:, 0], model, depth, camera, settings)
    rows = np.arange(N)
    if settings.keep == 0:
        k = np.argmax(score, axis=1)
        Rk, tk = Rc[rows, k], tc[rows, k]
        return Rk, tk, score_poses(Rk, tk, model, depth, camera, settings)
    order = np.argsort(-score, axis=1, kind="stable")[:, : settings.keep]  # (N, keep)
    keep = order.shape[1]
    Rl, tl, sl = local_search(Rc[rows[:, None], order].reshape(-1, 3, 3), tc[rows[:, None], order].reshape(-1, 3),
                              centre, model, depth, camera, settings)  # fmt: skip
    Rl, tl, sl = Rl.reshape(N, keep, 3, 3), tl.reshape(N, keep, 3), sl.reshape(N, keep)
    k = np.argmax(sl, axis=1)
    best = sl[rows, k]
    stay = best <= here
    R_out = np.where(stay[:, None, None], R[:, 0], Rl[rows, k])
    t_out = np.where(stay[:, None], t[:, 0], tl[rows, k])
    return R_out, t_out, np.where(stay, here, best)


__all__ = [
    "FLAT_RATIO",
    "ambiguity_turns",
    "is_flat",
    "local_search",
    "model_axis",
    "resolve_mode",
    "search_any",
    "search_any_many",
    "search_pose",
    "search_poses",
]
