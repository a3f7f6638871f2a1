"""Surface moments of triangle meshes (docs/method.md#pose-distance)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SurfaceMoments:
    """Area-weighted moments of a mesh surface, in the mesh frame.

    Attributes:
        area: m^2.
        centroid: (3,) metres, the surface centroid c0.
        covariance: (3, 3) m^2, ``M = (1/S) ∫ (x - c0)(x - c0)^T dS``.
        radius: metres, max distance from c0 to a vertex (the diameter D is twice this).
    """

    area: float
    centroid: np.ndarray
    covariance: np.ndarray
    radius: float


def surface_moments(vertices: np.ndarray, faces: np.ndarray) -> SurfaceMoments:
    """Exact area-weighted centroid and second moment of a triangle mesh.

    Args:
        vertices: (V, 3) float, metres. faces: (F, 3) int vertex indices.
    """
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[np.asarray(faces, dtype=np.int64)]  # (F, 3 corners, 3)
    areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    S = float(areas.sum())
    if not S > 0:
        raise ValueError("mesh has zero surface area")
    c0 = (areas[:, None] * tri.mean(axis=1)).sum(0) / S
    rel = tri - c0
    m = rel.mean(axis=1)  # (F, 3)
    # exact second moment of a triangle: A/12 (9 m m^T + a a^T + b b^T + c c^T)
    corners = np.einsum("fki,fkj->fij", rel, rel)
    M = (areas[:, None, None] / 12.0 * (9.0 * np.einsum("fi,fj->fij", m, m) + corners)).sum(0) / S
    radius = float(np.linalg.norm(v[np.unique(faces)] - c0, axis=1).max())
    return SurfaceMoments(S, c0, 0.5 * (M + M.T), radius)


def sqrtm_psd(M: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Symmetric square root of a PSD 3x3 matrix.

    Returns:
        (Lambda_mesh (3, 3) = U diag(sqrt w) U^T, sqrt_w (3,) ascending, U (3, 3) eigenvectors as columns).
    """
    w, U = np.linalg.eigh(M)
    sqrt_w = np.sqrt(np.clip(w, 0.0, None))
    return (U * sqrt_w) @ U.T, sqrt_w, U
