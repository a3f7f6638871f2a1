"""The two point clouds ICP fits: the object's model (:class:`ModelCloud`, points sampled on its mesh) and the
scene (:class:`SceneCloud`, the depth image's points with normals from the pixel grid)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class ModelCloud:
    """Points (P, 3) and outward unit normals (P, 3) on the mesh surface, model frame, metres."""

    points: np.ndarray
    normals: np.ndarray
    diameter: float

    @classmethod
    def from_mesh(cls, mesh: Any, count: int, diameter: float, seed: int = 0) -> ModelCloud:
        """``count`` points spread evenly over the surface of a trimesh (deterministic for a seed)."""
        import trimesh

        points, faces = trimesh.sample.sample_surface_even(mesh, count, seed=seed)
        if len(points) < count:  # even sampling can return fewer: top up uniformly
            extra, extra_faces = trimesh.sample.sample_surface(mesh, count - len(points), seed=seed + 1)
            points, faces = np.vstack((points, extra)), np.concatenate((faces, extra_faces))
        return cls(np.asarray(points, np.float64), np.asarray(mesh.face_normals[faces], np.float64), float(diameter))

    def posed(self, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The points at the pose (R, t) in the camera frame (P, 3), and which face the camera (P,)."""
        p = self.points @ R.T + t
        return p, np.sum((self.normals @ R.T) * p, -1) < 0


class _Grid(NamedTuple):
    """The strided pixel grid a :class:`SceneCloud` was made from: points and normals per pixel (NaN where
    none), which pixels have both, the pixels' image coordinates and the camera."""

    xyz: np.ndarray  # (h, w, 3)
    normals: np.ndarray  # (h, w, 3)
    ok: np.ndarray  # (h, w)
    u: np.ndarray  # (w,) image columns of the grid
    v: np.ndarray  # (h,) image rows
    fx: float
    fy: float
    cx: float
    cy: float
    stride: int


class SceneCloud:
    """The depth image as camera-frame points (N, 3) with unit normals (N, 3).

    Made from a depth image (:meth:`from_depth`), it keeps the strided pixel grid, and
    :meth:`neighbourhood` takes the points near a hypothesis from the pixels the ball projects onto:
    no k-d tree over the whole image (on a megapixel frame building one costs more than refining a
    hypothesis). ``tree``, a k-d tree over all the points, is made when first asked for.
    """

    def __init__(self, points: np.ndarray, normals: np.ndarray, grid: _Grid | None = None) -> None:
        self.points, self.normals = points, normals
        self._grid = grid
        self._tree: cKDTree | None = None

    @property
    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self.points if len(self.points) else np.full((1, 3), 1e9))  # empty: one far point
        return self._tree

    @classmethod
    def from_depth(cls, depth: np.ndarray, fx: float, fy: float, cx: float, cy: float, stride: int = 1) -> SceneCloud:
        """From a z-depth image (H, W) in metres (NaN or <= 0: missing) and its intrinsics."""
        depth = np.asarray(depth)
        if depth.ndim != 2:
            raise ValueError(f"icp: depth must be an (H, W) image, got shape {depth.shape}")
        # the strided grid first: its points, and normals from its own neighbours (only the grid's pixels are
        # converted: a megapixel frame at stride 4 is a sixteenth of the work)
        u = np.arange(0, depth.shape[1], stride, dtype=np.float64)
        v = np.arange(0, depth.shape[0], stride, dtype=np.float64)
        d = depth[::stride, ::stride].astype(np.float64)
        z = np.where(np.isfinite(d) & (d > 0), d, np.nan)
        x, y = z * ((u - cx) / fx), z * ((v - cy) / fy)[:, None]
        xyz = np.stack((x, y, z), -1)
        # normals from the neighbouring pixels (central differences; the border has none), coordinate by
        # coordinate on whole planes (several times faster than on the last axis of (h, w, 3) arrays)
        n = np.full_like(xyz, np.nan)
        ok = np.zeros(z.shape, bool)  # the point, and a normal from both neighbours each way
        if xyz.shape[0] > 2 and xyz.shape[1] > 2:
            a = [c[1:-1, 2:] - c[1:-1, :-2] for c in (x, y, z)]  # along u
            b = [c[2:, 1:-1] - c[:-2, 1:-1] for c in (x, y, z)]  # along v
            c = [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
            norm = np.sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2])
            scale = np.where(norm > 0, norm, np.nan)  # finite: so is every coordinate of the normal
            unit = [ck / scale for ck in c]
            away = unit[0] * x[1:-1, 1:-1] + unit[1] * y[1:-1, 1:-1] + unit[2] * z[1:-1, 1:-1] > 0
            for k in range(3):  # turned to face the camera
                n[1:-1, 1:-1, k] = np.where(away, -unit[k], unit[k])
            ok[1:-1, 1:-1] = np.isfinite(scale) & np.isfinite(z[1:-1, 1:-1])
        kept = np.flatnonzero(ok)  # rows of the flattened grids: faster than a mask over (h, w, 3)
        return cls(xyz.reshape(-1, 3)[kept], n.reshape(-1, 3)[kept], _Grid(xyz, n, ok, u, v, fx, fy, cx, cy, stride))

    def neighbourhood(self, centre: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """The points within ``radius`` metres of ``centre`` (3,) and their normals, in pixel order."""
        if self._grid is None:
            idx = np.sort(np.asarray(self.tree.query_ball_point(centre, radius), dtype=np.int64))
            return self.points[idx], self.normals[idx]
        g = self._grid
        x, y, z = (float(c) for c in centre)
        rows, cols = slice(None), slice(None)
        if z - radius > 1e-9:  # the ball lies in front of the camera: its pixels lie in the box of its corners
            depths = (z - radius, z + radius)
            us = [g.fx * xx / zz + g.cx for xx in (x - radius, x + radius) for zz in depths]
            vs = [g.fy * yy / zz + g.cy for yy in (y - radius, y + radius) for zz in depths]
            cols = slice(*np.searchsorted(g.u, [min(us) - 1, max(us) + 1]))
            rows = slice(*np.searchsorted(g.v, [min(vs) - 1, max(vs) + 1]))
        window = g.xyz[rows, cols]
        inside = g.ok[rows, cols] & (np.sum((window - centre) ** 2, -1) <= radius * radius)
        return window[inside], g.normals[rows, cols][inside]


__all__ = ["ModelCloud", "SceneCloud"]
