"""Depth-agreement search around a pose hypothesis: the refinement ICP cannot do (issue 26).

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
    z = points[..., 2]
    safe = np.where(z > 0, z, np.inf)
    u = np.floor(points[..., 0] * camera.fx / safe + camera.cx + 0.5)
    v = np.floor(points[..., 1] * camera.fy / safe + camera.cy + 0.5)
    h, w = depth.shape
    inside = valid & (z > 0) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    measured = depth[np.where(inside, v, 0).astype(np.intp), np.where(inside, u, 0).astype(np.intp)]
    r = np.where(inside, measured - z, np.nan)
    agree = np.sum(np.abs(r) <= tolerance, -1)  # NaN compares False: missing depth counts neither way
    through = np.sum(r > tolerance, -1)
    return (agree - see_through_weight * through) / np.maximum(np.sum(valid, -1), 1)


def turns(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations (T, 3, 3) by ``angles`` (T,) radians about the unit ``axis`` (Rodrigues)."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    s, c = np.sin(angles)[:, None, None], np.cos(angles)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * (K @ K)


def _best_of(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any, n: np.ndarray,
             angles: np.ndarray, offsets: np.ndarray, frame: tuple[np.ndarray, np.ndarray], settings: SearchSettings,
             keep: int = 1) -> list[tuple[float, np.ndarray, np.ndarray, float]]:  # fmt: skip
    """The ``keep`` best (agreement, R, t, angle) among the turns ``angles`` (radians) of R about
    ``n`` through t and the shifts ``offsets[i] e1 + offsets[j] e2`` (metres); the best turn of each
    angle only, best first (ties: the earlier angle, the smaller shift)."""
    e1, e2 = frame
    shifts = (offsets[:, None, None] * e1 + offsets[None, :, None] * e2).reshape(-1, 3)  # (M, 3), row-major (i, j)
    D, found = model.diameter, []
    for angle, Rk in zip(angles, turns(n, angles) @ R, strict=True):  # one turn at a time: (M, K, 3) stays small
        posed, facing = model.posed(Rk, t)
        pts = posed[facing]
        scores = agreement(pts[None] + shifts[:, None], np.ones((len(shifts), len(pts)), bool), depth, camera,
                           settings.tolerance * D, settings.see_through_weight)  # fmt: skip
        m = int(np.argmax(scores))
        found.append((float(scores[m]), Rk, t + shifts[m], float(angle)))
    found.sort(key=lambda f: -f[0])  # stable: ties keep the earlier angle
    return found[:keep]


def search_pose(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any, axis: np.ndarray,
                settings: SearchSettings) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """The best pose among the turns and shifts of (R, t) (module docstring) and its agreement.

    With ``coarse`` > 1 the grid is first searched at ``coarse`` times its steps, then at its own
    steps around the three best coarse turns (± one coarse step of turn and shift each way).

    Args:
        R (3, 3), t (3,): the pose (camera frame, metres). model: a :class:`opnet.geometry.icp.ModelCloud`.
        depth: (H, W) z-depth (metres, NaN missing) seen by ``camera`` (fx, fy, cx, cy).
        axis: the model-frame axis to turn about (:func:`model_axis`).
    Returns:
        (R, t, agreement) of the best candidate (the first of equals: no turn, no shift, if it ties).
    """
    D, s = model.diameter, settings
    n = R @ axis  # the axis in the camera frame, through the origin t
    helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    frame = (e1, np.cross(n, e1))

    def offsets(step: float, reach: float) -> np.ndarray:
        k = int(np.floor(reach / step + 1e-9))
        values = np.arange(-k, k + 1) * step
        return values[np.argsort(np.abs(values), kind="stable")]  # no shift first: it wins ties

    if s.coarse <= 1:
        angles = np.radians(np.arange(0.0, 360.0 - 1e-9, s.turn_step_deg))
        best = _best_of(R, t, model, depth, camera, n, angles, offsets(s.shift_step * D, s.shift * D), frame, s)[0]
        return best[1], best[2], best[0]
    turn, step = s.turn_step_deg * s.coarse, s.shift_step * s.coarse
    angles = np.radians(np.arange(0.0, 360.0 - 1e-9, turn))
    coarse = _best_of(R, t, model, depth, camera, n, angles, offsets(step * D, s.shift * D), frame, s, keep=3)
    if s.fine == "local":
        return _refine_turns(coarse, model, depth, camera, n, frame, np.radians(turn) / 2, step * D / 2, s)
    best = None
    for _, _, t_c, angle in coarse:
        fine = np.radians(np.arange(-turn, turn + 1e-9, s.turn_step_deg)) + angle
        fine = fine[np.argsort(np.abs(fine - angle), kind="stable")]  # the coarse turn first: it wins ties
        found = _best_of(R, t_c, model, depth, camera, n, fine, offsets(s.shift_step * D, step * D), frame, s)[0]
        if best is None or found[0] > best[0]:
            best = found
    return best[1], best[2], best[0]


def _refine_turns(starts: list[tuple[float, np.ndarray, np.ndarray, float]], model: Any, depth: np.ndarray, camera: Any,
                  n: np.ndarray, frame: tuple[np.ndarray, np.ndarray], turn: float, shift: float,
                  settings: SearchSettings) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """``fine: local``: from the coarse grid's best poses a pattern search of six moves (a turn of ``turn``
    radians about ``n`` either way, a shift of ``shift`` metres either way along each of ``frame``), every
    start's moves scored in one batch; a start whose best is to stay halves its steps, until they are below
    half the grid's own steps. The best pose and its agreement (the first start of equals)."""
    R = np.array([f[1] for f in starts])
    t = np.array([f[2] for f in starts])
    score = np.array([f[0] for f in starts])
    C, rows = len(R), np.arange(len(R))
    steps_r, steps_t = np.full(C, turn), np.full(C, shift)
    stop_r, stop_t = np.radians(settings.turn_step_deg) / 2, settings.shift_step * model.diameter / 2
    e1, e2 = frame
    while (steps_r >= stop_r).any() or (steps_t >= stop_t).any():
        dR = np.repeat(np.eye(3)[None, None], C, 0).repeat(7, 1)  # (C, 7, 3, 3): stay, turn +-, shifts +- e1, e2
        dR[:, 1], dR[:, 2] = turns(n, steps_r), turns(n, -steps_r)
        dv = np.zeros((C, 7, 3))
        for j, e in enumerate((e1, -e1, e2, -e2)):
            dv[:, 3 + j] = steps_t[:, None] * e
        Rn = dR @ R[:, None]
        tn = t[:, None] + dv  # turns about the axis through the pose's origin, as the grid's
        s = score_poses(Rn.reshape(-1, 3, 3), tn.reshape(-1, 3), model, depth, camera, settings).reshape(C, 7)
        s[:, 0] = score
        best = s.argmax(1)
        stay = best == 0
        steps_r[stay] /= 2
        steps_t[stay] /= 2
        R, t, score = Rn[rows, best], tn[rows, best], s[rows, best]
    k = int(np.argmax(score))
    return R[k], t[k], float(score[k])


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
    p = np.einsum("nij,pj->npi", R, model.points) + t[:, None]
    facing = np.einsum("nij,pj,npi->np", R, model.normals, p) < 0
    return agreement(p, facing, depth, camera, settings.tolerance * model.diameter, settings.see_through_weight)


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
        s = score_poses(Rn.reshape(-1, 3, 3), tn.reshape(-1, 3), model, depth, camera, settings).reshape(C, 13)
        best = s.argmax(1)  # ties: the first, i.e. no move
        stay = best == 0
        step_r[stay] /= 2
        step_t[stay] /= 2
        R, t, score = Rn[rows, best], tn[rows, best], s[rows, best]
    return R, t, score


def search_any(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any, space: Any,
               settings: SearchSettings, turns_and_centre: tuple[np.ndarray, np.ndarray] | None = None,
               ) -> tuple[np.ndarray, np.ndarray, float]:  # fmt: skip
    """``mode: flips`` from one pose (3, 3), (3,) or several starts (S, 3, 3), (S, 3) (module docstring):
    the ambiguity turns of every start scored in one batch, at twice the tolerance (a turned hypothesis
    is a few degrees and millimetres out), the ``keep`` best searched locally; the best pose and its
    agreement (the first start itself unless beaten).

    Args:
        turns_and_centre: :func:`ambiguity_turns` of the model (made once per object by the caller).
    """
    R, t = np.asarray(R, np.float64).reshape(-1, 3, 3), np.asarray(t, np.float64).reshape(-1, 3)
    G, centre = turns_and_centre if turns_and_centre is not None else ambiguity_turns(model.points, space)
    Rc = (R[:, None] @ G).reshape(-1, 3, 3)  # (S * C, 3, 3): turned about the centroid, which stays
    tc = (np.einsum("sij,j->si", R, centre) + t)[:, None].repeat(len(G), 1).reshape(-1, 3) - Rc @ centre
    loose = dataclasses.replace(settings, tolerance=2.0 * settings.tolerance)
    score = score_poses(Rc, tc, model, depth, camera, loose)
    here = float(score_poses(R[:1], t[:1], model, depth, camera, settings)[0])
    if settings.keep == 0:
        k = int(np.argmax(score))
        return Rc[k], tc[k], float(score_poses(Rc[k : k + 1], tc[k : k + 1], model, depth, camera, settings)[0])
    order = np.argsort(-score, kind="stable")[: settings.keep]
    Rl, tl, sl = local_search(Rc[order], tc[order], centre, model, depth, camera, settings)
    k = int(np.argmax(sl))
    if sl[k] <= here:
        return R[0], t[0], here
    return Rl[k], tl[k], float(sl[k])


def pose_agreement(R: np.ndarray, t: np.ndarray, model: Any, depth: np.ndarray, camera: Any,
                   settings: SearchSettings) -> float:  # fmt: skip
    """:func:`agreement` of one pose (its model points facing the camera)."""
    posed, facing = model.posed(R, t)
    return float(agreement(posed[None], facing[None], depth, camera, settings.tolerance * model.diameter,
                           settings.see_through_weight)[0])  # fmt: skip


__all__ = ["AXES", "MODES", "SCORES", "SearchSettings", "agreement", "ambiguity_turns", "axis_permutations", "is_flat", "local_search",
           "model_axis", "pose_agreement", "resolve_mode", "score_poses", "search_any", "search_pose", "turns"]
