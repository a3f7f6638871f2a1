"""Planes in a depth frame: back-projection, RANSAC with a least-squares refit, heights over a plane.

A :class:`Plane` is held in the camera frame (OpenCV: x right, y down, z forward, metres) as a unit normal
``n`` pointing from the plane towards the camera and the camera's distance ``offset`` to it: a point ``p``
lies on it where ``n . p = -offset``, and ``n . p + offset`` is its height over the plane (positive on the
camera's side). NumPy only; deterministic for a given random generator.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from opnet.geometry.camera import Camera

#: the longer side of the subsampled image the points come from, pixels
SAMPLE_PIXELS = 480
#: the points a RANSAC hypothesis is scored on (a random subsample of the frame's)
SCORE_POINTS = 6000


@dataclass(frozen=True)
class Plane:
    """A plane in the camera frame: unit normal towards the camera, the camera's distance to it (metres)."""

    normal: np.ndarray
    offset: float

    def height(self, points: np.ndarray) -> np.ndarray:
        """(N,) height of (N, 3) points over the plane, metres (positive on the camera's side)."""
        return np.asarray(points) @ self.normal + self.offset

    def angle_deg(self, other: Plane) -> float:
        """The angle between the two planes' normals, degrees."""
        return math.degrees(math.acos(float(np.clip(self.normal @ other.normal, -1.0, 1.0))))

    def ray_depth(self, u: float, v: float, camera: Camera) -> float:
        """The z-depth (metres) at which the ray of pixel (u, v) meets the plane (inf where it does not)."""
        ray = np.array([(u - camera.cx) / camera.fx, (v - camera.cy) / camera.fy, 1.0])
        along = float(self.normal @ ray)
        return -self.offset / along if along < -1e-12 else math.inf


def oriented(normal: np.ndarray, offset: float) -> Plane:
    """The plane ``normal . p + offset = 0`` with its normal turned towards the camera (the origin)."""
    normal = np.asarray(normal, dtype=np.float64)
    scale = float(np.linalg.norm(normal))
    normal, offset = normal / scale, offset / scale
    return Plane(normal, float(offset)) if offset >= 0 else Plane(-normal, float(-offset))


def sample_stride(camera: Camera) -> int:
    """The pixel stride that leaves about :data:`SAMPLE_PIXELS` samples along the image's longer side."""
    return max(1, int(round(max(camera.width, camera.height) / SAMPLE_PIXELS)))


def back_project(depth: np.ndarray, camera: Camera, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """The valid depth of an (H, W) z-depth image (metres, NaN or <= 0 missing) strictly between the camera's
    clip planes (a generated frame writes what lies beyond them onto them), every ``stride``-th pixel: (N, 3) points in the camera frame and their (N, 2) pixels (u, v)."""
    d = np.asarray(depth, dtype=np.float64)[stride // 2 :: stride, stride // 2 :: stride]
    v, u = np.mgrid[stride // 2 : depth.shape[0] : stride, stride // 2 : depth.shape[1] : stride]
    eps = 1e-3 * (camera.clip_end - camera.clip_start)  # depth clamped onto a plane is no surface
    ok = np.isfinite(d) & (d > camera.clip_start + eps) & (d < camera.clip_end - eps)
    z, u, v = d[ok], u[ok].astype(np.float64), v[ok].astype(np.float64)
    points = np.stack([(u - camera.cx) * z / camera.fx, (v - camera.cy) * z / camera.fy, z], axis=1)
    return points, np.stack([u, v], axis=1)


def fit_plane(points: np.ndarray) -> Plane:
    """The least-squares plane of (N >= 3, 3) points (the normal: the direction of least spread)."""
    centre = points.mean(0)
    spread = points - centre
    _, vectors = np.linalg.eigh(spread.T @ spread)
    normal = vectors[:, 0]
    return oriented(normal, -float(normal @ centre))


def refit(points: np.ndarray, plane: Plane, tol: float, rounds: int = 3) -> tuple[Plane, np.ndarray]:
    """``plane`` refitted by least squares to the points within ``tol`` metres of it, ``rounds`` times;
    the plane and its (N,) inlier mask."""
    inliers = np.abs(plane.height(points)) < tol
    for _ in range(rounds):
        if inliers.sum() < 3:
            break
        plane = fit_plane(points[inliers])
        inliers = np.abs(plane.height(points)) < tol
    return plane, inliers


def ransac_plane(points: np.ndarray, tol: float, rng: np.random.Generator, iterations: int = 300,
                 max_tilt_deg: float = 75.0) -> tuple[Plane, np.ndarray] | None:
    """The plane of most points within ``tol`` (RANSAC over triples, then :func:`refit`), among planes
    whose normal lies within ``max_tilt_deg`` of the viewing direction (a floor the camera sees);
    None when no triple gives one."""
    n = len(points)
    if n < 3:
        return None
    min_facing = math.cos(math.radians(max_tilt_deg))
    triples = rng.integers(0, n, size=(iterations, 3))
    a, b, c = points[triples[:, 0]], points[triples[:, 1]], points[triples[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    keep = norms > 1e-12
    normals[keep] /= norms[keep, None]
    keep &= np.abs(normals[:, 2]) >= min_facing
    if not keep.any():
        return None
    # each hypothesis scored on the same subsample of the points; the winner refitted on all of them
    probe = points[rng.choice(n, size=min(n, SCORE_POINTS), replace=False)] if n > SCORE_POINTS else points
    normals, offsets = normals[keep], -np.einsum("ij,ij->i", normals[keep], a[keep])
    counts = np.concatenate([np.count_nonzero(np.abs(probe @ normals[i:i + 64].T + offsets[i:i + 64]) < tol, axis=0)
                             for i in range(0, len(normals), 64)])
    k = int(np.argmax(counts))
    best = oriented(normals[k], float(offsets[k]))
    plane, inliers = refit(points, best, tol)
    if abs(plane.normal[2]) < min_facing:
        return None
    return plane, inliers


def find_planes(points: np.ndarray, tol: float, rng: np.random.Generator, max_planes: int = 8,
                min_points: int = 200) -> list[tuple[Plane, np.ndarray]]:
    """Up to ``max_planes`` planes the camera faces, each the best of the points the earlier ones left
    (sequential RANSAC), each with at least ``min_points`` inliers; (plane, inlier mask over all points)."""
    left = np.ones(len(points), dtype=bool)
    found: list[tuple[Plane, np.ndarray]] = []
    while len(found) < max_planes and left.sum() >= min_points:
        idx = np.flatnonzero(left)
        fitted = ransac_plane(points[idx], tol, rng)
        if fitted is None:
            break
        plane, inliers = fitted
        if inliers.sum() < min_points:
            break
        mask = np.zeros(len(points), dtype=bool)
        mask[idx[inliers]] = True
        found.append((plane, mask))
        left &= ~mask
    return found


def plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning a plane of ``normal`` (a right-handed frame with the normal as z)."""
    helper = np.array([0.0, 1.0, 0.0]) if abs(normal[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(helper, normal)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(normal, e1)
