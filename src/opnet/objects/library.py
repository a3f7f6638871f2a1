"""Built-in objects: procedural meshes that need no download, one per symmetry class.

| name      | symmetry                   | shape                                             |
|-----------|----------------------------|---------------------------------------------------|
| bracket   | none                       | L-shaped angle bracket with unequal legs          |
| zbracket  | cyclic, order 2 about z    | Z-profile bracket (centrally symmetric profile)   |
| shaft     | revolution about z         | stepped shaft                                     |
| pin       | revolution + rotoreflection| plain cylindrical pin                             |

Every mesh is in metres with its origin at the surface centroid, so the official and exact Brégier
distances coincide for them.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the mesh library is imported where a mesh is made or read (it costs a second at start)
    import trimesh

from opnet.geometry.symmetry import Symmetry
from opnet.objects.model import ObjectModel
from opnet.objects.surface import surface_moments

MM = 0.001


def _ear_clip(poly: np.ndarray) -> np.ndarray:
    """Triangulate a simple counter-clockwise polygon (N, 2) by ear clipping -> (N-2, 3) indices."""
    idx = list(range(len(poly)))
    tris: list[tuple[int, int, int]] = []

    def cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
        return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))

    while len(idx) > 3:
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = poly[i0], poly[i1], poly[i2]
            if cross(a, b, c) <= 0:  # reflex or collinear corner
                continue
            others = [poly[j] for j in idx if j not in (i0, i1, i2)]
            if any(cross(a, b, p) >= 0 and cross(b, c, p) >= 0 and cross(c, a, p) >= 0 for p in others):
                continue
            tris.append((i0, i1, i2))
            idx.pop(k)
            break
        else:
            raise ValueError("polygon is not simple and counter-clockwise")
    tris.append((idx[0], idx[1], idx[2]))
    return np.array(tris)


def _extruded(profile_mm: list[tuple[float, float]], height_mm: float) -> trimesh.Trimesh:
    import trimesh

    poly = np.asarray(profile_mm, dtype=np.float64) * MM
    mesh = trimesh.creation.extrude_triangulation(poly, _ear_clip(poly), height_mm * MM)
    return _centred(mesh)


def _revolved(profile_mm: list[tuple[float, float]], sections: int = 64) -> trimesh.Trimesh:
    import trimesh

    return _centred(trimesh.creation.revolve(np.asarray(profile_mm) * MM, sections=sections))


def _centred(mesh: trimesh.Trimesh) -> trimesh.Trimesh:
    mesh.apply_translation(-surface_moments(mesh.vertices, mesh.faces).centroid)
    mesh.fix_normals()
    return mesh


def bracket_mesh() -> trimesh.Trimesh:
    """L-shaped angle bracket, legs 60 mm and 40 mm, 20 mm wide: no proper symmetry."""
    return _extruded([(0, 0), (60, 0), (60, 12), (15, 12), (15, 40), (0, 40)], 20)


def zbracket_mesh() -> trimesh.Trimesh:
    """Z-profile bracket 50 x 50 x 20 mm: a half-turn about z maps it onto itself, nothing else."""
    profile = [(-25, -25), (5, -25), (5, 15), (25, 15), (25, 25), (-5, 25), (-5, -15), (-25, -15)]
    return _extruded(profile, 20)


def shaft_mesh() -> trimesh.Trimesh:
    """Stepped shaft, 85 mm long, diameters 20 / 32 / 16 mm: revolution about z, no flip."""
    return _revolved([(0, -40), (10, -40), (10, 10), (16, 10), (16, 25), (8, 25), (8, 45), (0, 45)])


def pin_mesh() -> trimesh.Trimesh:
    """Plain cylinder, 12 mm diameter, 50 mm long: revolution about z plus the end-over-end flip."""
    return _revolved([(0, -25), (6, -25), (6, 25), (0, 25)])


BUILTINS: dict[str, tuple[Callable[[], trimesh.Trimesh], Symmetry]] = {
    "bracket": (bracket_mesh, Symmetry("none")),
    "zbracket": (zbracket_mesh, Symmetry("cyclic", order=2)),
    "shaft": (shaft_mesh, Symmetry("revolution")),
    "pin": (pin_mesh, Symmetry("revolution", rotoreflection=True)),
}


def builtin_names() -> list[str]:
    return sorted(BUILTINS)


def builtin_object(name: str) -> ObjectModel:
    """One of :data:`BUILTINS` as an object model."""
    if name not in BUILTINS:
        raise ValueError(f"unknown built-in object {name!r}; available: {', '.join(builtin_names())}")
    make_mesh, symmetry = BUILTINS[name]
    return ObjectModel.from_mesh(name, make_mesh(), symmetry, source=f"built-in object {name!r}")
