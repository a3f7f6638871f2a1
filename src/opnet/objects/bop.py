"""BOP object models (Hodaň et al., bop.felk.cvut.cz): ``models_info.json`` entries and meshes to
opnet's object models, and opnet's symmetries back to BOP entries.

::

    <dataset>/models/models_info.json     per obj_id: diameter (mm), symmetries_discrete (4x4, mm),
                                          symmetries_continuous ({axis, offset (mm)})
    <dataset>/models/obj_XXXXXX.ply       the meshes, mm

The object side of the BOP format: :mod:`opnet.datasets.bop` (scenes, writer, results) builds on
it, never the other way round. Every error names the file and key.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from opnet._repr import short_repr
from opnet.fileio.files import read_json
from opnet.geometry.symmetry import MAX_GROUP_SIZE, Symmetry
from opnet.objects.io import load_mesh
from opnet.objects.model import ObjectModel

MODELS_INFO = "models_info.json"
#: a symmetry whose axis or translation misses the model origin by more than this share of the
#: diameter cannot be expressed as a rotation about the origin (opnet's symmetry groups)
ORIGIN_TOL = 0.01
#: BOP ids name files of 6 digits (``obj_000001.ply``); 0 is no object
MAX_BOP_ID = 999_999

# ------------------------------------------------------------------------------------------ files


def bop_numbers(value: Any, n: int, key: str, where: str) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        a = np.zeros(0)
    if a.size != n or not np.isfinite(a).all() or _has_bool(value):
        what = "a finite number" if n == 1 else f"{n} finite numbers"
        raise ValueError(f"{where}: '{key}' must be {what}, got {short_repr(value)}")
    return a


def _has_bool(value: Any) -> bool:
    return isinstance(value, bool) or (isinstance(value, list) and any(_has_bool(v) for v in value))


def bop_id(value: Any, key: str, where: str) -> int:
    """A BOP object id (``obj_id``, ``--obj-id``, ``data.object_id``) as an int in 1..999999: a
    whole number, not a boolean or a fraction (``1.9`` is no id, not object 1).

    Raises:
        ValueError: naming ``where`` and ``key``.
    """
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_BOP_ID:
        raise ValueError(f"{where}: {key}={short_repr(value)} is not a BOP object id (a whole number in "
                         f"1..{MAX_BOP_ID})")
    return value


def bop_list(value: Any, key: str, where: str) -> list[Any]:
    if not isinstance(value, list):
        raise ValueError(f"{where}: '{key}' must be a list, got {short_repr(value)}")
    return value


def bop_key(entry: Any, key: str, where: str) -> Any:
    if not isinstance(entry, dict) or key not in entry:
        raise ValueError(f"{where}: missing key '{key}'")
    return entry[key]


# ------------------------------------------------------------------------------------- symmetries


def _rotation_to_z(axis: np.ndarray) -> np.ndarray:
    """A rotation A with A @ axis = z (the identity when the axis already is +z)."""
    a = axis / np.linalg.norm(axis)
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(a, z), float(a @ z)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx * (1 / (1 + c))


def _axis_angle(R: np.ndarray) -> tuple[np.ndarray, float]:
    angle = math.acos(max(-1.0, min(1.0, (np.trace(R) - 1) / 2)))
    if angle > math.pi - 1e-6:  # 180 degrees: the axis from R + I
        M = R + np.eye(3)
        axis = M[:, int(np.argmax(np.linalg.norm(M, axis=0)))]
    else:
        axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return axis / max(np.linalg.norm(axis), 1e-12), angle


def symmetry_from_bop(info: dict[str, Any], where: str) -> tuple[Symmetry, np.ndarray]:
    """opnet's symmetry of a BOP ``models_info`` entry, and the alignment ``R_align`` of the model
    frame (``x_opnet = R_align x_bop``) that puts the symmetry axis on z.

    - no symmetries: none;
    - ``symmetries_continuous`` with one axis: revolution about it; a discrete symmetry that turns
      the axis over (e.g. 180 degrees about x for an axis z) adds the end-over-end flip;
    - ``symmetries_discrete`` whose non-identity rotations share one axis and form C_k: cyclic k;
    - other discrete sets: the finite group they form with the identity (closure checked).

    Raises:
        ValueError: naming ``where``: several continuous axes (a sphere), a symmetry that does not
            pass through the model origin (translation or offset > 1 % of the diameter), a
            discrete matrix that is not a rotation, or a set that is not a group.
    """
    if not isinstance(info, dict):
        raise ValueError(f"{where}: expected an object of model info (diameter, symmetries), got a "
                         f"{type(info).__name__}")
    diameter = float(bop_numbers(info.get("diameter", 0.0) or 0.0, 1, "diameter", where)[0])
    tol = ORIGIN_TOL * diameter if diameter > 0 else 1.0  # mm
    discrete = []
    for i, m in enumerate(bop_list(info.get("symmetries_discrete") or [], "symmetries_discrete", where)):
        T = bop_numbers(m, 16, f"symmetries_discrete[{i}]", where).reshape(4, 4)
        R, t = T[:3, :3], T[:3, 3]
        if np.abs(R.T @ R - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0:
            raise ValueError(f"{where}: symmetries_discrete[{i}] is not a rotation (a reflection or scaled matrix)")
        if np.linalg.norm(t) > tol:
            raise ValueError(f"{where}: symmetries_discrete[{i}] moves the origin by {np.linalg.norm(t):.3g} mm: opnet's "
                             "symmetries are rotations about the model origin; centre the model on the symmetry axis")
        if np.abs(R - np.eye(3)).max() > 1e-6 and all(np.abs(R - D).max() > 1e-6 for D in discrete):
            discrete.append(R)  # a repeated element is one element of the group
        if len(discrete) > MAX_GROUP_SIZE:
            raise ValueError(f"{where}: symmetries_discrete holds more than {MAX_GROUP_SIZE} distinct rotations: "
                             "not a part's symmetry group")
    continuous = bop_list(info.get("symmetries_continuous") or [], "symmetries_continuous", where)
    if len(continuous) > 1:
        raise ValueError(f"{where}: {len(continuous)} continuous symmetry axes (a sphere?) cannot be mapped; "
                         "opnet supports one axis of revolution")
    if continuous:
        axis = bop_numbers(bop_key(continuous[0], "axis", f"{where}: symmetries_continuous[0]"), 3, "axis", where)
        offset = bop_numbers(continuous[0].get("offset", [0, 0, 0]), 3, "offset", where)
        if np.linalg.norm(axis) < 1e-9:
            raise ValueError(f"{where}: symmetries_continuous axis is zero")
        # the offset is a point on the axis: only its distance to the axis line matters
        a = axis / np.linalg.norm(axis)
        miss = np.linalg.norm(offset - (offset @ a) * a)
        if miss > tol:
            raise ValueError(f"{where}: the continuous symmetry axis misses the model origin by {miss:.3g} mm; "
                             "centre the model on the axis")
        A = _rotation_to_z(a)
        flip = False
        for R in discrete:
            Rz = A @ R @ A.T
            if Rz[2, 2] < -1 + 1e-6:
                flip = True
            elif Rz[2, 2] < 1 - 1e-6:
                raise ValueError(f"{where}: a discrete symmetry tilts the axis of revolution (neither keeps nor "
                                 "turns it over): cannot be mapped")
        return Symmetry("revolution", rotoreflection=flip), A
    if not discrete:
        return Symmetry("none"), np.eye(3)
    axes_angles = [_axis_angle(R) for R in discrete]
    axis0 = axes_angles[0][0]
    k = len(discrete) + 1
    if all(abs(abs(ax @ axis0) - 1) < 1e-6 for ax, _ in axes_angles):
        steps = [ang / (2 * math.pi / k) for _, ang in axes_angles]
        if all(abs(s - round(s)) < 1e-4 for s in steps):
            return Symmetry("cyclic", order=k), _rotation_to_z(axis0)
    try:
        return Symmetry("finite", rotations=np.stack([np.eye(3), *discrete])), np.eye(3)
    except ValueError as e:
        raise ValueError(f"{where}: symmetries_discrete: {e}") from None


def bop_symmetry_entries(symmetry: Symmetry) -> dict[str, Any]:
    """``symmetries_discrete`` / ``symmetries_continuous`` of a models_info entry for ``symmetry``
    (opnet's model frame, symmetries about the origin)."""
    out: dict[str, Any] = {}
    if symmetry.is_revolution:
        out["symmetries_continuous"] = [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]
        if symmetry.rotoreflection:
            out["symmetries_discrete"] = [_matrix16(np.diag([1.0, -1.0, -1.0]))]
        return out
    group = symmetry.group()
    if len(group) > 1:
        out["symmetries_discrete"] = [_matrix16(R) for R in group[1:]]
    return out


def _matrix16(R: np.ndarray) -> list[float]:
    T = np.eye(4)
    T[:3, :3] = R
    return [float(v) for v in T.reshape(-1)]


# ------------------------------------------------------------------------------------------ models


def models_dir_of(root: Path) -> Path:
    """``<dataset>/models`` for a split folder ``<dataset>/<split>`` (or the dataset folder itself)."""
    for candidate in (root.parent / "models", root / "models"):
        if (candidate / MODELS_INFO).is_file():
            return candidate
    raise FileNotFoundError(f"{root.parent / 'models' / MODELS_INFO}: file not found (a BOP split folder "
                            "<dataset>/<split> needs <dataset>/models/models_info.json)")


def model_info(models_dir: Path, obj_id: int) -> dict[str, Any]:
    path = models_dir / MODELS_INFO
    obj_id = bop_id(obj_id, "obj_id", str(path))
    info = read_json(path)
    if not isinstance(info, dict):
        raise ValueError(f"{path}: expected an object of obj_id -> model info")
    entry = info.get(str(obj_id))
    if entry is None:
        ids = ", ".join(sorted(info, key=lambda s: int(s) if s.isdigit() else 0)[:20])
        raise ValueError(f"{path}: obj_id {obj_id} is not in this dataset's models (ids: {ids})")
    return entry


def bop_object(models_dir: str | Path, obj_id: int, name: str | None = None) -> ObjectModel:
    """The opnet object model of BOP object ``obj_id``: its mesh (mm -> m, aligned so the symmetry
    axis is z) and its symmetry from models_info.json."""
    models_dir = Path(models_dir)
    info = model_info(models_dir, obj_id)
    obj_id = bop_id(obj_id, "obj_id", str(models_dir / MODELS_INFO))
    symmetry, A = symmetry_from_bop(info, f"{models_dir / MODELS_INFO}: obj_id {obj_id}")
    mesh_path = models_dir / f"obj_{obj_id:06d}.ply"
    mesh = load_mesh(mesh_path, 0.001, A if np.abs(A - np.eye(3)).max() > 0 else None)
    return ObjectModel.from_mesh(name or f"obj_{obj_id:06d}", mesh, symmetry, source=str(mesh_path))
