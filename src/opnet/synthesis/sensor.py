"""Depth-sensor models applied to rendered depth at generation time (``sensor=`` Hydra group).

A rendered depth image is exact; a real sensor's is not. :class:`SensorModel` turns the exact
z-depth of the image camera into what a structured-light or time-of-flight sensor would deliver,
with parameters in physical units:

1. **Projector shadows** (structured light; ``baseline_m`` > 0). The projector sits ``baseline_m``
   to the camera's +x with the camera's orientation and intrinsics, so a point seen at pixel
   (u, v) with depth z is lit from projector column ``u_p = u - fx b / z`` on the same row
   (camera and projector rows coincide: epipolar lines are image rows). A point is in shadow (no
   depth) when a nearer surface covers its projector column: a depth buffer of the projector per
   row, each pixel covering its footprint (``u_p`` ± 0.5), so the projector lights through the
   holes of a perforated sheet what lies behind it. This uses the surfaces the camera sees (the
   standard depth-map approximation; an occluder invisible to the camera casts no shadow).
2. **Depth edges** (a jump larger than ``edge_jump_m`` between neighbours): the far side loses
   ``edge_missing_px`` pixels with probability ``edge_missing_prob`` (the correlation window of
   structured light, the blurred return of time of flight); with probability
   ``mixed_pixel_prob`` an edge pixel gets a depth between the near and the far surface
   (time-of-flight "flying pixels").
3. **Grazing surfaces**: the incidence angle between the surface normal (from the depth
   image's gradients) and the viewing ray; the dropout probability ramps from 0 at
   ``grazing_start_deg`` to 1 at ``grazing_end_deg``.
4. **Lateral jitter**: each pixel reads the depth of a neighbour offset by N(0, ``lateral_px``)
   pixels per axis (rounded): ragged edges, as the lateral noise of Nguyen et al. 2012.
5. **Axial noise**: Gaussian with
   ``sigma = noise_a_m + noise_b_m * (z - noise_z0_m)^2 + noise_angle_m / sqrt(z) * theta^2 / (pi/2 - theta)^2``
   (metres; z in metres, theta the incidence angle, capped at 80 deg): the model of Nguyen, Izadi, Lovell,
   "Modeling Kinect sensor noise for improved 3D reconstruction and tracking", 3DIMPVT 2012.
6. **Quantization**: of the disparity ``fx b / z`` in steps of ``disparity_step_px`` (structured
   light: depth steps grow with z^2), and/or of the depth in steps of ``depth_step_m``.
7. **Dropout**: isolated pixels (``dropout_rate``) and clustered holes (``blob_rate`` of the image
   in blobs of about ``blob_scale_px``: dark, specular or saturated patches).

Pixel-unit parameters (``lateral_px``, ``edge_missing_px``, ``disparity_step_px``,
``blob_scale_px``) refer to the rendered camera's pixels. A scene rendered at ``scene.camera_scale``
x the pixels of its camera file applies :meth:`SensorModel.scaled`: each of them times the scale
(``edge_missing_px`` rounded, at least 1 where it is > 0), so that the artefacts keep their size in
the scene and the disparity steps their depth steps. The output is a deterministic function
of the depth, the camera and the generator passed in; ``SensorModel()`` (the ``ideal`` preset)
returns the depth unchanged and draws no random number.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
import torch

from opnet.geometry.camera import Camera
from opnet.synthesis.config import from_known_keys

#: a surface casts a shadow on a point only when it is this much nearer (metres, and relative to
#: the depth): a surface does not shadow itself where it slopes within a pixel's footprint
SHADOW_TOLERANCE = 0.003
SHADOW_TOLERANCE_REL = 0.003
#: the projector's depth buffer has this many bins per pixel
SHADOW_SUBPIXELS = 4

#: entropy tag of the sensor's random stream (SeedSequence([seed, cycle, scene, SENSOR_STREAM]))
SENSOR_STREAM = 0x5E45
#: the incidence-angle noise term is evaluated at most at this angle (Nguyen et al. fitted it up to
#: about 80 deg; beyond, and at depth edges where the normal is ill-defined, it would diverge)
ANGLE_TERM_CAP_DEG = 80.0


@dataclass(frozen=True)
class SensorModel:
    """A depth sensor's artefacts; every default is "none" (an ideal sensor). See the module doc."""

    name: str = "ideal"
    baseline_m: float = 0.0
    disparity_step_px: float = 0.0
    depth_step_m: float = 0.0
    noise_a_m: float = 0.0
    noise_b_m: float = 0.0
    noise_z0_m: float = 0.0
    noise_angle_m: float = 0.0
    lateral_px: float = 0.0
    edge_jump_m: float = 0.01
    edge_missing_px: int = 0
    edge_missing_prob: float = 1.0
    mixed_pixel_prob: float = 0.0
    grazing_start_deg: float = 90.0
    grazing_end_deg: float = 90.0
    dropout_rate: float = 0.0
    blob_rate: float = 0.0
    blob_scale_px: float = 8.0

    def __post_init__(self) -> None:
        def need(ok: bool, key: str, expected: str) -> None:
            if not ok:
                raise ValueError(f"sensor.{key}={getattr(self, key)!r}: expected {expected}")

        for f in dataclasses.fields(self):
            if f.name != "name":
                value = getattr(self, f.name)
                need(isinstance(value, (int, float)) and math.isfinite(value) and value >= 0, f.name,
                     "a finite number >= 0")
        for key in ("edge_missing_prob", "mixed_pixel_prob", "dropout_rate", "blob_rate"):
            need(getattr(self, key) <= 1.0, key, "a probability in [0, 1]")
        need(self.edge_jump_m > 0, "edge_jump_m", "> 0 metres")
        need(self.grazing_start_deg <= self.grazing_end_deg <= 90.0, "grazing_end_deg",
             f"grazing_start_deg ({self.grazing_start_deg}) <= grazing_end_deg <= 90")
        need(self.disparity_step_px == 0 or self.baseline_m > 0, "disparity_step_px",
             "0 unless baseline_m > 0 (disparity needs a projector baseline)")
        need(self.blob_scale_px >= 1 or self.blob_rate == 0, "blob_scale_px", ">= 1 pixel")
        need(float(self.edge_missing_px).is_integer(), "edge_missing_px", "a whole number of pixels")

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | None) -> SensorModel:
        """From a mapping (the Hydra ``sensor`` node); None = ideal; unknown keys are errors."""
        values = dict(values or {})
        values.pop("tag", None)  # the dataset-folder suffix of the preset (conf/sensor/*.yaml)
        return from_known_keys(cls, values, "sensor")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def scaled(self, scale: float) -> SensorModel:
        """This sensor for the image at ``scale`` x the pixels of the camera its settings refer to
        (``scene.camera_scale``): the pixel-unit settings times ``scale`` (module doc), the others
        unchanged; ``self`` at scale 1 and for an ideal sensor (it stays ideal)."""
        if scale == 1 or self.is_ideal:
            return self
        edge = max(1, round(self.edge_missing_px * scale)) if self.edge_missing_px > 0 else 0
        try:
            return dataclasses.replace(self, lateral_px=self.lateral_px * scale, edge_missing_px=edge,
                                       disparity_step_px=self.disparity_step_px * scale,
                                       blob_scale_px=self.blob_scale_px * scale)
        except ValueError as e:  # blob_scale_px below a pixel
            raise ValueError(f"{e} (the sensor at scene.camera_scale={scale:g})") from None

    @property
    def is_ideal(self) -> bool:
        """True when :meth:`apply` returns its input unchanged (whatever the name)."""
        return dataclasses.replace(self, name="ideal") == SensorModel()

    # ---- the model ---------------------------------------------------------------------------
    def apply(self, depth: np.ndarray, camera: Camera, rng: np.random.Generator) -> np.ndarray:
        """The sensor's depth for the exact z-depth ``depth`` ((H, W) metres, NaN = none)."""
        if self.is_ideal:
            return np.asarray(depth, dtype=np.float32)
        z = np.asarray(depth, dtype=np.float64)
        H, W = z.shape
        valid = np.isfinite(z) & (z > 0)
        z = np.where(valid, z, np.nan)
        out = z.copy()
        missing = np.zeros((H, W), dtype=bool)

        if self.baseline_m > 0:
            missing |= projector_shadow(z, camera.fx, self.baseline_m)

        near, far, edge_any = _depth_edges(z, self.edge_jump_m)
        if self.edge_missing_px > 0 and self.edge_missing_prob > 0:
            band = far_side_band(z, int(self.edge_missing_px), self.edge_jump_m)
            missing |= band & (rng.random((H, W)) < self.edge_missing_prob)
        if self.mixed_pixel_prob > 0:
            mixed = edge_any & (rng.random((H, W)) < self.mixed_pixel_prob)
            alpha = rng.random((H, W))
            out = np.where(mixed, near + alpha * (far - near), out)

        theta = None
        if self.grazing_start_deg < 90.0 or self.noise_angle_m > 0:
            theta = incidence_angle(z, camera)
        if self.grazing_start_deg < 90.0:
            start, end = math.radians(self.grazing_start_deg), math.radians(self.grazing_end_deg)
            ramp = np.clip((theta - start) / max(end - start, 1e-9), 0.0, 1.0)
            missing |= np.nan_to_num(ramp, nan=0.0) > rng.random((H, W))

        out = np.where(missing, np.nan, out)
        if self.lateral_px > 0:
            dv = np.rint(rng.normal(0.0, self.lateral_px, (H, W))).astype(np.int64)
            du = np.rint(rng.normal(0.0, self.lateral_px, (H, W))).astype(np.int64)
            vv = np.clip(np.arange(H)[:, None] + dv, 0, H - 1)
            uu = np.clip(np.arange(W)[None, :] + du, 0, W - 1)
            out = out[vv, uu]
            theta = theta[vv, uu] if theta is not None else None

        if self.noise_a_m > 0 or self.noise_b_m > 0 or self.noise_angle_m > 0:
            sigma = self.noise_a_m + self.noise_b_m * (out - self.noise_z0_m) ** 2
            if self.noise_angle_m > 0 and theta is not None:
                t = np.minimum(np.nan_to_num(theta, nan=0.0), math.radians(ANGLE_TERM_CAP_DEG))
                sigma = sigma + self.noise_angle_m / np.sqrt(out) * t**2 / (math.pi / 2 - t) ** 2
            out = out + rng.standard_normal((H, W)) * np.nan_to_num(sigma, nan=0.0)

        if self.disparity_step_px > 0:
            fb = camera.fx * self.baseline_m
            d = fb / out
            out = fb / (np.maximum(np.rint(d / self.disparity_step_px), 1.0) * self.disparity_step_px)
        if self.depth_step_m > 0:
            out = np.rint(out / self.depth_step_m) * self.depth_step_m

        drop = np.zeros((H, W), dtype=bool)
        if self.dropout_rate > 0:
            drop |= rng.random((H, W)) < self.dropout_rate
        if self.blob_rate > 0:
            drop |= _blobs(H, W, self.blob_rate, self.blob_scale_px, rng)
        out = np.where(drop, np.nan, out)
        return out.astype(np.float32)


def projector_shadow(z: np.ndarray, fx: float, baseline_m: float) -> np.ndarray:
    """(H, W) bool: pixels whose surface point the projector ``baseline_m`` to the camera's +x does
    not light (module doc, step 1). NaN depth casts no shadow and gets none.

    A depth buffer of the projector, row by row: every pixel covers the projector columns of its
    footprint, ``u_p`` ± 0.5 in quarter-pixel bins (consecutive pixels of a surface overlap, so a surface leaves no gap),
    and a pixel is in shadow when a surface more than :data:`SHADOW_TOLERANCE` nearer covers its
    own projector column. Through the holes of a perforated sheet the projector lights what lies
    behind wherever its ray passes a hole, as a real one does (an ordering test along the row
    would shadow everything behind the sheet)."""
    H, W = z.shape
    valid = np.isfinite(z) & (z > 0)
    if not valid.any():
        return valid
    rows, cols = np.nonzero(valid)
    depth = z[rows, cols]
    # projector columns in bins of 1 / SHADOW_SUBPIXELS px, counted from the smallest
    u_p = (cols - fx * baseline_m / depth) * SHADOW_SUBPIXELS
    u_p -= math.floor(float(u_p.min())) - SHADOW_SUBPIXELS
    bins = math.ceil(float(u_p.max())) + 2 * SHADOW_SUBPIXELS
    first = np.floor(u_p - SHADOW_SUBPIXELS / 2).astype(np.int64)  # the footprint's bins
    last = np.ceil(u_p + SHADOW_SUBPIXELS / 2).astype(np.int64) - 1
    index, values = [], []
    for k in range(SHADOW_SUBPIXELS + 1):
        take = first + k <= last
        index.append(rows[take] * bins + first[take] + k)
        values.append(depth[take])
    # a scatter-min (order-free, so deterministic); torch's is ~10x numpy's minimum.at
    buffer = torch.full((H * bins,), math.inf, dtype=torch.float64)
    buffer.scatter_reduce_(0, torch.from_numpy(np.concatenate(index)), torch.from_numpy(np.concatenate(values)), "amin")
    nearest = buffer.numpy()[rows * bins + np.floor(u_p).astype(np.int64)]
    out = np.zeros((H, W), dtype=bool)
    out[rows, cols] = nearest < depth - np.maximum(SHADOW_TOLERANCE, SHADOW_TOLERANCE_REL * depth)
    return out


def _depth_edges(z: np.ndarray, jump: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(near, far, edge pixels): the 3 x 3 min and max depth, and the pixels with a 4-neighbour
    more than ``jump`` nearer or farther."""
    ok = np.isfinite(z)
    near = _min_filter(z, 1)
    far = -_min_filter(-z, 1)
    edge = ok & ((z - near > jump) | (far - z > jump))
    return np.where(np.isfinite(near), near, z), np.where(np.isfinite(far), far, z), edge


def far_side_band(z: np.ndarray, width: int, jump: float) -> np.ndarray:
    """Pixels within ``width`` pixels (Chebyshev) of a surface more than ``jump`` nearer: the far
    side of depth edges, where correlation windows and blurred returns lose depth."""
    return np.isfinite(z) & (z - _min_filter(z, width) > jump)


def _min_filter(z: np.ndarray, radius: int) -> np.ndarray:
    """Minimum over the (2 radius + 1)^2 window, ignoring NaN (inf where the window has no depth)."""
    filled = np.where(np.isfinite(z), z, np.inf).astype(np.float32)
    k = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return cv2.erode(filled, k, borderType=cv2.BORDER_REPLICATE).astype(np.float64)


def incidence_angle(z: np.ndarray, camera: Camera) -> np.ndarray:
    """(H, W) angle (radians) between the surface normal (central differences of the back-projected
    points) and the viewing ray; NaN where a neighbour has no depth."""
    H, W = z.shape
    u = (np.arange(W) - camera.cx) / camera.fx
    v = (np.arange(H) - camera.cy) / camera.fy
    P = np.stack([z * u[None, :], z * v[:, None], z], axis=-1)
    du = np.full_like(P, np.nan)
    dv = np.full_like(P, np.nan)
    du[:, 1:-1] = P[:, 2:] - P[:, :-2]
    dv[1:-1] = P[2:] - P[:-2]
    n = np.cross(du, dv)
    cos = np.abs(np.sum(n * P, axis=-1)) / (np.linalg.norm(n, axis=-1) * np.linalg.norm(P, axis=-1))
    return np.arccos(np.clip(cos, 0.0, 1.0))


def _blobs(H: int, W: int, rate: float, scale: float, rng: np.random.Generator) -> np.ndarray:
    """A ``rate`` share of the image in smooth random blobs of about ``scale`` pixels."""
    h, w = max(2, int(math.ceil(H / scale))), max(2, int(math.ceil(W / scale)))
    field = cv2.resize(rng.standard_normal((h, w)).astype(np.float32), (W, H), interpolation=cv2.INTER_CUBIC)
    return field > np.quantile(field, 1.0 - rate)


def sensor_rng(seed: int, cycle: int, scene: int) -> np.random.Generator:
    """The sensor's random stream of scene ``scene`` of ``cycle`` (independent of the drop streams)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(cycle), int(scene), SENSOR_STREAM]))
