"""Pictures for people: object positions on the network input, projected models on depth images."""

from __future__ import annotations

import cv2
import numpy as np

from opnet.geometry.camera import Camera
from opnet.metrics.records import GroundTruthSet, HypothesisSet

GT_COLOR = (60, 200, 60)  # BGR-agnostic: images are RGB here
REQUIRED_OCCLUSION = 0.5


def depth_to_rgb(depth: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    """(H, W) depth (any unit, NaN = missing) to an (H, W, 3) uint8 RGB picture; missing = black."""
    valid = np.isfinite(depth)
    if not valid.any():
        return np.zeros(depth.shape + (3,), np.uint8)
    lo = float(np.nanmin(depth)) if lo is None else lo
    hi = float(np.nanmax(depth)) if hi is None else hi
    norm = np.clip((np.nan_to_num(depth, nan=hi) - lo) / max(hi - lo, 1e-9), 0, 1)
    rgb = cv2.applyColorMap((255 * (1 - norm)).astype(np.uint8), cv2.COLORMAP_VIRIDIS)[..., ::-1]
    rgb = np.ascontiguousarray(rgb)
    rgb[~valid] = 0
    return rgb


def _score_color(score: float) -> tuple[int, int, int]:
    s = float(np.clip(score, 0, 1))
    return (255, int(220 * (1 - s)), int(60 * (1 - s)))


def draw_positions(
    image: np.ndarray, camera: Camera, gt: GroundTruthSet | None, hyps: HypothesisSet | None, scale: int = 3
) -> np.ndarray:
    """Network input (S, S) in [0, 1] with ground-truth origins (green rings; filled = must be
    found) and predicted origins (crosses, red = confident). Returns (S*scale, S*scale, 3) uint8."""
    rgb = depth_to_rgb(image, 0.0, 1.0)
    rgb = cv2.resize(rgb, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    to_px = lambda uv: (int(round((uv[0] + 0.5) * scale - 0.5)), int(round((uv[1] + 0.5) * scale - 0.5)))  # noqa: E731
    if gt is not None and len(gt):
        for t, occ in zip(camera.project(gt.t), gt.occlusion_rate):
            cv2.circle(rgb, to_px(t), 3 * scale, GT_COLOR, -1 if occ <= REQUIRED_OCCLUSION else 1, cv2.LINE_AA)
    if hyps is not None and len(hyps):
        for uv, s in zip(camera.project(hyps.t), hyps.score):
            cv2.drawMarker(rgb, to_px(uv), _score_color(s), cv2.MARKER_TILTED_CROSS, 4 * scale, 2, cv2.LINE_AA)
    return rgb


def draw_models(
    depth: np.ndarray, camera: Camera, vertices: np.ndarray, faces: np.ndarray, hyps: HypothesisSet, max_objects: int = 50
) -> np.ndarray:
    """Depth image (H, W) metres with each hypothesis' mesh projected on it (outline coloured by
    score, translucent fill). ``vertices`` (V, 3) metres in the model frame, ``faces`` (F, 3)."""
    rgb = depth_to_rgb(depth)
    overlay = rgb.copy()
    order = np.argsort(-hyps.score)[:max_objects]
    for k in order[::-1]:  # most confident drawn last, on top
        pts = vertices @ hyps.R[k].T + hyps.t[k]
        if (pts[:, 2] <= 1e-6).any():
            continue
        uv = camera.project(pts)
        polys = np.round(uv[faces]).astype(np.int32)  # (F, 3, 2)
        mask = np.zeros(depth.shape, np.uint8)
        cv2.fillPoly(mask, list(polys), 1)
        color = _score_color(hyps.score[k])
        overlay[mask > 0] = color
        contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        cv2.drawContours(rgb, contours, -1, color, 1, cv2.LINE_AA)
    return cv2.addWeighted(overlay, 0.35, rgb, 0.65, 0)
