"""Loading object models from mesh files, configs, and Siléane poseutils.json files."""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # the mesh library is imported where a mesh is made or read (it costs a second at start)
    import trimesh

from opnet._repr import short_repr
from opnet.fileio.files import require_regular_file
from opnet.geometry.rotations import euler_to_matrix
from opnet.geometry.symmetry import Symmetry
from opnet.objects.library import BUILTINS, builtin_names, builtin_object
from opnet.objects.model import ObjectModel

log = logging.getLogger(__name__)

MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf")


def load_mesh(path: str | Path, scale: float = 1.0, model_rotation: Any = None,
              model_origin: Any = None) -> trimesh.Trimesh:  # fmt: skip
    """Read a triangle mesh file and bring it to metres in the model frame.

    Args:
        path: .obj, .stl, .ply, ... (anything trimesh reads as one mesh; scenes are merged).
        scale: multiply coordinates by this (0.001 for a mesh in millimetres).
        model_rotation: optional fixed correction so that the symmetry axis becomes z: a 3x3
            matrix, or three Z-Y-Z Euler angles in degrees, applied as ``x_model = R (x_file - origin)``.
        model_origin: optional point of the scaled file frame (metres) that becomes the model origin
            (the symmetry centre, which every symmetry axis must pass through: ``opnet-object`` writes it).
    """
    path = require_regular_file(path)  # a FIFO or a device is named as such, not "not found"
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise ValueError(f"{path}: unsupported mesh format {path.suffix!r}; expected one of {MESH_SUFFIXES}")
    if isinstance(scale, bool) or not isinstance(scale, int | float) or not np.isfinite(scale) or scale <= 0:
        raise ValueError(f"{path}: mesh_scale must be a positive number, got {short_repr(scale)}")
    declared = declared_faces(path)
    if declared is not None:
        _check_face_count(declared, path)  # from the header: before minutes of loading
    import trimesh

    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types on corrupt files
        raise ValueError(f"{path}: cannot read mesh ({type(e).__name__}: {str(e)[:200]})") from e
    if not isinstance(loaded, trimesh.Trimesh):
        raise ValueError(f"{path}: file holds no triangle mesh")
    _check_face_count(len(loaded.faces), path)
    if not np.isfinite(loaded.vertices).all():  # processing would drop them, and their faces, silently
        raise ValueError(f"{path}: mesh has non-finite (NaN or inf) vertex coordinates")
    loaded.process()  # merge duplicate vertices, drop degenerate faces (what process=True would do)
    mesh = outward_faces(loaded.copy(), path)
    if scale != 1.0:
        mesh.apply_scale(scale)
    if model_origin is not None:
        origin = np.asarray(model_origin, dtype=np.float64) if not isinstance(model_origin, str) else np.full(1, np.nan)
        if origin.shape != (3,) or not np.isfinite(origin).all():
            raise ValueError(f"{path}: model_origin must be three numbers (metres), got {short_repr(model_origin)}")
        mesh.apply_translation(-origin)
    if model_rotation is not None:
        R = np.asarray(model_rotation, dtype=np.float64)
        if R.shape == (3,):
            R = euler_to_matrix(np.radians(R))
        if R.shape != (3, 3) or not np.isfinite(R).all() or np.abs(R.T @ R - np.eye(3)).max() > 1e-6:
            raise ValueError(f"{path}: model_rotation must be a rotation matrix or 3 Z-Y-Z angles in degrees")
        if np.linalg.det(R) < 0:
            raise ValueError(f"{path}: model_rotation has det -1, a reflection: it would mirror the part; "
                             "give a proper rotation (det +1)")
        T = np.eye(4)
        T[:3, :3] = R
        mesh.apply_transform(T)
    return mesh


#: more triangles than a part's model needs: physics and rendering would take minutes and gigabytes
#: (a 5-million-face scan took 93 s and 6 GB before failing); simplify such a mesh first
MAX_MESH_FACES = 1_000_000


def _check_face_count(faces: int, path: Path) -> None:
    if faces > MAX_MESH_FACES:
        raise ValueError(f"{path}: the mesh has {faces:,} faces, more than {MAX_MESH_FACES:,}; simplify it "
                         "(e.g. quadric decimation in MeshLab or Blender) to a part model of fewer faces")


def declared_faces(path: Path) -> int | None:
    """The face count a binary STL or a PLY header declares (None for other formats or an
    unreadable header; the loader then judges the file)."""
    try:
        with path.open("rb") as fh:
            head = fh.read(4096)
    except OSError:
        return None
    suffix = path.suffix.lower()
    if suffix == ".stl" and not head[:5].lower() == b"solid" and len(head) >= 84:
        return int.from_bytes(head[80:84], "little")
    if suffix == ".ply" and head.startswith(b"ply"):
        m = re.search(rb"\nelement face (\d{1,12})\s", head)
        return int(m.group(1)) if m else None
    return None


def outward_faces(mesh: trimesh.Trimesh, path: Path) -> trimesh.Trimesh:
    """``mesh`` with its faces wound consistently and its normals pointing outwards (a closed mesh
    of negative volume is inside out: physics would give it a negative mass), repaired in place
    with a warning.

    Raises:
        ValueError: naming ``path``: a closed mesh still inside out after the repair.
    """
    if len(mesh.faces) == 0 or (mesh.is_winding_consistent and not (mesh.is_watertight and mesh.volume < 0)):
        return mesh
    import trimesh

    trimesh.repair.fix_normals(mesh)
    if mesh.is_watertight and mesh.volume < 0:
        raise ValueError(f"{path}: the mesh is inside out (its normals point inwards) and could not be repaired; "
                         "flip its normals in a mesh editor")
    log.warning("%s: faces were wound inconsistently or inside out (normals pointing inwards); repaired", path)
    return mesh


def load_object(
    name: str,
    *,
    mesh: str | Path | None = None,
    symmetry: Symmetry | str | dict | None = None,
    mesh_scale: float = 1.0,
    model_rotation: Any = None,
    builtin: str | None = None,
    poseutils: str | Path | None = None,
    model_origin: Any = None,
) -> ObjectModel:
    """Build an object model from whichever source is given.

    Exactly one of ``builtin``, ``mesh`` or ``poseutils`` is needed; with no source, ``name`` is
    looked up among the built-in objects. ``poseutils`` together with ``mesh`` takes Λ, the group and
    δ from the official file and keeps the mesh for rendering.
    """
    if builtin is None and mesh is None and poseutils is None:
        if name not in BUILTINS:
            raise ValueError(
                f"unknown object {name!r}: not a built-in ({', '.join(builtin_names())}) and no mesh or poseutils given"
            )
        builtin = name
    if builtin is not None:
        if mesh is not None or poseutils is not None:
            raise ValueError(f"object {name!r}: give either builtin or mesh/poseutils, not both")
        obj = builtin_object(builtin)
        return obj if obj.name == name else ObjectModel.from_mesh(name, obj.mesh, obj.symmetry, f"built-in {builtin!r}")
    mesh_obj = None if mesh is None else load_mesh(mesh, mesh_scale, model_rotation, model_origin)
    if poseutils is not None:
        return ObjectModel.from_poseutils(poseutils, name, mesh_obj)
    assert mesh_obj is not None
    return ObjectModel.from_mesh(name, mesh_obj, Symmetry.from_spec(symmetry), source=str(mesh))
