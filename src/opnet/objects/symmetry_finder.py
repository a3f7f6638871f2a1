"""Find a part's proper symmetries from its mesh, numerically (``opnet-object``).

A rotation ``g`` about the surface centroid is a symmetry when it maps the surface onto itself: every
point sampled evenly on the surface, turned by ``g``, lies within the tolerance of the surface (its
*deviation*: the 98th percentile of the distances from the turned points to a denser sample of the
surface, which a sampling gap, a chamfer or a missing face does not move, a turned feature does).

Candidates:

- the principal axes of the surface (its covariance about the centroid); where two of its spreads are
  equal (the plane of a cyclic part of order >= 3, a revolution part's cross-section) the directions of
  that plane every half degree are tried for half turns (a dihedral group's two-fold axes, a flip end
  over end); where all three are equal (a cube, a tetrahedron, a sphere) the directions from the
  centroid to the farthest surface points and to the face centres of the convex hull are tried too;
- about each candidate axis the turns by 360/k degrees, k = 72 down to 2 (the largest k that holds is
  the axis's order: gears, sprockets and bolt circles run to 60 and more), and five turns of unrelated
  angles: all five holding makes it a revolution axis.

The rotations found generate the group (closed under composition, each product checked); it is then
named as the metric wants it (:class:`opnet.geometry.symmetry.Symmetry`): none, cyclic k about one
axis, revolution (with the flip, rotoreflection), or a finite group (dihedral 2k, tetrahedral 12,
octahedral 24, icosahedral 60) given by its rotations. ``model_rotation`` turns the main axis (the
revolution axis, or the axis of highest order) onto z and, for a group with two-fold axes across it,
one of them onto x; ``model_origin`` is the centroid, which every symmetry axis passes through. A part
symmetric about more than one revolution axis (a sphere) is refused: its pose has no orientation.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from opnet.geometry.pose_numpy import axis_permutations, turns
from opnet.objects.surface import surface_moments

#: the turns that must all hold for a revolution axis (degrees, unrelated to one another and to 360/k)
REVOLUTION_TEST_DEG = (7.3, 23.9, 61.7, 97.1, 151.3)
#: the highest order tried about an axis (gears, sprockets and bolt circles run to 60 and more; a part of finer
#: symmetry is a revolution part to any camera)
MAX_ORDER = 72
#: two principal spreads within this share of one another are equal (a degenerate plane)
EQUAL_SPREAD = 0.03
#: the sample a revolution verdict limited by the sampling is checked again on
DENSE_SAMPLES = 12000
#: the largest group assembled (the dihedral group of the highest order tried)
MAX_GROUP = 2 * MAX_ORDER


@dataclass
class Candidate:
    """A turn tried: its axis (file frame, unit), angle (degrees) and deviation (metres)."""

    axis: np.ndarray
    angle_deg: float
    deviation: float


@dataclass
class SymmetryReport:
    """What :func:`find_symmetry` found.

    Attributes:
        spec: the ``symmetry`` entry of an object config (``{kind, order, rotoreflection, rotations}``;
            rotations in the model frame, i.e. after ``model_rotation``).
        name: the group's name (C1, C2, D6, C-inf, D-inf, T, O, I, ...).
        model_rotation: (3, 3): ``x_model = R (x_file - origin)``: the main axis onto z.
        origin: (3,) the centroid in the file's frame (metres), the symmetry centre.
        tolerance: metres; diameter: metres (D as the metric defines it, about the centroid).
        found: the symmetric turns, with their deviations; rejected: the best non-symmetric turn per
            axis tried (how far from symmetric it is).
    """

    spec: dict
    name: str
    model_rotation: np.ndarray
    origin: np.ndarray
    tolerance: float
    diameter: float
    group: np.ndarray
    found: list[Candidate] = field(default_factory=list)
    rejected: list[Candidate] = field(default_factory=list)


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    """The turn by ``angle`` radians about ``axis`` (any length)."""
    return turns(_unit(axis), np.array([angle]))[0]


class _Surface:
    """Evenly sampled surface points about the centroid, and the deviation of a turn."""

    def __init__(self, mesh: trimesh.Trimesh, samples: int, seed: int) -> None:
        moments = surface_moments(mesh.vertices, mesh.faces)  # exact: a symmetric mesh's axes come out exact
        self.centroid, self.covariance = moments.centroid, moments.covariance
        probe, _ = trimesh.sample.sample_surface(mesh, samples, seed=seed)
        dense, _ = trimesh.sample.sample_surface(mesh, 8 * samples, seed=seed + 1)
        self.points = np.asarray(probe, np.float64) - self.centroid
        self.tree = cKDTree(np.asarray(dense, np.float64) - self.centroid)
        # what two samplings of one surface differ by: the floor of any deviation
        self.floor = float(np.percentile(self._distances(self.points), 98))

    def _distances(self, points: np.ndarray) -> np.ndarray:
        """Each point's distance to the dense sample (the queries on every core)."""
        return self.tree.query(points, workers=-1)[0]

    def deviation(self, R: np.ndarray) -> float:
        return float(np.percentile(self._distances(self.points @ R.T), 98))

    def screen(self, R: np.ndarray) -> float:
        """The deviation on every 4th point: a quick look at whether a turn is close at all."""
        return float(np.percentile(self._distances(self.points[::4] @ R.T), 98))

    def mean_distance(self, R: np.ndarray) -> float:
        """The mean distance: smoother than the percentile, what an axis is refined by."""
        return float(self._distances(self.points @ R.T).mean())


def _principal(covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(spreads (3,) ascending, axes (3, 3) as columns) of a surface covariance."""
    w, V = np.linalg.eigh(covariance)
    return np.sqrt(np.maximum(w, 0.0)), V


def _refined(surface: _Surface, axis: np.ndarray, angle: float) -> tuple[np.ndarray, float]:
    """The axis near ``axis`` (within a few degrees) whose turn by ``angle`` radians deviates least: a pattern
    search tilting it about two directions across it; (axis, deviation)."""
    best = surface.mean_distance(_axis_rotation(axis, angle))
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    step = 2.0
    while step >= 0.03:
        e1 = _unit(np.cross(axis, helper))
        e2 = np.cross(axis, e1)
        moved = False
        for e in (e1, -e1, e2, -e2):
            cand = _unit(axis + math.tan(math.radians(step)) * e)
            dev = surface.mean_distance(_axis_rotation(cand, angle))
            if dev < best:
                axis, best, moved = cand, dev, True
                break
        if not moved:
            step /= 2
    return axis, surface.deviation(_axis_rotation(axis, angle))


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _same_axis(a: np.ndarray, b: np.ndarray, deg: float = 2.0) -> bool:
    return abs(float(a @ b)) > math.cos(math.radians(deg))


def _order(surface: _Surface, axis: np.ndarray, tol: float, rejected: list[Candidate],
           max_order: int = MAX_ORDER) -> tuple[int | None, list[Candidate]]:  # fmt: skip
    """The axis's order: None for a revolution axis, else the largest k (1: none) whose turn holds."""
    revolution = [Candidate(axis, a, surface.deviation(_axis_rotation(axis, math.radians(a)))) for a in REVOLUTION_TEST_DEG]
    if all(c.deviation <= tol for c in revolution):
        return None, revolution
    worst = max(revolution, key=lambda c: c.deviation)
    # an axis all of whose turns are close (a near-revolution: every k is close) is refined once, on an unrelated
    # turn; any other axis for each close k, once each of its multiples is close too
    shared = _refined(surface, axis.copy(), math.radians(REVOLUTION_TEST_DEG[2]))[0] \
        if all(c.deviation <= 3.0 * tol for c in revolution) else None  # fmt: skip

    def largest(about: np.ndarray, k: int, limit: float, quick: bool = False) -> float:
        """The largest deviation of the multiples of 360/k about ``about``, the half turn first (where a part that
        is only near-symmetric deviates most), stopping at the first beyond ``limit``; ``quick``: screened."""
        measure = surface.screen if quick else surface.deviation
        dev = 0.0
        for m in range(k // 2, 0, -1):
            dev = max(dev, measure(_axis_rotation(about, 2 * math.pi * m / k)))
            if dev > limit:
                break
        return dev

    for k in range(max_order, 1, -1):
        if surface.screen(_axis_rotation(axis, 2 * math.pi / k)) > 3.0 * tol:
            continue  # not close: the axis may be a degree off the mesh's own (a tessellation's asymmetry), no more
        if shared is not None:
            refined = shared
        elif largest(axis, k, 3.0 * tol, quick=True) <= 3.0 * tol:
            refined, _ = _refined(surface, axis.copy(), 2 * math.pi / k)
        else:
            continue
        # every multiple of the turn must hold (a 7-fold turn of a hexagon is close, twice it is not)
        worst_dev = largest(refined, k, tol)
        if worst_dev <= tol:
            axis[:] = refined
            return k, [Candidate(axis, 360.0 / k, worst_dev)]
    rejected.append(Candidate(axis, 180.0, surface.deviation(_axis_rotation(axis, math.pi))))
    rejected.append(worst)
    return 1, []


def _close_group(generators: list[np.ndarray], surface: _Surface, tol: float) -> np.ndarray:
    """The group the rotations generate (about the centroid), each element checked; ValueError when it grows
    past :data:`MAX_GROUP` or an element does not hold (the turns found were not one part's group)."""
    group = [np.eye(3)]

    def known(M: np.ndarray) -> bool:  # within 2 degrees of an element: the same (axes found numerically)
        return any(np.trace(M.T @ G) > 1 + 2 * math.cos(math.radians(2.0)) for G in group)

    frontier = [g for g in generators if not known(g)]
    for g in frontier:
        group.append(g)
    while frontier:
        new = []
        for A, B in itertools.product(group, frontier):
            for M in (A @ B, B @ A):
                U, _, Vt = np.linalg.svd(M)
                M = U @ Vt
                if not known(M):
                    group.append(M)
                    new.append(M)
                    if len(group) > MAX_GROUP:
                        raise ValueError(f"the symmetric turns found generate more than {MAX_GROUP} rotations")
        frontier = new
    bad = [dev for dev in map(surface.deviation, group) if dev > 2.5 * tol]  # products add the axes' errors
    if bad:
        raise ValueError(f"the symmetric turns found compose into turns that are not (deviation {max(bad) * 1000:.2f} mm)")
    return np.array(group)


def _frame(main: np.ndarray, across: np.ndarray | None) -> np.ndarray:
    """A rotation taking ``main`` onto z and ``across`` (if given, made perpendicular) onto x."""
    z = _unit(main)
    helper = across if across is not None else np.eye(3)[int(np.argmin(np.abs(z)))]
    x = _unit(helper - (helper @ z) * z)
    y = np.cross(z, x)
    return np.stack([x, y, z])  # rows: x_model = R x_file


def find_symmetry(mesh: trimesh.Trimesh, tolerance: float, samples: int = 3000, seed: int = 0) -> SymmetryReport:
    """The proper symmetry group of a mesh in metres (module docstring).

    Args:
        tolerance: metres; a turn whose deviation is at most this is a symmetry.
    Raises:
        ValueError: a sphere-like part (several revolution axes), or turns that do not form a group.
    """
    report = _find_symmetry(mesh, tolerance, samples, seed)
    if report.spec["kind"] == "revolution" and report.tolerance > float(tolerance) and samples < DENSE_SAMPLES:
        # the sampling floor, not the tolerance, let the revolution test pass: the teeth of a fine gear or a bolt
        # circle of many holes are finer than the sample; the axis is tried again on a denser one
        dense = _Surface(mesh, DENSE_SAMPLES, seed)
        tol = max(float(tolerance), 1.5 * dense.floor)
        axis = report.model_rotation.T @ np.array([0.0, 0.0, 1.0])
        if any(dense.deviation(_axis_rotation(axis, math.radians(a))) > tol for a in REVOLUTION_TEST_DEG):
            return _find_symmetry(mesh, tolerance, DENSE_SAMPLES, seed)
    return report


def _find_symmetry(mesh: trimesh.Trimesh, tolerance: float, samples: int, seed: int) -> SymmetryReport:
    surface = _Surface(mesh, samples, seed)
    tol = max(float(tolerance), 1.5 * surface.floor)
    spreads, V = _principal(surface.covariance)
    axes = [V[:, k] for k in range(3)]
    equal = [abs(spreads[i] - spreads[j]) <= EQUAL_SPREAD * max(spreads[j], 1e-12) for i, j in ((0, 1), (1, 2), (0, 2))]
    found: list[Candidate] = []
    rejected: list[Candidate] = []
    orders: list[tuple[np.ndarray, int | None]] = []
    for axis in axes:
        k, cands = _order(surface, axis, tol, rejected)
        orders.append((axis, k))
        found += cands
    revolution = [a for a, k in orders if k is None]
    if all(equal) or len(revolution) > 1:
        extra = _sphere_like_axes(mesh, surface)
        # the axes of a platonic group have orders 2 to 5
        more = [(a, _order(surface, a, tol, rejected, 5)) for a in extra if not any(_same_axis(a, b) for b, _ in orders)]
        for a, (k, cands) in more:
            orders.append((a, k))
            found += cands
        revolution = [a for a, k in orders if k is None]
        if len(revolution) > 1:
            raise ValueError("the part is symmetric about several axes of revolution (a sphere-like part): its pose "
                             "has no orientation to estimate; opnet needs a part with at most one axis of revolution")
    if revolution:
        axis = revolution[0]
        flip = _flip_across(surface, axis, tol, found, rejected)
        R = _frame(axis, flip)
        origin = surface.centroid
        spec = {"kind": "revolution", "rotoreflection": flip is not None}
        group = np.stack([np.eye(3), np.diag([1.0, -1.0, -1.0])]) if flip is not None else np.eye(3)[None]
        return _report(spec, "D-inf" if flip is not None else "C-inf", R, origin, tol, mesh, group, found, rejected)
    # a unique axis with a degenerate plane across it: half turns about the plane's directions
    if any(equal) and not all(equal):
        unique = 2 if equal[0] else 0
        plane = [k for k in range(3) if k != unique]
        degs = np.arange(0.0, 180.0, 0.5)
        dirs = [math.cos(math.radians(a)) * axes[plane[0]] + math.sin(math.radians(a)) * axes[plane[1]] for a in degs]
        devs = np.array([surface.screen(_axis_rotation(d, math.pi)) for d in dirs])
        minima = np.flatnonzero((devs <= np.roll(devs, 1)) & (devs <= np.roll(devs, -1)) & (devs <= 3.0 * tol))
        for i in minima[np.argsort(devs[minima])][:3]:  # the sweep's three best local minima, refined
            d, dev = _refined(surface, dirs[i], math.pi)
            if dev <= tol and not any(_same_axis(d, b) for b, _ in orders):
                orders.append((d, 2))
                found.append(Candidate(d, 180.0, dev))
                break  # one half turn across generates the others with the main axis (a dihedral group)
    # two generators: the axis of highest order and the best other axis not along it (more would only add
    # their numerical errors to the products)
    ranked = sorted([(a, k) for a, k in orders if k and k > 1], key=lambda ak: -ak[1])
    generators = [_axis_rotation(a, 2 * math.pi / k) for a, k in ranked[:1]]
    others = [(a, k) for a, k in ranked[1:] if not _same_axis(a, ranked[0][0])]
    generators += [_axis_rotation(a, 2 * math.pi / k) for a, k in others[:1]]
    group = _close_group(generators, surface, tol)
    return _classify(group, orders, surface, tol, mesh, found, rejected)


def _flip_across(surface: _Surface, axis: np.ndarray, tol: float, found: list[Candidate],
                 rejected: list[Candidate]) -> np.ndarray | None:  # fmt: skip
    """A direction across ``axis`` whose half turn holds (a revolution part alike end over end), or None."""
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = _unit(np.cross(axis, helper))
    e2 = np.cross(axis, e1)
    best = None
    for deg in (0.0, 45.0, 90.0, 135.0):
        d = math.cos(math.radians(deg)) * e1 + math.sin(math.radians(deg)) * e2
        c = Candidate(d, 180.0, surface.deviation(_axis_rotation(d, math.pi)))
        if c.deviation <= tol:
            found.append(c)
            return d
        best = c if best is None or c.deviation < best.deviation else best
    rejected.append(best)
    return None


def _sphere_like_axes(mesh: trimesh.Trimesh, surface: _Surface) -> list[np.ndarray]:
    """Candidate axes of a part with three equal spreads: towards its farthest surface points and the face
    centres of its convex hull (one per direction and its opposite)."""
    dirs = []
    far = surface.points[np.argsort(-np.linalg.norm(surface.points, axis=1))[:200]]
    hull = mesh.convex_hull
    centres = hull.triangles_center - surface.centroid
    for p in [*far, *centres, *(hull.face_normals)]:
        if np.linalg.norm(p) < 1e-9:
            continue
        d = _unit(p)
        if not any(_same_axis(d, e, 3.0) for e in dirs):
            dirs.append(d)
        if len(dirs) >= 60:
            break
    # the midpoints of pairs of neighbouring ones (edge axes of a platonic solid)
    pairs = [_unit(a + b) for a, b in itertools.combinations(dirs[:20], 2) if 0.2 < float(a @ b) < 0.95]
    for d in pairs:
        if not any(_same_axis(d, e, 3.0) for e in dirs):
            dirs.append(d)
    return dirs


def _axis_of(G: np.ndarray) -> tuple[np.ndarray, float]:
    """The unit axis and angle (degrees) of a rotation."""
    angle = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(G) - 1) / 2))))
    w, V = np.linalg.eig(G)
    axis = np.real(V[:, int(np.argmin(np.abs(w - 1)))])
    return _unit(axis), angle


def _classify(group: np.ndarray, orders: list, surface: _Surface, tol: float, mesh: trimesh.Trimesh,
              found: list[Candidate], rejected: list[Candidate]) -> SymmetryReport:  # fmt: skip
    n = len(group)
    origin = surface.centroid
    if n == 1:
        return _report({"kind": "none"}, "C1", np.eye(3), origin, tol, mesh, group, found, rejected)
    # each non-identity element's axis, and each axis's order (the number of elements about it, + 1)
    axes: list[tuple[np.ndarray, int]] = []
    for G in group[1:]:
        a, _ = _axis_of(G)
        for i, (b, k) in enumerate(axes):
            if _same_axis(a, b):
                axes[i] = (b, k + 1)
                break
        else:
            axes.append((a, 2))
    main, order = max(axes, key=lambda ak: ak[1])
    if len(axes) == 1:  # cyclic about one axis
        R = _frame(main, None)
        return _report({"kind": "cyclic", "order": order}, f"C{order}", R, origin, tol, mesh, group, found, rejected)
    across = [a for a, k in axes if k == 2 and abs(float(a @ main)) < math.sin(math.radians(3.0))]
    if order == n // 2 and len(across) == n // 2:  # dihedral D_k: the k-fold axis onto z, a two-fold onto x
        name, R = f"D{order}", _frame(main, across[0])
        exact = [_axis_rotation(np.eye(3)[2], 2 * math.pi * m / order) @ f for f in (np.eye(3), np.diag([1.0, -1.0, -1.0]))
                 for m in range(order)]  # fmt: skip
    elif n == 12 and order == 3:  # tetrahedral: its three two-fold axes onto x, y, z
        two = [a for a, k in axes if k == 2]
        name, R = "T", _frame(two[0], next(a for a in two[1:] if abs(float(a @ two[0])) < 0.1))
        exact = [P @ S for P in _cyclic_permutations() for S in _sign_flips()]
    elif n == 24 and order == 4:  # octahedral: two of its four-fold axes onto z and x
        four = [a for a, k in axes if k == 4]
        name, R = "O", _frame(four[0], next(a for a in four[1:] if abs(float(a @ four[0])) < 0.1))
        exact = list(axis_permutations())
    else:  # the icosahedral group (or an unnamed one): as measured, rounded
        name, R = ("I" if n == 60 else f"G{n}"), _frame(main, across[0] if across else None)
        exact = list(np.einsum("ij,njk,lk->nil", R, group, R))
    G_model = np.array(exact)
    spec = {"kind": "finite", "rotations": np.round(G_model, 9).tolist()}
    return _report(spec, name, R, origin, tol, mesh, group, found, rejected)


def _cyclic_permutations() -> list[np.ndarray]:
    return [np.eye(3), np.eye(3)[[1, 2, 0]], np.eye(3)[[2, 0, 1]]]


def _sign_flips() -> list[np.ndarray]:
    return [np.diag(d) for d in ((1.0, 1.0, 1.0), (1.0, -1.0, -1.0), (-1.0, 1.0, -1.0), (-1.0, -1.0, 1.0))]


def _report(spec: dict, name: str, R: np.ndarray, origin: np.ndarray, tol: float, mesh: trimesh.Trimesh,
            group: np.ndarray, found: list[Candidate], rejected: list[Candidate]) -> SymmetryReport:  # fmt: skip
    D = 2.0 * float(np.linalg.norm(np.asarray(mesh.vertices) - origin, axis=1).max())
    return SymmetryReport(spec, name, R, origin, tol, D, group, found, rejected)


__all__ = ["Candidate", "SymmetryReport", "find_symmetry"]
