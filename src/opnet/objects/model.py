"""Object models: a triangle mesh, its proper symmetry group, and what the metric derives from them.

Λ, the surface centroid and the threshold δ = 0.1·D with D = 2 × max ‖vertex − centroid‖ follow
docs/method.md#pose-distance. The symmetry axis is the model z-axis (docs/data.md#objects).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:  # the mesh library is imported where a mesh is made or read (it costs a second at start)
    import trimesh

from opnet.fileio.files import read_json
from opnet.geometry.distance import PoseSpace
from opnet.geometry.symmetry import Symmetry, symmetry_from_rotations
from opnet.objects.surface import SurfaceMoments, sqrtm_psd, surface_moments

# plausible diameters of a bin-picking part, metres; outside this the mesh is most likely in other units
MIN_DIAMETER_M = 0.002
MAX_DIAMETER_M = 5.0


@dataclass(frozen=True)
class ObjectModel:
    """A rigid part: mesh (metres, model frame) + proper symmetry + metric quantities.

    Attributes:
        name: identifier used in configs and file names.
        symmetry: proper symmetry group about the model z-axis.
        centroid: (3,) metres, surface centroid in the model frame.
        covariance: (3, 3) m^2, surface covariance M about the centroid, model frame.
        diameter: metres, D = 2 × max distance from the centroid to a vertex.
        mesh: the triangle mesh in metres (None for objects known only from a poseutils.json).
        Lambda_override: (3, 3) metres; when given (from a poseutils.json), the Λ the distance uses.
    """

    name: str
    symmetry: Symmetry
    centroid: np.ndarray = field(compare=False)
    covariance: np.ndarray = field(compare=False)
    diameter: float
    # a trimesh.Trimesh or None, annotated Any: the mesh library is imported where a mesh is made or read, and
    # OmegaConf resolves a dataclass's field types when an object model goes into a config
    mesh: Any = field(default=None, compare=False, repr=False)
    Lambda_override: np.ndarray | None = field(default=None, compare=False, repr=False)

    # ---- construction ------------------------------------------------------------------------
    @classmethod
    def from_mesh(
        cls, name: str, mesh: trimesh.Trimesh, symmetry: Symmetry | str | dict | None = None, source: str = "<mesh>"
    ) -> ObjectModel:
        """Build from a mesh already in metres; validates it (see :func:`validate_mesh`)."""
        validate_mesh(mesh, source)
        mom = surface_moments(mesh.vertices, mesh.faces)
        _check_units(2 * mom.radius, source)
        return cls(name, Symmetry.from_spec(symmetry), mom.centroid, mom.covariance, 2 * mom.radius, mesh)

    @classmethod
    def from_poseutils(cls, path: str | Path, name: str | None = None, mesh: trimesh.Trimesh | None = None) -> ObjectModel:
        """Build the metric side of an object from an official Siléane ``poseutils.json``."""
        path = Path(path)
        data = _read_json(path)
        kind = _require(data, "type", path)
        threshold = _require(data, "distance_threshold", path)
        if isinstance(threshold, bool) or not isinstance(threshold, int | float) or not math.isfinite(threshold) or threshold <= 0:
            raise ValueError(f"{path}: 'distance_threshold' = {threshold!r}, expected a positive distance in metres")
        threshold = float(threshold)
        name = name or path.parent.name
        try:
            return cls._from_poseutils_data(data, kind, threshold, name, mesh, path)
        except (ValueError, TypeError) as e:  # ill-typed or ragged arrays, an invalid group
            raise ValueError(str(e) if str(e).startswith(str(path)) else f"{path}: {e}") from None

    @classmethod
    def _from_poseutils_data(cls, data: dict[str, Any], kind: Any, threshold: float, name: str,
                             mesh: trimesh.Trimesh | None, path: Path) -> ObjectModel:
        if kind == "AffinePoseUtils":
            Lambda = np.asarray(_require(data, "Lambda", path), float)
            G = np.asarray(_require(data, "G", path), float)
            if Lambda.shape != (3, 3) or G.ndim != 3 or G.shape[1:] != (3, 3):
                raise ValueError(f"{path}: 'Lambda' must be 3x3 and 'G' a list of 3x3 matrices")
            sym = symmetry_from_rotations(G)
            cov = Lambda @ Lambda.T
            return cls(name, sym, np.zeros(3), cov, threshold / 0.1, mesh, Lambda)
        if kind == "RevolutionPoseUtils":
            lam = float(_require(data, "lambda", path))
            flip = data.get("rotoreflection_symmetry", False)
            if not isinstance(flip, bool):
                raise ValueError(f"{path}: 'rotoreflection_symmetry' must be true or false, got a {type(flip).__name__}")
            # only lam matters for the revolution distance; spread it as lam_r = 0, lam_z = lam
            cov = np.diag([0.0, 0.0, lam**2])
            return cls(name, Symmetry("revolution", rotoreflection=flip), np.zeros(3), cov, threshold / 0.1, mesh)
        raise ValueError(f"{path}: unknown poseutils 'type' {kind!r}; expected AffinePoseUtils or RevolutionPoseUtils")

    # ---- derived quantities ------------------------------------------------------------------
    @property
    def delta(self) -> float:
        """Distance threshold of a correct pose, metres: 0.1 × D."""
        return 0.1 * self.diameter

    @property
    def Lambda(self) -> np.ndarray:
        """(3, 3) metres: M^(1/2) in the model frame (what the mesh-frame pose distance uses)."""
        if self.Lambda_override is not None:
            return self.Lambda_override
        return sqrtm_psd(self.covariance)[0]

    @property
    def Lambda_principal(self) -> np.ndarray:
        """(3,) metres, square roots of the eigenvalues of M, ascending (the official diagonal Λ)."""
        return np.sqrt(np.clip(np.linalg.eigvalsh(self.covariance), 0, None))

    @property
    def lam_revolution(self) -> tuple[float, float, float]:
        """(lam_r, lam_z, lam) metres for the revolution distance: lam_r^2 = (M_xx + M_yy) / 2."""
        lam_r = float(np.sqrt(max(0.5 * (self.covariance[0, 0] + self.covariance[1, 1]), 0.0)))
        lam_z = float(np.sqrt(max(self.covariance[2, 2], 0.0)))
        return lam_r, lam_z, float(np.hypot(lam_r, lam_z))

    @property
    def pose_space(self) -> PoseSpace:
        """The Brégier pose space of this object (distance, representatives, threshold)."""
        lam = self.lam_revolution[2] if self.symmetry.is_revolution else 0.0
        return PoseSpace(self.Lambda, self.symmetry.group(), self.delta, self.symmetry.is_revolution, lam)

    @property
    def extent(self) -> np.ndarray:
        """(3,) metres, axis-aligned bounding-box size of the mesh in the model frame."""
        if self.mesh is None:
            raise ValueError(f"object {self.name!r} has no mesh")
        return np.asarray(self.mesh.extents, dtype=np.float64)

    def moments(self) -> SurfaceMoments:
        if self.mesh is None:
            raise ValueError(f"object {self.name!r} has no mesh")
        return surface_moments(self.mesh.vertices, self.mesh.faces)

    def to_poseutils(self) -> dict[str, Any]:
        """The official ``poseutils.json`` content for this object (principal frame, mesh-origin quirk)."""
        _, sqrt_w, U = sqrtm_psd(self.covariance)
        R_ref2i = U.T
        t_ref2i = (-U.T @ self.centroid).reshape(3, 1)
        common = {"Rref2i": R_ref2i.tolist(), "tref2i": t_ref2i.tolist(), "distance_threshold": self.delta}
        if self.symmetry.is_revolution:
            return {"type": "RevolutionPoseUtils", "lambda": self.lam_revolution[2],
                    "rotoreflection_symmetry": self.symmetry.rotoreflection, **common}
        return {"type": "AffinePoseUtils", "Lambda": self.Lambda.tolist(),
                "G": self.symmetry.group().tolist(), **common}


def validate_mesh(mesh: trimesh.Trimesh, source: str) -> None:
    """Refuse meshes that cannot describe a part: no faces, NaN vertices, zero area."""
    import trimesh

    if not isinstance(mesh, trimesh.Trimesh):
        raise ValueError(f"{source}: expected a triangle mesh, got {type(mesh).__name__}")
    if len(mesh.faces) == 0 or len(mesh.vertices) < 3:
        raise ValueError(f"{source}: mesh has no faces ({len(mesh.vertices)} vertices, {len(mesh.faces)} faces)")
    if not np.isfinite(mesh.vertices).all():
        raise ValueError(f"{source}: mesh has non-finite (NaN or inf) vertex coordinates")
    areas = mesh.area_faces
    if not areas.sum() > 0:
        raise ValueError(f"{source}: mesh is degenerate (all {len(areas)} faces have zero area)")


def _check_units(diameter: float, source: str) -> None:
    if not MIN_DIAMETER_M <= diameter <= MAX_DIAMETER_M:
        hint = "millimetres: set mesh_scale: 0.001" if diameter > MAX_DIAMETER_M else "too small: check mesh_scale"
        raise ValueError(
            f"{source}: implausible units, the part is {diameter:.6g} m across "
            f"(expected {MIN_DIAMETER_M}..{MAX_DIAMETER_M} m); the mesh is probably in {hint}"
        )


def _read_json(path: Path) -> dict[str, Any]:
    data = read_json(path)  # regular files only (/dev/zero or a FIFO would never end), errors naming it
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object, got {type(data).__name__}")
    return data


def _require(data: dict[str, Any], key: str, path: Path) -> Any:
    if key not in data:
        raise ValueError(f"{path}: missing key {key!r}")
    return data[key]
