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
3. the best candidate is returned with its agreement (:class:`opnet.geometry.icp.Refiner` then
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
import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np

SCORES = ("agreement", "network", "product")
AXES = ("auto", "x", "y", "z")
MODES = ("auto", "turn", "flips")
#: ``mode: auto`` searches turns about the normal of a part whose least principal spread is under this
#: share of the next (a flat part), the ambiguity turns of any other
FLAT_RATIO = 0.25


@dataclass(frozen=True)
class SearchSettings:
    """Settings of the search; lengths in units of the object's diameter (module docstring).

    Attributes:
        axis: the model axis the part is turned about: auto (least spread of its points) | x | y | z.
        turn_step_deg: step of the turns (all the way round).
        shift: largest shift across the axis, each way.
        shift_step: step of the shift grid.
        tolerance: a measured depth within this of the model's agrees.
        see_through_weight: weight of the points the sensor sees through (measured behind the model).
        score: the refined hypothesis's score: agreement | network (the network's, unchanged) |
            product (network × max(agreement, 0)).
        suppress: after the search, a hypothesis within this many δ (the metric's threshold, pose
            distance, symmetry-aware) of a better-scored one is dropped: searches from nearby
            hypotheses end on the same pose, and the copy could only count as a false positive
            (0: keep all).
        coarse: 1 searches the whole grid; N > 1 first a grid N times coarser, then the fine grid
            around its three best turns (about N² times fewer candidates).
        fine: after the coarse grid (``coarse`` > 1): grid (the fine grid around its three best turns) | local
            (a pattern search of turns and shifts from them, a few dozen poses instead of a thousand).
        merge: before the refinement, a hypothesis whose origin lies within this many diameters of a
            better-scored one's is dropped (status ``suppressed``): the search from the better one reaches
            its pose (0: search from every hypothesis).
        mode: turn (about ``axis``, with shifts: flat parts) | flips (the ambiguity turns and a local
            search: any part) | auto (turn for a flat part, else flips).
        keep: ``flips``: how many of the best ambiguity turns go on to the local search.
        local_deg, local_shift (× diameter), local_rounds: ``flips``' local search (module docstring).
    """

    axis: str = "auto"
    turn_step_deg: float = 5.0
    shift: float = 0.1
    shift_step: float = 0.02
    tolerance: float = 0.04
    see_through_weight: float = 1.0
    score: str = "agreement"
    suppress: float = 1.0
    coarse: int = 3
    merge: float = 0.1
    fine: str = "local"
    mode: str = "auto"
    keep: int = 3
    local_deg: float = 8.0
    local_shift: float = 0.04
    local_rounds: int = 4

    def __post_init__(self) -> None:
        if self.fine not in ("grid", "local"):
            raise ValueError(f"search.fine must be grid or local, got {self.fine!r}")
        if self.mode not in MODES:
            raise ValueError(f"search.mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        for key in ("keep", "local_rounds"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 100:
                raise ValueError(f"search.{key} must be an integer in 0..100, got {value!r}")
        for key in ("local_deg", "local_shift"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or not 0 < value <= 90:
                raise ValueError(f"search.{key} must be a positive number (at most 90), got {value!r}")
        if self.axis not in AXES:
            raise ValueError(f"search.axis must be one of {', '.join(AXES)}, got {self.axis!r}")
        if self.score not in SCORES:
            raise ValueError(f"search.score must be one of {', '.join(SCORES)}, got {self.score!r}")
        for key in ("turn_step_deg", "shift_step", "tolerance"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or value <= 0:
                raise ValueError(f"search.{key} must be a positive number, got {value!r}")
        for key in ("shift", "see_through_weight", "suppress", "merge"):
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value) or value < 0:
                raise ValueError(f"search.{key} must be a number >= 0, got {value!r}")
        if isinstance(self.coarse, bool) or not isinstance(self.coarse, int) or self.coarse < 1:
            raise ValueError(f"search.coarse must be a positive integer, got {self.coarse!r}")
        if self.turn_step_deg > 360:
            raise ValueError(f"search.turn_step_deg must be at most 360, got {self.turn_step_deg!r}")
        if self.shift / self.shift_step > 50:
            raise ValueError(f"search: shift / shift_step = {self.shift / self.shift_step:g} makes a grid of more "
                             "than 101 x 101 shifts; take a larger shift_step")  # fmt: skip

    @classmethod
    def from_config(cls, cfg: Any) -> SearchSettings:
        """From a mapping (a config group); unknown keys are an error naming them."""
        cfg = dict(cfg or {})
        unknown = set(cfg) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"search: unknown keys {sorted(unknown)}; expected {', '.join(cls.__dataclass_fields__)}")
        return cls(**cfg)


def model_axis(points: np.ndarray, axis: str = "auto") -> np.ndarray:
    """The unit axis (3,) of the model frame the search turns about: a named axis, or (``auto``) the
    principal axis of least spread of ``points`` (P, 3) (the normal of a flat part)."""
    if axis != "auto":
        return np.eye(3)[AXES.index(axis) - 1]
    centred = points - points.mean(0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    return vectors[:, 0]


def agreement(points: np.ndarray, valid: np.ndarray, depth: np.ndarray, camera: Any, tolerance: float,
              see_through_weight: float) -> np.ndarray:  # fmt: skip
    """Agreement of posed model points (..., K, 3) (camera frame, metres; ``valid`` (..., K) marks
    those that count, e.g. facing the camera) with a z-depth image (H, W) (NaN: missing): per pose,
    (points measured within ``tolerance`` - ``see_through_weight`` x points measured behind the model
    by more) / valid points."""
    return agreement_xyz(points[..., 0], points[..., 1], points[..., 2], valid, depth, camera, tolerance,
                         see_through_weight)  # fmt: skip


def agreement_xyz(x: np.ndarray, y: np.ndarray, z: np.ndarray, valid: np.ndarray, depth: np.ndarray, camera: Any,
                  tolerance: float, see_through_weight: float) -> np.ndarray:  # fmt: skip
    """:func:`agreement` of points given by their coordinates x, y, z (..., K) each."""
    inv = np.divide(1.0, z, out=np.zeros_like(z), where=z > 0)  # behind the camera: never inside
    u = x * (camera.fx * inv) + (camera.cx + 0.5)  # the pixel is floor(u); u >= 0 makes the cast a floor
    v = y * (camera.fy * inv) + (camera.cy + 0.5)
    h, w = depth.shape
    inside = valid & (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    index = np.where(inside, v, 0).astype(np.intp) * w + np.where(inside, u, 0).astype(np.intp)  # no cast of inf
    r = depth.ravel()[index] - z
    r[~inside] = np.nan
    agree = np.count_nonzero(np.abs(r) <= tolerance, -1)  # NaN compares False: missing depth counts neither way
    through = np.count_nonzero(r > tolerance, -1)
    return (agree - see_through_weight * through) / np.maximum(np.count_nonzero(valid, -1), 1)


def posed_xyz(R: np.ndarray, t: np.ndarray, model: Any, dtype: Any = np.float64,
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """All the model points at poses (N, 3, 3), (N, 3), camera frame: x, y, z (N, P) each of ``dtype`` (one
    matrix product per coordinate), and which face the camera (N, P)."""
    R, t = np.asarray(R, np.float64), np.asarray(t, np.float64)
    points = model.points.T.astype(dtype)
    x, y, z = (R[:, k].astype(dtype) @ points + t[:, k : k + 1].astype(dtype) for k in range(3))
    # (R n) . (R p + t) = n . p + n . (R^T t): one (N, P) product, no turned normals
    local_t = np.einsum("nji,nj->ni", R, t)
    facing = local_t @ model.normals.T + np.sum(model.normals * model.points, 1) < 0
    return x, y, z, facing


def facing_xyz(R: np.ndarray, t: np.ndarray, model: Any, dtype: Any = np.float64,
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The model points facing the camera at poses (N, 3, 3), (N, 3), packed: x, y, z (N, K) each of ``dtype``,
    and which of them are real (N, K) (K: the most any pose has; the rest pad with point 0, masked out).
    Agreement counts only these, at half the work of all the points."""
    x, y, z, facing = posed_xyz(R, t, model, dtype)
    count = facing.sum(1)
    K = int(count.max(initial=0))
    rows, cols = np.nonzero(facing)  # row-major: each pose's facing points in model order
    slot = np.arange(len(rows)) - np.repeat(np.cumsum(count) - count, count)
    chosen = np.zeros((len(facing), K), np.intp)
    chosen[rows, slot] = cols
    return (*(np.take_along_axis(c, chosen, 1) for c in (x, y, z)), np.arange(K) < count[:, None])


def _dtype(depth: np.ndarray) -> Any:
    """The float type points are scored in against ``depth``: its own (float32 halves the memory traffic:
    millimetre tolerances at metres lose nothing in it)."""
    return depth.dtype if depth.dtype in (np.float32, np.float64) else np.float64


def turns(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations (T, 3, 3) by ``angles`` (T,) radians about the unit ``axis`` (3,) (Rodrigues)."""
    return rodrigues(axis, angles)


def skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrices (..., 3, 3) of vectors (..., 3): ``skew(v) @ x == np.cross(v, x)``."""
    v = np.asarray(v, np.float64)
    K = np.zeros((*v.shape, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    K[..., 1, 0], K[..., 2, 0], K[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return K


def rodrigues(axes: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations (..., 3, 3) by ``angles`` (...) radians about unit ``axes`` (..., 3), broadcast together."""
    axes, angles = np.broadcast_arrays(np.asarray(axes, np.float64), np.asarray(angles, np.float64)[..., None])
    K = skew(axes)
    s, c = np.sin(angles[..., :1])[..., None], np.cos(angles[..., :1])[..., None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _offsets(step: float, reach: float) -> np.ndarray:
    """Shifts -k step .. k step (k steps within ``reach``), the smallest first: no shift wins ties."""
    k = int(np.floor(reach / step + 1e-9))
    values = np.arange(-k, k + 1) * step
    return values[np.argsort(np.abs(values), kind="stable")]


#: candidate points scored per batch of the turn search (bounds its memory: about 100 MB)
BATCH_POINTS = 1_500_000


def _best_of(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any, n: np.ndarray,
             angles: np.ndarray, offsets: np.ndarray, frame: tuple[np.ndarray, np.ndarray], settings: SearchSettings,
             keep: int = 1) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """For each of N poses (N, 3, 3), (N, 3): the ``keep`` best among its turns by ``angles`` (A,) radians
    about its axis ``n`` (N, 3) through t and its shifts ``offsets[i] e1 + offsets[j] e2`` (metres; ``frame``:
    e1, e2 (N, 3)); the best shift of each turn only, best first (ties: the earlier angle, the smaller shift).
    Returns agreement (N, keep), R (N, keep, 3, 3), t (N, keep, 3), angle (N, keep)."""
    e1, e2 = frame
    N, A = len(R), len(angles)
    shifts = (offsets[None, :, None, None] * e1[:, None, None] + offsets[None, None, :, None] * e2[:, None, None])
    shifts = shifts.reshape(N, -1, 3)  # (N, M, 3), row-major (i, j)
    Rs = (rodrigues(n[:, None], angles[None]) @ R[:, None]).reshape(-1, 3, 3)  # (N A, 3, 3)
    x, y, z, facing = facing_xyz(Rs, np.repeat(t, A, 0), model, _dtype(depth))  # (N A, K) each
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
        R (N, 3, 3), t (N, 3): the poses (camera frame, metres). model: a :class:`opnet.geometry.icp.ModelCloud`.
        depth: (H, W) z-depth (metres, NaN missing) seen by ``camera`` (fx, fy, cx, cy).
        axis: the model-frame axis to turn about (:func:`model_axis`).
    Returns:
        R (N, 3, 3), t (N, 3), agreement (N,) of each pose's best candidate (the first of equals: no turn, no
        shift, if it ties).
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
    coarse = _best_of(R, t, model, depth, camera, n, angles, _offsets(step * D, s.shift * D), frame, s, keep=3)
    if s.fine == "local":
        return _refine_turns(coarse[:3], model, depth, camera, n, frame, np.radians(turn) / 2, step * D / 2, s)
    out_R, out_t, out_s = R.copy(), t.copy(), np.full(len(R), -np.inf)
    for c in range(coarse[0].shape[1]):  # around each of the three best coarse turns, the first best of equals
        angle = coarse[3][:, c]
        for h in range(len(R)):
            fine = np.radians(np.arange(-turn, turn + 1e-9, s.turn_step_deg)) + angle[h]
            fine = fine[np.argsort(np.abs(fine - angle[h]), kind="stable")]  # the coarse turn first: it wins ties
            score, Rb, tb, _ = _best_of(R[h : h + 1], coarse[2][h : h + 1, c], model, depth, camera, n[h : h + 1],
                                        fine, _offsets(s.shift_step * D, step * D), (e1[h : h + 1], frame[1][h : h + 1]),
                                        s)  # fmt: skip
            if score[0, 0] > out_s[h]:
                out_R[h], out_t[h], out_s[h] = Rb[0, 0], tb[0, 0], score[0, 0]
    return out_R, out_t, out_s


def _refine_turns(starts: tuple[np.ndarray, np.ndarray, np.ndarray], model: Any, depth: np.ndarray, camera: Any,
                  n: np.ndarray, frame: tuple[np.ndarray, np.ndarray], turn: float, shift: float,
                  settings: SearchSettings) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """``fine: local``: from each pose's coarse best (``starts``: agreement (N, S), R (N, S, 3, 3), t (N, S, 3))
    a pattern search of six moves (a turn of ``turn`` radians about its axis ``n`` (N, 3) either way, a shift of
    ``shift`` metres either way along each of ``frame`` (N, 3) each), every start's moves scored in one batch; a
    start whose best is to stay halves its steps; a pose's starts go on until all its steps are below half the
    grid's own. Each pose's best (the first start of equals): R (N, 3, 3), t (N, 3), agreement (N,)."""
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


def axis_permutations() -> np.ndarray:
    """The 24 rotations that map the coordinate axes onto one another (signed permutations, det +1),
    the identity first."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            M = np.zeros((3, 3))
            M[range(3), perm] = signs
            if np.linalg.det(M) > 0:
                out.append(M)
    out.sort(key=lambda M: -np.trace(M))  # the identity (trace 3) first
    return np.array(out)


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


def score_poses(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any,
                settings: SearchSettings) -> np.ndarray:  # fmt: skip
    """Agreement of poses (N, 3, 3), (N, 3) (their model points facing the camera), in one batch."""
    x, y, z, facing = facing_xyz(R, t, model, _dtype(depth))
    return agreement_xyz(x, y, z, facing, depth, camera, settings.tolerance * model.diameter,
                         settings.see_through_weight)  # fmt: skip


def facing_points(R: np.ndarray, t: np.ndarray, model: Any) -> tuple[np.ndarray, np.ndarray]:
    """:func:`facing_xyz` as points: (N, K, 3) and which of them are real (N, K)."""
    x, y, z, valid = facing_xyz(R, t, model)
    return np.stack((x, y, z), -1), valid


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


def pose_agreement(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any,
                   settings: SearchSettings) -> float:  # fmt: skip
    """:func:`agreement` of one pose (its model points facing the camera)."""
    return float(score_poses(np.asarray(R)[None], np.asarray(t)[None], model, depth, camera, settings)[0])


__all__ = [
    "AXES",
    "MODES",
    "SCORES",
    "SearchSettings",
    "agreement",
    "agreement_xyz",
    "ambiguity_turns",
    "axis_permutations",
    "facing_points",
    "facing_xyz",
    "is_flat",
    "local_search",
    "model_axis",
    "pose_agreement",
    "posed_xyz",
    "resolve_mode",
    "rodrigues",
    "score_poses",
    "search_any",
    "search_any_many",
    "search_pose",
    "search_poses",
    "turns",
]
