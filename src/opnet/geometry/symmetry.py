"""Proper symmetry groups of rigid objects (docs/data.md#objects, docs/method.md#pose-distance).

The symmetry axis of an object is its model z-axis. Classes:
- ``none``: no proper symmetry (C1).
- ``cyclic``: order ``k`` about z (Ck), group ``{Rz(2 pi m / k)}``.
- ``revolution``: any turn about z (C-infinity); ``rotoreflection`` adds the half-turn about an
  axis perpendicular to z (D-infinity, e.g. a plain cylinder).
- ``finite``: an explicit finite group of rotations (dihedral, platonic, ...).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from opnet._repr import short_repr

SymmetryKind = Literal["none", "cyclic", "revolution", "finite"]
_KINDS = ("none", "cyclic", "revolution", "finite")


#: beyond this a cyclic part is, for any depth camera, a solid of revolution (and the group gets huge)
MAX_CYCLIC_ORDER = 360
#: the largest finite group accepted: the dihedral group of the largest cyclic order
MAX_GROUP_SIZE = 2 * MAX_CYCLIC_ORDER
#: matrices read before deduplication (repeats are dropped; more than this is not a group spec)
MAX_GROUP_INPUT = 8 * MAX_GROUP_SIZE

@dataclass(frozen=True)
class Symmetry:
    """A proper symmetry group, in the model frame.

    Attributes:
        kind: one of "none", "cyclic", "revolution", "finite".
        order: k for "cyclic" (>= 2); 1 otherwise.
        rotoreflection: for "revolution": also symmetric under a half-turn about an axis ⟂ z.
        rotations: (K, 3, 3) float64 for "finite": the group elements (identity included).
    """

    kind: SymmetryKind = "none"
    order: int = 1
    rotoreflection: bool = False
    rotations: np.ndarray | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        if self.kind not in _KINDS:
            raise ValueError(f"symmetry kind must be one of {_KINDS}, got {short_repr(self.kind)}")
        if self.kind == "cyclic" and (int(self.order) != self.order or not 2 <= self.order <= MAX_CYCLIC_ORDER):
            raise ValueError(f"cyclic symmetry needs an integer order in 2..{MAX_CYCLIC_ORDER}, got {short_repr(self.order)} "
                             "(a part with finer symmetry is a solid of revolution: kind: revolution)")
        if self.kind != "cyclic" and self.order != 1:
            raise ValueError(f"'order' only applies to cyclic symmetry (kind={short_repr(self.kind)})")
        if self.rotoreflection and self.kind != "revolution":
            raise ValueError("'rotoreflection' only applies to revolution symmetry")
        if self.kind == "finite":
            if self.rotations is None:
                raise ValueError("finite symmetry needs 'rotations', a list of 3x3 matrices")
            object.__setattr__(self, "rotations", _validated_group(np.asarray(self.rotations, float)))

    @property
    def is_revolution(self) -> bool:
        return self.kind == "revolution"

    def group(self) -> np.ndarray:
        """(K, 3, 3) float64 finite group elements, identity first.

        For revolution symmetry this is the finite part that the continuous spin about z does not
        cover: ``{I}``, or ``{I, Rx(pi)}`` with rotoreflection.
        """
        if self.kind == "cyclic":
            from opnet.geometry.rotations import axis_angle_rotation  # torch-free callers never get here

            angles = 2 * math.pi * np.arange(self.order) / self.order
            return axis_angle_rotation("Z", angles)
        if self.kind == "finite":
            assert self.rotations is not None
            return self.rotations.copy()
        if self.kind == "revolution" and self.rotoreflection:
            return np.stack((np.eye(3), np.diag([1.0, -1.0, -1.0])))
        return np.eye(3)[None]

    @property
    def euler3_period(self) -> float | None:
        """Period of the third Z-Y-Z Euler angle: 2 pi / k (cyclic), 2 pi (none), None (revolution: dropped).

        For an explicit finite group the cyclic subgroup about z is used.
        """
        if self.kind == "revolution":
            return None
        if self.kind == "cyclic":
            return 2 * math.pi / self.order
        if self.kind == "finite":
            return 2 * math.pi / _z_cyclic_order(self.group())
        return 2 * math.pi

    @classmethod
    def from_spec(cls, spec: str | Mapping[str, Any] | Symmetry | None) -> Symmetry:
        """Build from a config value: "none" | "revolution" | "cyclic2" | {"kind": ..., ...}."""
        if isinstance(spec, Symmetry):
            return spec
        if spec is None:
            return cls()
        if isinstance(spec, str):
            s = spec.strip().lower()
            if s.startswith("cyclic") and s[6:].isdigit():
                return cls("cyclic", order=int(s[6:]))
            return cls(s)  # type: ignore[arg-type]
        unknown = set(spec) - {"kind", "order", "rotoreflection", "rotations"}
        if unknown:
            raise ValueError(f"unknown symmetry keys {sorted(unknown)}; expected kind, order, rotoreflection, rotations")
        order = spec.get("order", 1)
        if isinstance(order, bool) or not isinstance(order, int | float) or not float(order).is_integer():
            raise ValueError(f"symmetry order must be a whole number, got {short_repr(order)}")
        return cls(
            kind=spec.get("kind", "none"),
            order=int(order),
            rotoreflection=_flag(spec.get("rotoreflection", False), "symmetry.rotoreflection"),
            rotations=None if spec.get("rotations") is None else np.asarray(spec["rotations"], float),
        )

    def to_spec(self) -> dict[str, Any]:
        """Plain-data form accepted by :meth:`from_spec`."""
        out: dict[str, Any] = {"kind": self.kind}
        if self.kind == "cyclic":
            out["order"] = self.order
        if self.kind == "revolution":
            out["rotoreflection"] = self.rotoreflection
        if self.kind == "finite":
            out["rotations"] = self.group().tolist()
        return out


def _validated_group(G: np.ndarray, tol: float = 1e-5) -> np.ndarray:
    """The distinct elements of ``G`` (repeats within ``tol`` dropped), identity first, after
    checking that they are proper rotations forming a group of at most :data:`MAX_GROUP_SIZE`.

    Repeats and closure are found with a k-d tree over the flattened matrices: O(K^2 log K) for K
    elements (the K^2 products are the check itself), not the O(K^3) of comparing every product with
    every element.
    """
    from scipy.spatial import cKDTree

    if G.ndim != 3 or G.shape[1:] != (3, 3) or len(G) == 0:
        raise ValueError(f"symmetry rotations must have shape (K, 3, 3), got {G.shape}")
    if len(G) > MAX_GROUP_INPUT:
        raise ValueError(f"symmetry rotations: {len(G)} matrices given, more than {MAX_GROUP_INPUT}: not a part's "
                         f"symmetry group (at most {MAX_GROUP_SIZE} elements)")
    if not np.isfinite(G).all():
        raise ValueError("symmetry rotations must be finite numbers")
    eye = np.eye(3)
    if np.abs(G.transpose(0, 2, 1) @ G - eye).max() > tol or np.abs(np.linalg.det(G) - 1).max() > tol:
        raise ValueError("symmetry rotations must be proper rotation matrices (orthonormal, det +1; "
                         "a reflection is not a rigid motion)")
    # repeats: exact-ish ones collapse on a coarse grid first (cheap for many copies), then an element is
    # dropped when an earlier survivor lies within tol (the grid may split a pair across a cell border)
    _, first = np.unique(np.round(G.reshape(len(G), 9) * 1e3), axis=0, return_index=True)
    G = G[np.sort(first)]
    flat = G.reshape(len(G), 9)
    nearest = np.array([min(near) for near in cKDTree(flat).query_ball_point(flat, tol, p=np.inf)])
    G = G[nearest == np.arange(len(G))]
    if len(G) > MAX_GROUP_SIZE:
        raise ValueError(f"symmetry rotations: {len(G)} distinct elements, more than {MAX_GROUP_SIZE} (a cyclic "
                         f"order beyond {MAX_CYCLIC_ORDER} is a solid of revolution: kind: revolution)")
    flat = G.reshape(len(G), 9)
    tree = cKDTree(flat)
    dist, idx = tree.query(eye.reshape(1, 9), p=np.inf)
    if dist[0] > tol:
        raise ValueError("symmetry rotations must contain the identity")
    products = np.einsum("aij,bjk->abik", G, G).reshape(-1, 9)
    dist, _ = tree.query(products, p=np.inf, distance_upper_bound=tol * 10)
    if not (dist <= tol * 10).all():
        raise ValueError("symmetry rotations are not closed under composition: not a group")
    identity = int(idx[0])
    order = [identity, *(i for i in range(len(G)) if i != identity)]
    return G[order]


def _flag(value: Any, key: str) -> bool:
    """A true/false config value; strings and numbers are refused (``'false'`` would read as true)."""
    if isinstance(value, bool | np.bool_):
        return bool(value)
    raise ValueError(f"{key} must be true or false, got a {type(value).__name__}")


def _z_cyclic_order(G: np.ndarray, tol: float = 1e-6) -> int:
    """Number of group elements that are turns about z."""
    return int(sum(abs(g[2, 2] - 1) < tol for g in G))


def cyclic_group(order: int) -> np.ndarray:
    """(order, 3, 3) turns about z by 2 pi m / order."""
    return Symmetry("cyclic", order=order).group()


def as_symmetry(spec: str | Mapping[str, Any] | Symmetry | None) -> Symmetry:
    """Alias of :meth:`Symmetry.from_spec` for call sites that read better as a function."""
    return Symmetry.from_spec(spec)


def dihedral_group(order: int) -> np.ndarray:
    """(2 * order, 3, 3): turns about z by 2 pi m / order and half-turns about axes in the xy plane."""
    turns = cyclic_group(order)
    flips = turns @ np.diag([1.0, -1.0, -1.0])
    return np.concatenate((turns, flips))


def symmetry_from_rotations(rotations: Sequence[Sequence[Sequence[float]]]) -> Symmetry:
    """Explicit finite group; collapses to "none" or "cyclic" when that is what it is."""
    G = _validated_group(np.asarray(rotations, float))
    if len(G) == 1:
        return Symmetry("none")
    if _z_cyclic_order(G) == len(G):
        return Symmetry("cyclic", order=len(G))
    return Symmetry("finite", rotations=G)
