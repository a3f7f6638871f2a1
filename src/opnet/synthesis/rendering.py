"""Depth, instance segmentation and visibility of a bin scene with pyrender (EGL, offscreen).

Decisions:
- Everything is rendered in the internal OpenCV camera frame; the pyrender camera node sits at
  ``diag(1, -1, -1)`` (OpenGL looks down -z with y up). pyrender's ``IntrinsicsCamera`` puts pixel
  edges at integers (``x_window = fx X / Z + cx``), so the OpenCV principal point (pixel centres
  at integers) is passed as ``cx + 0.5``, ``cy + 0.5``; the unit tests check the pixel coverage.
- One pass with ``RenderFlags.SEG`` gives both the z-depth (metres, 0 -> NaN) and the segmentation:
  object k is drawn in colour (k, 0, 0); the bin and the ground are drawn in black, so they hide
  objects behind them but are not objects. The near plane is half of ``clip_start``, the far plane
  twice ``clip_end``: what lies outside the clip planes is rendered and then written as missing
  depth by the depth code, never cut open.
- Visibility = visible pixels of k / pixels of k rendered alone with the same camera. The solo
  counts come from union passes (:mod:`opnet.synthesis.offscreen`): up to 24 objects per pass,
  each in its own bit, without depth test, so one pass counts every silhouette at once. Parts
  outside the image must count too: the pass covers the rectangle of the unbounded canvas (the
  same pixel grid, the principal point shifted by whole pixels) that holds every counted part's
  projected bounding box; only beyond ``MAX_CANVAS`` pixels a side does it fall back to the
  image-sized windows each box touches, their counts summed.
- Only what can cover a pixel is drawn: the scene pass leaves out parts whose projected bounding
  box misses the image, and solo counts are made only for parts with a visible pixel (the others
  have visibility 0 whatever their count). Both are exact; in bulk piles they save about half of
  the rendering.
- Solo counts are cached within a cycle and reused while an object moved less than
  ``solo_cache_mm`` and ``solo_cache_deg`` since it was counted (at 0.3 mm and 0.3 degree the
  count changes by well under 1 %); a reused count may then be a pixel short, so visibility is
  capped at 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from opnet.geometry.camera import Camera
from opnet.synthesis.offscreen import (
    UNION_BITS,
    bit_color,
    count_bits,
    pyrender,
    shared_renderer,
    union_mode,
)

#: OpenCV camera axes expressed in the OpenGL camera frame pyrender uses (and back: it is its own inverse)
GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])
_BLACK = (0, 0, 0)
#: a visibility pass covers at most this many pixels a side in one viewport
MAX_CANVAS = 2048


@dataclass
class RenderedScene:
    """One rendered scene.

    Attributes:
        depth: (H, W) float32 z-depth in metres, camera frame; NaN where nothing was hit.
        segmentation: (H, W) int32, k for pixels of object k (1-based drop order), 0 elsewhere.
        visibility: (N,) float64 in [0, 1], visible pixels / solo pixels of each object (0 when it
            projects to no pixel at all).
        solo_pixels: (N,) int64 pixels of each object rendered alone (enlarged canvas).
        solo_renders: how many solo render passes this scene needed.
    """

    depth: np.ndarray
    segmentation: np.ndarray
    visibility: np.ndarray
    solo_pixels: np.ndarray
    solo_renders: int


class SceneRenderer:
    """Renders bin scenes of one part with one camera; reuse it for every scene of a worker.

    Args:
        mesh: the part, model frame, metres.
        camera: the image camera (internal OpenCV frame; size, intrinsics, clip planes).
        bin_mesh: the bin in the bin frame, metres, or None for no bin.
        ground_size: side of the square ground plate under the bin, metres (0 = no ground).
        ground_depth: the ground plate's top lies this far below the bin frame origin, metres.
        solo_cache_mm, solo_cache_deg: solo-count reuse tolerances (module docstring).
    """

    def __init__(
        self,
        mesh: trimesh.Trimesh,
        camera: Camera,
        bin_mesh: trimesh.Trimesh | None = None,
        ground_size: float = 0.0,
        ground_depth: float = 0.0,
        solo_cache_mm: float = 0.3,
        solo_cache_deg: float = 0.3,
    ) -> None:
        self.camera = camera
        self._tol_t = solo_cache_mm * 1e-3
        self._tol_cos = math.cos(math.radians(solo_cache_deg))
        self._scene = pyrender.Scene(bg_color=[0.0, 0.0, 0.0, 0.0])
        self._cam_node = self._scene.add(self._gl_camera(0, 0), pose=GL_FROM_CV)
        # SEG passes use neither normals nor shading: shared vertices ("smooth") give the same
        # pixels as per-face vertices with a sixth of the vertex work (13 % faster 75-part scenes)
        self._mesh = pyrender.Mesh.from_trimesh(mesh, smooth=True)
        self._box_corners = trimesh.bounds.corners(mesh.bounds)  # (8, 3) model frame
        self._objects: list[pyrender.Node] = []
        self._statics: list[pyrender.Node] = []
        self._clutter: pyrender.Node | None = None
        self._ground: pyrender.Node | None = None
        self._bins: dict[int, tuple[list[pyrender.Node], pyrender.Node | None]] = {}
        self.add_bin(0, bin_mesh, ground_size, ground_depth)
        self.select_bin(0)
        self._cache: dict[int, tuple[np.ndarray, int]] = {}

    def add_bin(self, key: int, bin_mesh: trimesh.Trimesh | None, ground_size: float = 0.0,
                ground_depth: float = 0.0) -> None:  # fmt: skip
        """Another bin and its ground plate (the constructor's arguments), drawn once :meth:`select_bin`
        picks ``key`` (the constructor's bin is ``0``): one scene holds every bin model of a dataset."""
        nodes, ground = [], None
        if bin_mesh is not None:
            nodes.append(self._scene.add(pyrender.Mesh.from_trimesh(bin_mesh, smooth=False)))
        if ground_size > 0:
            plate = trimesh.creation.box(extents=(ground_size, ground_size, 0.01))
            plate.apply_translation((0.0, 0.0, -ground_depth - 0.005))
            ground = self._scene.add(pyrender.Mesh.from_trimesh(plate, smooth=False))
            nodes.append(ground)
        self._bins[key] = (nodes, ground)

    def select_bin(self, key: int) -> None:
        """Draw bin ``key`` (:meth:`add_bin`) and its ground from now on; the others stay in the scene
        undrawn (every pass draws only the nodes it colours)."""
        nodes, self._ground = self._bins[key]
        self._statics = [*nodes, *([self._clutter] if self._clutter is not None else [])]

    def _gl_camera(self, ox: int, oy: int) -> pyrender.IntrinsicsCamera:
        """The camera of a window whose top-left pixel is pixel (ox, oy) of the (unbounded) image."""
        c = self.camera
        return pyrender.IntrinsicsCamera(
            c.fx, c.fy, c.cx - ox + 0.5, c.cy - oy + 0.5, znear=0.5 * c.clip_start, zfar=2.0 * c.clip_end
        )

    def close(self) -> None:
        """Drop the scene's objects (the shared GL context stays for the next renderer)."""
        bins = [node for nodes, _ in self._bins.values() for node in nodes]
        for node in [*self._objects, *bins, *([self._clutter] if self._clutter is not None else [])]:
            self._scene.remove_node(node)
        self._objects, self._statics, self._clutter, self._ground, self._bins = [], [], None, None, {}
        self._cache.clear()

    def begin_cycle(self, T_cam_bin: np.ndarray, clutter: trimesh.Trimesh | None = None,
                    T_cam_ground: np.ndarray | None = None) -> None:  # fmt: skip
        """New cycle: place the bin and the ground (``T_cam_ground``, the frame the ground plate
        hangs from; None = the bin's), replace the foreign pieces on the floor (``clutter``, bin
        frame, drawn like the bin; None = none) and forget cached counts."""
        if self._clutter is not None:
            self._scene.remove_node(self._clutter)
            self._statics.remove(self._clutter)
            self._clutter = None
        if clutter is not None:
            self._clutter = self._scene.add(pyrender.Mesh.from_trimesh(clutter, smooth=False))
            self._statics.append(self._clutter)
        for node in self._statics:
            self._scene.set_pose(node, T_cam_bin if node is not self._ground or T_cam_ground is None else T_cam_ground)
        self._cache.clear()

    # ---- rendering ---------------------------------------------------------------------------
    def render(self, T_cam_obj: np.ndarray) -> RenderedScene:
        """Render the bin with objects at ``T_cam_obj`` (N, 4, 4) model-to-camera poses, metres."""
        n = len(T_cam_obj)
        self._set_objects(T_cam_obj)
        boxes = [self._pixel_box(T) for T in T_cam_obj]
        depth, seg = self._scene_pass([k for k, box in enumerate(boxes) if _in_window(box, (0, 0), self.camera)])
        visible = np.bincount(seg.ravel(), minlength=n + 1)[1 : n + 1]
        # a part with no visible pixel has visibility 0 whatever its solo count: not counted
        solo, renders = self._solo_counts(T_cam_obj, boxes, visible > 0)
        # a reused solo count may be a pixel short of the moved object's: never report more than 1
        vis = np.minimum(visible / np.maximum(solo, 1), 1.0) * (solo > 0)
        return RenderedScene(depth, seg, vis.astype(np.float64), solo, renders)

    def _scene_pass(self, drawn: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """(depth (H, W) float32 metres, NaN = nothing; segmentation (H, W) int32) with objects
        ``drawn`` (indices; the others lie outside the image and would not cover a pixel)."""
        seg_map = {self._objects[k]: (k + 1, 0, 0) for k in drawn}
        seg_map.update({node: _BLACK for node in self._statics})
        color, z = self._render_seg(seg_map, (0, 0))
        return np.where(z > 0, z, np.nan).astype(np.float32), color[..., 0].astype(np.int32)

    def _set_objects(self, T_cam_obj: np.ndarray) -> None:
        while len(self._objects) < len(T_cam_obj):
            self._objects.append(self._scene.add(self._mesh))
        for node, T in zip(self._objects, T_cam_obj):
            self._scene.set_pose(node, np.asarray(T, dtype=np.float64))

    def _render_seg(self, seg_map: dict, origin: tuple[int, int], size: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """SEG pass over the ``size`` (w, h; default the image's) rectangle of the unbounded canvas
        whose top-left pixel is ``origin`` (ox, oy): the image's pixel grid, another viewport."""
        self._cam_node.camera = self._gl_camera(*origin)
        w, h = size or (self.camera.width, self.camera.height)
        return shared_renderer(w, h).render(self._scene, pyrender.RenderFlags.SEG, seg_node_map=seg_map)

    # ---- visibility denominators -------------------------------------------------------------
    def _solo_counts(self, T_cam_obj: np.ndarray, boxes: list, wanted: np.ndarray) -> tuple[np.ndarray, int]:
        """Solo pixel counts of the objects ``wanted`` ((N,) bool; 0 for the others) and the passes
        made; ``boxes`` are their projected bounding boxes (:meth:`_pixel_box`).

        The objects to count are rendered over one viewport: the rectangle of the canvas pixel
        grid that holds all their boxes, so a part reaching out of the image costs no extra
        pass. Beyond ``MAX_CANVAS`` pixels a side, image-sized window by window."""
        n = len(T_cam_obj)
        counts = np.zeros(n, dtype=np.int64)
        todo: list[int] = []
        for k in np.flatnonzero(wanted):
            cached = self._cache.get(k)
            if cached is not None and self._same_pose(cached[0], T_cam_obj[k]):
                counts[k] = cached[1]
            elif boxes[k] is not None:
                todo.append(int(k))
        renders = 0
        with union_mode():
            for (origin, size), members in self._canvas_passes([boxes[k] for k in todo], todo):
                for chunk in range(0, len(members), UNION_BITS):
                    group = members[chunk : chunk + UNION_BITS]
                    seg_map = {self._objects[k]: bit_color(j) for j, k in enumerate(group)}
                    color, _ = self._render_seg(seg_map, origin, size)
                    counts[group] += count_bits(color, len(group))
                    renders += 1
        for k in todo:
            self._cache[k] = (np.array(T_cam_obj[k], dtype=np.float64), int(counts[k]))
        return counts, renders

    def _canvas_passes(self, boxes: list, todo: list[int]) -> list:
        """[((origin, size), objects)]: one rectangle of pixels around every box (1 pixel to
        spare) when it is at most ``MAX_CANVAS`` a side, else the image-sized windows each box
        touches."""
        if not todo:
            return []
        lo = np.floor(np.min([b[:2] for b in boxes], axis=0) + 0.5).astype(int) - 1
        hi = np.floor(np.max([b[2:] for b in boxes], axis=0) + 0.5).astype(int) + 1
        size = hi - lo + 1
        if size.max() <= MAX_CANVAS:
            return [(((int(lo[0]), int(lo[1])), (int(size[0]), int(size[1]))), todo)]
        by_window: dict[tuple[int, int], list[int]] = {}
        for k, box in zip(todo, boxes):
            for window in _windows(box, self.camera.width, self.camera.height):
                by_window.setdefault(window, []).append(k)
        return [((window, None), members) for window, members in sorted(by_window.items())]

    def _same_pose(self, T_a: np.ndarray, T_b: np.ndarray) -> bool:
        if np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]) > self._tol_t:
            return False
        cos = (np.trace(T_a[:3, :3].T @ T_b[:3, :3]) - 1.0) / 2.0
        return bool(cos >= self._tol_cos)

    def _pixel_box(self, T: np.ndarray) -> tuple[float, float, float, float] | None:
        """Projected (u0, v0, u1, v1) of the model bounding box, or None if it crosses z <= near."""
        p = self._box_corners @ T[:3, :3].T + T[:3, 3]
        if p[:, 2].min() <= 0.5 * self.camera.clip_start:
            return None
        uv = self.camera.project(p)
        return float(uv[:, 0].min()), float(uv[:, 1].min()), float(uv[:, 0].max()), float(uv[:, 1].max())


def _in_window(box: tuple[float, float, float, float] | None, window: tuple[int, int], camera: Camera) -> bool:
    """Whether a projected box may cover a pixel of the image-sized ``window`` (a box crossing the
    near plane, None, always may)."""
    if box is None:
        return True
    return window in _windows(box, camera.width, camera.height)


def _windows(box: tuple[float, float, float, float], W: int, H: int) -> list[tuple[int, int]]:
    """Offsets (whole pixels) of the W x H windows of the unbounded canvas that ``box`` touches."""
    u0, v0, u1, v1 = box
    xs = range(math.floor((u0 + 0.5) / W), math.floor((u1 + 0.5) / W) + 1)
    ys = range(math.floor((v0 + 0.5) / H), math.floor((v1 + 0.5) / H) + 1)
    return [(i * W, j * H) for j in ys for i in xs]
