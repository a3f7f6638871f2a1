"""Collision shapes and mass properties of a part for the physics engines.

Decisions:
- "convex_hull": the engine builds the convex hull of the mesh vertices. Fast and stable, right
  for convex-ish parts (the pin).
- "vhacd": an approximate convex decomposition made once per mesh and cached as a multi-object OBJ
  file named by a hash of the mesh and the decomposition settings, in ``cache_dir`` (default
  $OPNET_CACHE or ~/.cache/opnet): for MuJoCo (the default engine) CoACD (``coacd_threshold``;
  maintained, wheels for every CPython 3), for pybullet its built-in V-HACD 2.2 (voxel mode), as
  the datasets made before MuJoCo were. Both run single-threaded in a child process with a time
  cap, are deterministic (same input, same bytes), and the cache is written atomically, so
  parallel workers and later runs all load the same decomposition. The engine turns the OBJ's
  objects into a compound of convex hulls (:func:`convex_parts`).
- ``max_convex_pieces``: a decomposition of more pieces is merged toward that many (the pair whose
  joint hull adds the least volume first), as far as the merges add at most ``convex_merge_budget``
  of its volume, and cached beside it. A physics step costs about the convex pieces in contact: a
  T-LESS 20 pile of 39 pieces per part took five times a bunny's.
- "auto": "vhacd" when the mesh volume is below ``convexity_threshold`` times its hull volume
  (the L/Z brackets, the stepped shaft, the bunny, the ring screw, the gear shaft), else the hull.
- Mass and centre of mass come from the closed mesh (uniform density 1000 kg/m^3, only ratios
  matter), or from its convex hull when the mesh is not watertight; the inertial frame is the
  principal frame. The principal moments are computed but not given to pybullet: 3.2.7 turns
  maximal-coordinate bodies into NaN when ``localInertiaDiagonal`` is changed, so Bullet's own
  estimate from the collision shape is used (irrelevant for piles at rest).
"""

from __future__ import annotations

import hashlib
import logging
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from opnet.paths import user_cache_dir
from opnet.synthesis.config import SceneConfig

DENSITY = 1000.0  # kg/m^3
_VHACD_VERSION = "pybullet-vhacd-2.2-v1"  # bump to invalidate old cache entries
_COACD_VERSION = "coacd-1-v1"
#: vertices per convex part: 32 steps about 25 % faster than V-HACD's 64 in piles, same shape
VHACD_MAX_VERTICES = 32
#: default time cap of one decomposition, made once per mesh and cached: the built-in meshes take 5..60 s,
#: an industrial part of 24k triangles (two shells) 245 CPU seconds of CoACD, over 300 s of wall time on two
#: shared cores (the hull fallback then fills every hole of the part)
VHACD_TIMEOUT_S = 1200.0
#: convex hull volume / extent^3 below which a mesh counts as flat (a 10 cm plate 0.1 mm thick: 1e-3)
MIN_RELATIVE_VOLUME = 1e-6


@dataclass(frozen=True)
class CollisionModel:
    """What the simulator needs to make bodies of one part.

    Attributes:
        mode: "convex_hull" or "vhacd".
        vertices: (V, 3) float64 mesh vertices, model frame, metres (convex_hull mode).
        obj_file: the cached decomposition, model frame, metres (vhacd mode; one OBJ object per
            convex part).
        mass: kg.
        com: (3,) centre of mass in the model frame, metres.
        R_model_inertial: (3, 3) principal axes of inertia as columns, model frame (det +1).
        inertia: (3,) principal moments of inertia, kg m^2 (informative; see the module docstring).
    """

    mode: str
    vertices: np.ndarray
    obj_file: Path | None
    mass: float
    com: np.ndarray
    R_model_inertial: np.ndarray
    inertia: np.ndarray


def convexity(mesh: trimesh.Trimesh) -> float:
    """Mesh volume / convex hull volume (1 for a convex part); 0 when the mesh is not closed."""
    if not mesh.is_watertight:
        return 0.0
    return float(abs(mesh.volume) / mesh.convex_hull.volume)


def choose_mode(mesh: trimesh.Trimesh, cfg: SceneConfig) -> str:
    """The collision mode ``cfg.collision`` asks for, resolving "auto" (see the module docstring)."""
    if cfg.collision != "auto":
        return cfg.collision
    return "vhacd" if convexity(mesh) < cfg.convexity_threshold else "convex_hull"


def mass_properties(mesh: trimesh.Trimesh) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """(mass kg, com (3,), R_model_inertial (3, 3), principal moments (3,)) at :data:`DENSITY`."""
    solid = mesh if mesh.is_watertight and abs(mesh.volume) > 0 else mesh.convex_hull
    solid = solid.copy()
    solid.density = DENSITY
    moments, axes = np.linalg.eigh(np.asarray(solid.moment_inertia, dtype=np.float64))
    if np.linalg.det(axes) < 0:
        axes[:, 0] = -axes[:, 0]
    return float(solid.mass), np.asarray(solid.center_mass, dtype=np.float64), axes, np.clip(moments, 1e-12, None)


def build_collision_model(mesh: trimesh.Trimesh, cfg: SceneConfig, cache_dir: Path | None = None) -> CollisionModel:
    """Collision model of ``mesh`` (metres, model frame); runs V-HACD on a cache miss (seconds)."""
    check_solid(mesh)
    mode = choose_mode(mesh, cfg)
    obj_file = None
    if mode == "vhacd":
        cache = cache_dir or _cfg_cache(cfg)
        if cfg.physics == "pybullet":
            obj_file = vhacd_cached(mesh, cfg.vhacd_resolution, cache)
        else:
            obj_file = coacd_cached(mesh, cfg.coacd_threshold, cache)
    if obj_file is not None and cfg.max_convex_pieces:
        obj_file = merged_cached(obj_file, cfg.max_convex_pieces, cfg.convex_merge_budget)
    if mode == "vhacd" and obj_file is None:
        mode = "convex_hull"  # the decomposition ran past its time cap (warned): the hull still simulates
    mass, com, axes, moments = mass_properties(mesh)
    return CollisionModel(mode, np.asarray(mesh.vertices, dtype=np.float64), obj_file, mass, com, axes, moments)


def _cfg_cache(cfg: SceneConfig) -> Path:
    return Path(cfg.cache_dir).expanduser() if cfg.cache_dir else user_cache_dir()


def mesh_key(mesh: trimesh.Trimesh, resolution: int, version: str = _VHACD_VERSION, setting: str | None = None) -> str:
    """Hash of the mesh geometry and the decomposition's settings: the cache file name (V-HACD's
    ``resolution`` by default; another method gives its ``version`` and ``setting`` text)."""
    h = hashlib.sha256(version.encode())
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    h.update((f"{int(resolution)}" if setting is None else setting).encode() + f"/{VHACD_MAX_VERTICES}".encode())
    return h.hexdigest()[:24]


def check_solid(mesh: trimesh.Trimesh) -> None:
    """A part must enclose a volume: a flat sheet or a single triangle cannot be simulated (and
    kept V-HACD busy for minutes).

    Raises:
        ValueError: the mesh has (almost) no volume.
    """
    extent = float(np.max(mesh.extents)) if len(mesh.vertices) else 0.0
    try:
        hull_volume = float(mesh.convex_hull.volume) if extent > 0 else 0.0
    except Exception:  # noqa: BLE001 - qhull refuses coplanar points: that is the flat case
        hull_volume = 0.0
    if extent <= 0 or hull_volume < MIN_RELATIVE_VOLUME * extent**3:
        raise ValueError(
            f"the mesh has no volume (flat, a single triangle, or degenerate: convex hull {hull_volume:.3g} m^3 "
            f"for an extent of {extent:.3g} m); a part must be a solid"
        )


def vhacd_timeout_s() -> float:
    """Time cap of one convex decomposition: $OPNET_VHACD_TIMEOUT seconds, default 1200."""
    try:
        return float(os.environ.get("OPNET_VHACD_TIMEOUT", VHACD_TIMEOUT_S))
    except ValueError:
        raise ValueError(f"OPNET_VHACD_TIMEOUT={os.environ['OPNET_VHACD_TIMEOUT']!r}: expected seconds") from None


def _run_vhacd(src: str, dst: str, log: str, resolution: int) -> None:
    from opnet._stdio import quiet_c_output

    with quiet_c_output():  # V-HACD prints its progress there
        import pybullet as pb

        client = pb.connect(pb.DIRECT)
        try:
            pb.vhacd(src, dst, log, resolution=int(resolution), maxNumVerticesPerCH=VHACD_MAX_VERTICES,
                     physicsClientId=client)
        finally:
            pb.disconnect(client)


def _run_coacd(src: str, dst: str, log: str, threshold: float) -> None:
    import coacd

    mesh = trimesh.load(src, force="mesh", process=False)
    coacd.set_log_level("error")
    parts = coacd.run_coacd(coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)), threshold=float(threshold),
                            max_ch_vertex=VHACD_MAX_VERTICES, seed=0)
    Path(dst).write_text(_parts_obj([np.asarray(v, dtype=np.float64) for v, _ in parts],
                                    [np.asarray(f, dtype=np.int64) for _, f in parts]))


def _parts_obj(vertices: list[np.ndarray], faces: list[np.ndarray]) -> str:
    """A multi-object OBJ: one object per convex part (1-based, file-wide vertex indices)."""
    lines, base = [], 1
    for k, (v, f) in enumerate(zip(vertices, faces, strict=True)):
        lines.append(f"o part_{k}")
        lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in v]
        lines += [f"f {a + base} {b + base} {c + base}" for a, b, c in f]
        base += len(v)
    return "\n".join(lines) + "\n"


def convex_parts(obj_file: Path) -> list[np.ndarray]:
    """The vertices (V_k, 3) of each object of a decomposition OBJ file, in file order.

    Raises:
        ValueError: the file holds no vertices or a malformed vertex line (names the file).
    """
    parts: list[list[list[float]]] = []
    for number, line in enumerate(Path(obj_file).read_text().splitlines(), 1):
        if line.startswith(("o ", "g ")) or (line.startswith("v ") and not parts):
            parts.append([])
        if line.startswith("v "):
            try:
                parts[-1].append([float(x) for x in line.split()[1:4]])
            except ValueError:
                raise ValueError(f"{obj_file}:{number}: malformed vertex line {line[:60]!r}") from None
    parts = [p for p in parts if p]
    if not parts:
        raise ValueError(f"{obj_file}: the convex decomposition holds no vertices")
    return [np.asarray(p, dtype=np.float64).reshape(-1, 3) for p in parts]


def _hull(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """(vertices, triangles, volume) of the convex hull of ``points`` (joggled when flat)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        hull = ConvexHull(points)
    except QhullError:
        hull = ConvexHull(points, qhull_options="QJ")
    keep = np.unique(hull.simplices)
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[keep] = np.arange(len(keep))
    return points[keep], remap[hull.simplices], float(hull.volume)


def _merge_sequence(hulls: list, max_pieces: int) -> tuple[list[tuple[int, int]], list[float]]:
    """The greedy merges of ``hulls`` down to ``max_pieces``: the (kept, absorbed) index pairs in
    order and the volume each added (joint hull minus the two pieces; negative where they overlap)."""
    hulls = list(hulls)
    n = len(hulls)

    def added(i: int, j: int) -> float:
        return _hull(np.concatenate([hulls[i][0], hulls[j][0]]))[2] - hulls[i][2] - hulls[j][2]

    cost = np.full((n, n), np.inf)
    for i in range(n):
        for j in range(i + 1, n):
            cost[i, j] = added(i, j)
    alive, pairs, costs = list(range(n)), [], []
    while len(alive) > max_pieces:
        sub = cost[np.ix_(alive, alive)]
        a, b = np.unravel_index(int(np.argmin(sub)), sub.shape)
        i, j = alive[min(a, b)], alive[max(a, b)]
        pairs.append((i, j))
        costs.append(float(sub[a, b]))
        hulls[i] = _hull(np.concatenate([hulls[i][0], hulls[j][0]]))
        alive.remove(j)
        for k in alive:
            if k != i:
                cost[min(i, k), max(i, k)] = added(i, k)
    return pairs, costs


def merge_convex_parts(parts: list[np.ndarray], max_pieces: int,
                       budget: float | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """``parts`` (vertex arrays of convex pieces) merged toward ``max_pieces`` hulls, as (vertices,
    triangles) each: repeatedly the two pieces whose joint convex hull adds the least volume to
    theirs are replaced by that hull (ties: the lowest indices). ``budget``: stop at the fewest
    pieces, along that sequence, whose merges added at most this fraction of the pieces' volume (a
    part with fine concave features keeps them; None: down to ``max_pieces``). Deterministic; a part
    of no more than ``max_pieces`` pieces comes back as their hulls, in order."""
    if max_pieces < 1:
        raise ValueError(f"max_pieces={max_pieces}: expected an integer >= 1")
    hulls = [_hull(np.asarray(p, dtype=np.float64)) for p in parts]
    pairs, costs = _merge_sequence(hulls, max_pieces)
    if budget is not None:
        allowed = float(budget) * sum(h[2] for h in hulls)
        within = [k + 1 for k, total in enumerate(np.cumsum(costs)) if total <= allowed]
        pairs = pairs[:max(within, default=0)]
    alive = list(range(len(hulls)))
    for i, j in pairs:
        hulls[i] = _hull(np.concatenate([hulls[i][0], hulls[j][0]]))
        alive.remove(j)
    return [(hulls[i][0], hulls[i][1]) for i in alive]


def merged_cached(obj_file: Path, max_pieces: int, budget: float | None = None) -> Path:
    """``obj_file`` (a decomposition) itself when it has at most ``max_pieces`` pieces, else its
    merge (:func:`merge_convex_parts`) cached beside it as ``<name>_max<max_pieces>[_b<budget>].obj``
    (written atomically: parallel workers may make it at once, all write the same bytes)."""
    parts = convex_parts(obj_file)
    if len(parts) <= max_pieces:
        return obj_file
    tag = f"_max{int(max_pieces)}" + ("" if budget is None else f"_b{float(budget):g}")
    out = obj_file.with_name(f"{obj_file.stem}{tag}.obj")
    if not out.is_file():
        merged = merge_convex_parts(parts, max_pieces, budget)
        fd, tmp = tempfile.mkstemp(dir=out.parent, prefix=".merge_", suffix=".obj")
        with os.fdopen(fd, "w") as f:
            f.write(_parts_obj([v for v, _ in merged], [t for _, t in merged]))
        os.replace(tmp, out)
    return out


def coacd_cached(mesh: trimesh.Trimesh, threshold: float, cache_dir: Path, timeout_s: float | None = None) -> Path | None:
    """The CoACD decomposition of ``mesh`` as an OBJ file in ``cache_dir`` (see :func:`vhacd_cached`)."""
    out = Path(cache_dir) / f"coacd_{mesh_key(mesh, 0, _COACD_VERSION, repr(float(threshold)))}.obj"
    return _decomposition_cached(mesh, out, "coacd", threshold, "CoACD", timeout_s)


def vhacd_cached(mesh: trimesh.Trimesh, resolution: int, cache_dir: Path, timeout_s: float | None = None) -> Path | None:
    """The convex decomposition of ``mesh`` as an OBJ file in ``cache_dir``, computed if missing.

    V-HACD runs in a child process with a time cap (:func:`vhacd_timeout_s`); past it the child is
    stopped, its temporary folder removed, a warning logged, and None returned (the caller uses
    the convex hull).
    """
    out = Path(cache_dir) / f"vhacd_{mesh_key(mesh, resolution)}.obj"
    return _decomposition_cached(mesh, out, "vhacd", resolution, "V-HACD", timeout_s)


def _child(run, src: str, dst: str, log: str, setting: float) -> None:
    """Run a decomposition; an exception goes to ``log`` (one line for the parent's error), not stderr."""
    try:
        run(src, dst, log, setting)
    except Exception as e:  # noqa: BLE001 - reported by the parent
        Path(log).write_text(f"{type(e).__name__}: {e}")
        Path(dst).unlink(missing_ok=True)


def _child_main(argv: list[str]) -> None:
    """Entry of the decomposition process: ``<coacd|vhacd> src dst log setting``."""
    method, src, dst, log, setting = argv
    run = {"coacd": _run_coacd, "vhacd": _run_vhacd}[method]
    _child(run, src, dst, log, float(setting) if method == "coacd" else int(setting))


def _decomposition_cached(mesh: trimesh.Trimesh, out: Path, method: str, setting: float, name: str,
                          timeout_s: float | None) -> Path | None:
    """``out``, made by ``method`` ("coacd" or "vhacd") in a child process if missing (time cap).

    The child is a fresh interpreter (not a fork: a forked child of a process whose OpenMP pool is
    running, torch's in train.py and the tests, deadlocks in CoACD's OpenMP start-up; nor
    multiprocessing's spawn, which re-imports the caller's main script)."""
    if out.is_file():
        return out
    timeout_s = vhacd_timeout_s() if timeout_s is None else timeout_s
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent, prefix=".vhacd_") as tmp:
        src, dst, log = Path(tmp) / "in.obj", Path(tmp) / "out.obj", Path(tmp) / "log.txt"
        mesh.export(src)
        code = "import sys; from opnet.synthesis.collision import _child_main; _child_main(sys.argv[1:])"
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
        try:
            subprocess.run([sys.executable, "-c", code, method, str(src), str(dst), str(log), repr(setting)], env=env,
                           stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           timeout=timeout_s, check=False)
        except subprocess.TimeoutExpired:  # the child is killed
            logging.getLogger(__name__).warning(
                "%s did not finish within %g s (OPNET_VHACD_TIMEOUT); using the convex hull of the mesh: a concave "
                "part then piles as its hull would (raise OPNET_VHACD_TIMEOUT to decompose it; made once, cached)",
                name, timeout_s)
            return None
        if not dst.is_file() or dst.stat().st_size == 0:
            tail = log.read_text()[-500:] if log.is_file() else "no log"
            raise ValueError(f"convex decomposition of the mesh failed ({name} wrote nothing; log: {tail}); "
                             "try scene.collision=convex_hull")
        os.replace(dst, out)
    return out
