"""Collision shapes and mass properties of a part for pybullet.

Decisions:
- "convex_hull": pybullet builds the convex hull of the mesh vertices. Fast and stable, right for
  convex-ish parts (the pin).
- "vhacd": an approximate convex decomposition (pybullet's built-in V-HACD 2.2, voxel mode) made
  once per mesh and cached as an OBJ file named by a hash of the mesh and the V-HACD settings, in
  ``cache_dir`` (default $OPNET_CACHE or ~/.cache/opnet). V-HACD is single-threaded here and
  deterministic (same input, same bytes), and the cache is written atomically, so parallel workers
  and later runs all load the same decomposition. pybullet turns the multi-object OBJ into a
  compound of convex hulls.
- "auto": "vhacd" when the mesh volume is below ``convexity_threshold`` times its hull volume
  (the L/Z brackets, the stepped shaft, the bunny, the ring screw, the gear shaft), else the hull.
- Mass and centre of mass come from the closed mesh (uniform density 1000 kg/m^3, only ratios
  matter), or from its convex hull when the mesh is not watertight; the inertial frame is the
  principal frame. The principal moments are computed but not given to pybullet: 3.2.7 turns
  maximal-coordinate bodies into NaN when ``localInertiaDiagonal`` is changed, so Bullet's own
  estimate from the collision shape is used (irrelevant for piles at rest).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from opnet.synthesis.config import SceneConfig

DENSITY = 1000.0  # kg/m^3
_VHACD_VERSION = "pybullet-vhacd-2.2-v1"  # bump to invalidate old cache entries
#: vertices per convex part: 32 steps about 25 % faster than V-HACD's 64 in piles, same shape
VHACD_MAX_VERTICES = 32


@dataclass(frozen=True)
class CollisionModel:
    """What the simulator needs to make bodies of one part.

    Attributes:
        mode: "convex_hull" or "vhacd".
        vertices: (V, 3) float64 mesh vertices, model frame, metres (convex_hull mode).
        obj_file: the cached decomposition, model frame, metres (vhacd mode).
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


def default_cache_dir() -> Path:
    """$OPNET_CACHE, else ``~/.cache/opnet``."""
    env = os.environ.get("OPNET_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "opnet"


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
    mode = choose_mode(mesh, cfg)
    obj_file = vhacd_cached(mesh, cfg.vhacd_resolution, cache_dir or _cfg_cache(cfg)) if mode == "vhacd" else None
    mass, com, axes, moments = mass_properties(mesh)
    return CollisionModel(mode, np.asarray(mesh.vertices, dtype=np.float64), obj_file, mass, com, axes, moments)


def _cfg_cache(cfg: SceneConfig) -> Path:
    return Path(cfg.cache_dir).expanduser() if cfg.cache_dir else default_cache_dir()


def mesh_key(mesh: trimesh.Trimesh, resolution: int) -> str:
    """Hash of the mesh geometry and the V-HACD settings: the cache file name."""
    h = hashlib.sha256(_VHACD_VERSION.encode())
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    h.update(f"{int(resolution)}/{VHACD_MAX_VERTICES}".encode())
    return h.hexdigest()[:24]


def vhacd_cached(mesh: trimesh.Trimesh, resolution: int, cache_dir: Path) -> Path:
    """The convex decomposition of ``mesh`` as an OBJ file in ``cache_dir``, computed if missing."""
    out = Path(cache_dir) / f"vhacd_{mesh_key(mesh, resolution)}.obj"
    if out.is_file():
        return out
    import pybullet as pb

    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent, prefix=".vhacd_") as tmp:
        src, dst, log = Path(tmp) / "in.obj", Path(tmp) / "out.obj", Path(tmp) / "log.txt"
        mesh.export(src)
        client = pb.connect(pb.DIRECT)
        try:
            with _quiet_stdout():
                pb.vhacd(str(src), str(dst), str(log), resolution=int(resolution),
                         maxNumVerticesPerCH=VHACD_MAX_VERTICES, physicsClientId=client)
        finally:
            pb.disconnect(client)
        if not dst.is_file() or dst.stat().st_size == 0:
            raise ValueError(f"convex decomposition of the mesh failed (V-HACD wrote nothing; log: {log.read_text()[-500:]})")
        os.replace(dst, out)
    return out


@contextlib.contextmanager
def _quiet_stdout() -> Iterator[None]:
    """Silence C-level stdout (V-HACD prints its progress there)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "wb") as devnull:
            os.dup2(devnull.fileno(), 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
