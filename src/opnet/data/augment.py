"""Sim-to-real augmentations of the normalized depth input (docs/method.md#network-input, paper "Sim-to-Real").

The paper applies "augmentations in a random order and with varying intensity, such as elastic
transformations, blurring, and adding noise to the pixels"; depth-sensor artefacts (random missing
pixels, holes at depth edges) are this project's addition **[decision]**. Missing pixels are
re-filled with :func:`opnet.data.preprocess.fill_missing_depth`, exactly as at test time.
The random resize interpolation (the paper's other sim-to-real noise) happens before, in
:func:`opnet.data.preprocess.to_network_input`: the caller draws the flag with
:meth:`DepthAugmenter.draw_interpolation`, which picks one of the configured names of
:data:`opnet.data.preprocess.RESIZE_INTERPOLATIONS` (all seven by default, only "area" in
``conf/augmentation/none.yaml``), so the whole sim-to-real recipe lives in one config group.

Albumentations is used for the elastic transformation (``ElasticTransform``), the blurs
(``GaussianBlur``, ``MotionBlur``) and the pixel noise (``GaussNoise``, float32, std relative to
1 = the clip range); the sensor dropout is plain numpy. Every random draw comes from the
``np.random.Generator`` passed to the call (albumentations transforms are re-seeded from it), so
the output is a deterministic function of the image and the generator state.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import albumentations as A  # offline: opnet/__init__.py has turned its update check off
import cv2
import numpy as np

from opnet.data.preprocess import RESIZE_INTERPOLATIONS, fill_missing_depth, square_canvas
from opnet.data.rotate import rotate_record
from opnet.datasets.record import SceneRecord
from opnet.geometry.camera import Camera

Range = tuple[float, float]


def _range(name: str, value: Sequence[float], low: float = 0.0) -> Range:
    lo, hi = (float(v) for v in value)
    if not low <= lo <= hi:
        raise ValueError(f"DepthAugmenter: {name}={tuple(value)}, expected ({low} <=) low <= high")
    return lo, hi


def _probability(name: str, value: float) -> float:
    if not 0.0 <= value <= 1.0:
        raise ValueError(f"DepthAugmenter: {name}={value}, expected a probability in [0, 1]")
    return float(value)


class DepthAugmenter:
    """Random-order, random-intensity augmentation of a normalized depth image.

    Each augmentation is applied with its probability; the applied ones run in a random order;
    each draws its intensity uniformly from its range.

    Args:
        p_elastic: probability of the elastic transformation.
        elastic_alpha: range of albumentations' ``alpha`` (displacement scale). With
            ``elastic_sigma=5`` the RMS displacement is about ``alpha / 45`` px at 128 x 128
            (alpha 10 -> 0.22 px, 50 -> 1.1 px RMS, 4 px at most).
        elastic_sigma: smoothness (Gaussian sigma, px) of the displacement field.
        p_blur: probability of a blur.
        p_motion_blur: probability that a blur is a motion blur instead of a Gaussian blur.
        blur_sigma: range of the Gaussian blur's sigma in pixels.
        motion_blur_size: range of the motion blur's kernel size in pixels (odd, >= 3).
        p_noise: probability of Gaussian pixel noise.
        noise_std: range of the noise's standard deviation in normalized depth units
            (1 = clip_end - clip_start).
        p_dropout: probability of depth-sensor dropout.
        dropout_rate: range of the fraction of pixels dropped at random.
        edge_dropout_rate: range of the fraction of depth-edge pixels dropped (the farther side
            of a jump, where structured-light sensors lose depth in shadows).
        edge_threshold: depth jump between neighbours (normalized units) that makes an edge.
        fill_value: value of an image whose pixels were all dropped (1 = far clip plane).
        resize_interpolations: names (keys of ``RESIZE_INTERPOLATIONS``) that
            :meth:`draw_interpolation` chooses from.
        p_zoom: probability of a random zoom (:meth:`view`): the network input shows a random
            square window of the canvas, ``zoom`` times its side, at a random position, as a
            camera closer to the bin or with a longer focal length would.
        zoom: range of the window side relative to the canvas side, in (0, 1].
        p_clip: probability of random clip planes (:meth:`view`): the near plane is drawn
            between the nearest valid depth and ``clip_margin`` x the clip range in front of it,
            the far plane likewise behind the farthest valid depth, so the normalized depth
            contrast varies as it does between sensors and set-ups.
        clip_margin: range of those margins, as fractions of the scene's clip range.
        p_rotate: probability of an in-plane rotation (:meth:`turn`): the camera turned about its
            optical axis, the labels turned with it, exact for any pinhole camera.
        rotate_deg: range of the turn's angle, degrees.
    """

    def __init__(
        self,
        p_elastic: float = 0.5,
        elastic_alpha: Sequence[float] = (10.0, 50.0),
        elastic_sigma: float = 5.0,
        p_blur: float = 0.5,
        p_motion_blur: float = 0.3,
        blur_sigma: Sequence[float] = (0.3, 1.2),
        motion_blur_size: Sequence[int] = (3, 5),
        p_noise: float = 0.5,
        noise_std: Sequence[float] = (0.001, 0.01),
        p_dropout: float = 0.5,
        dropout_rate: Sequence[float] = (0.0, 0.05),
        edge_dropout_rate: Sequence[float] = (0.0, 0.5),
        edge_threshold: float = 0.04,
        fill_value: float = 1.0,
        resize_interpolations: Sequence[str] = tuple(RESIZE_INTERPOLATIONS),
        p_zoom: float = 0.0,
        zoom: Sequence[float] = (0.6, 1.0),
        p_clip: float = 0.0,
        clip_margin: Sequence[float] = (0.0, 0.6),
        p_rotate: float = 0.0,
        rotate_deg: Sequence[float] = (-180.0, 180.0),
    ):
        self.p_elastic = _probability("p_elastic", p_elastic)
        self.p_blur = _probability("p_blur", p_blur)
        self.p_motion_blur = _probability("p_motion_blur", p_motion_blur)
        self.p_noise = _probability("p_noise", p_noise)
        self.p_dropout = _probability("p_dropout", p_dropout)
        self.elastic_alpha = _range("elastic_alpha", elastic_alpha)
        self.blur_sigma = _range("blur_sigma", blur_sigma, low=1e-3)
        self.noise_std = _range("noise_std", noise_std)
        self.dropout_rate = _range("dropout_rate", dropout_rate)
        self.edge_dropout_rate = _range("edge_dropout_rate", edge_dropout_rate)
        if not 0.0 <= self.dropout_rate[1] <= 1.0 or not 0.0 <= self.edge_dropout_rate[1] <= 1.0:
            raise ValueError(
                "DepthAugmenter: dropout_rate and edge_dropout_rate must lie in [0, 1]"
            )
        size = tuple(int(v) for v in motion_blur_size)
        if len(size) != 2 or not 3 <= size[0] <= size[1]:
            raise ValueError(f"DepthAugmenter: motion_blur_size={size}, expected 3 <= low <= high")
        if elastic_sigma <= 0 or edge_threshold <= 0:
            raise ValueError(
                f"DepthAugmenter: elastic_sigma={elastic_sigma} and edge_threshold={edge_threshold}"
                " must be positive"
            )
        self.edge_threshold, self.fill_value = float(edge_threshold), float(fill_value)
        unknown = [n for n in resize_interpolations if n not in RESIZE_INTERPOLATIONS]
        if unknown or not resize_interpolations:
            raise ValueError(
                f"DepthAugmenter: resize_interpolations={list(resize_interpolations)}, expected a "
                f"non-empty list of {list(RESIZE_INTERPOLATIONS)}"
            )
        self.resize_interpolations = tuple(str(n) for n in resize_interpolations)
        self.p_zoom = _probability("p_zoom", p_zoom)
        self.p_clip = _probability("p_clip", p_clip)
        self.zoom = _range("zoom", zoom, low=1e-3)
        if self.zoom[1] > 1.0:
            raise ValueError(f"DepthAugmenter: zoom={tuple(zoom)}, expected a range within (0, 1]")
        self.clip_margin = _range("clip_margin", clip_margin)
        self.p_rotate = _probability("p_rotate", p_rotate)
        self.rotate_deg = _range("rotate_deg", rotate_deg, low=-360.0)
        border = cv2.BORDER_REFLECT_101  # a constant border would add depth 0 (the near plane)
        self._elastic = A.ElasticTransform(
            alpha=self.elastic_alpha[0], sigma=float(elastic_sigma), approximate=True,
            border_mode=border, p=1.0,
        )  # fmt: skip
        self._gaussian_blur = A.GaussianBlur(blur_limit=0, sigma_limit=self.blur_sigma, p=1.0)
        self._motion_blur = A.MotionBlur(blur_limit=size, p=1.0)
        self._noise = A.GaussNoise(std_range=self.noise_std, p=1.0)

    def view(
        self, depth: np.ndarray, camera: Camera, rng: np.random.Generator, fit: str = "pad"
    ) -> tuple[Camera, tuple[int, int, int] | None]:
        """Random viewing conditions of a scene before it becomes the network input.

        Args:
            depth: (H, W) metres, NaN = missing (only read: its valid depth range).
            camera: the scene's camera.
            rng: the generator all draws come from.
            fit: the framing rule whose canvas the zoom window lies in.
        Returns:
            ``(camera, canvas)``: the camera with (maybe) other clip planes, and the square window
            ``(x0, y0, side)`` to resize to the network input (None: the usual canvas).
        """
        canvas = None
        if self.p_zoom > 0 and rng.random() < self.p_zoom:
            x0, y0, side = square_canvas(camera, fit)
            window = max(1, round(side * rng.uniform(*self.zoom)))
            canvas = (x0 + int(rng.integers(side - window + 1)), y0 + int(rng.integers(side - window + 1)), window)
        if self.p_clip > 0 and rng.random() < self.p_clip:
            valid = depth[np.isfinite(depth) & (depth > 0)]
            if len(valid):
                span = camera.clip_end - camera.clip_start
                near = float(valid.min()) - rng.uniform(*self.clip_margin) * span
                far = float(valid.max()) + rng.uniform(*self.clip_margin) * span
                camera = dataclasses.replace(camera, clip_start=max(near, 1e-3), clip_end=far)
        return camera, canvas

    def turn(self, record: SceneRecord, rng: np.random.Generator) -> SceneRecord:
        """With probability ``p_rotate``, the scene seen by its camera turned about the optical
        axis by an angle drawn from ``rotate_deg`` (exact, labels turned too:
        :mod:`opnet.data.rotate`). Draws nothing when ``p_rotate`` is 0."""
        if self.p_rotate == 0 or rng.random() >= self.p_rotate:
            return record
        return rotate_record(record, rng.uniform(*self.rotate_deg))

    def draw_interpolation(self, rng: np.random.Generator) -> int:
        """An OpenCV resize flag drawn uniformly from ``resize_interpolations``."""
        name = self.resize_interpolations[int(rng.integers(len(self.resize_interpolations)))]
        return RESIZE_INTERPOLATIONS[name]

    def _seeded(
        self, transform: A.BasicTransform, image: np.ndarray, rng: np.random.Generator
    ) -> np.ndarray:
        transform.set_random_seed(int(rng.integers(2**32)))
        return transform(image=image)["image"]

    def elastic(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Elastic transformation with ``alpha`` drawn from ``elastic_alpha``."""
        self._elastic.alpha = float(rng.uniform(*self.elastic_alpha))
        return self._seeded(self._elastic, image, rng)

    def blur(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Gaussian blur, or with probability ``p_motion_blur`` a motion blur."""
        motion = rng.random() < self.p_motion_blur
        return self._seeded(self._motion_blur if motion else self._gaussian_blur, image, rng)

    def noise(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Additive Gaussian pixel noise with std drawn from ``noise_std``."""
        return self._seeded(self._noise, image, rng)

    def dropout(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Drop random pixels and pixels on the far side of depth edges, then re-fill them."""
        drop = rng.random(image.shape) < rng.uniform(*self.dropout_rate)
        far_edge = np.zeros(image.shape, dtype=bool)
        for axis in (0, 1):
            jump = np.diff(image, axis=axis)  # image[i + 1] - image[i]
            head = (slice(None, -1), slice(None)) if axis == 0 else (slice(None), slice(None, -1))
            tail = (slice(1, None), slice(None)) if axis == 0 else (slice(None), slice(1, None))
            far_edge[tail] |= jump > self.edge_threshold  # the next pixel is farther
            far_edge[head] |= jump < -self.edge_threshold  # this pixel is farther
        drop |= far_edge & (rng.random(image.shape) < rng.uniform(*self.edge_dropout_rate))
        if not drop.any():
            return image
        holed = np.where(drop, np.float32(np.nan), image)
        return fill_missing_depth(holed, fill_value=self.fill_value)

    def __call__(self, image: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Augment a normalized depth image.

        Args:
            image: (H, W) float normalized depth in [0, 1], no NaN (the network input).
            rng: the generator all random draws come from.

        Returns:
            (H, W) float32 in [0, 1] without NaN.

        Raises:
            ValueError: for a non-2D, non-float image or one with NaN / infinite values.
        """
        if not isinstance(image, np.ndarray) or image.ndim != 2:
            raise ValueError(
                f"DepthAugmenter: image must be an (H, W) array, got {getattr(image, 'shape', type(image))}"
            )
        if not np.issubdtype(image.dtype, np.floating) or not np.isfinite(image).all():
            raise ValueError(
                f"DepthAugmenter: image must be float without NaN/inf (fill missing depth first), "
                f"got dtype {image.dtype}"
            )
        steps: list[tuple[float, Callable[[np.ndarray, np.random.Generator], np.ndarray]]] = [
            (self.p_elastic, self.elastic),
            (self.p_blur, self.blur),
            (self.p_noise, self.noise),
            (self.p_dropout, self.dropout),
        ]
        chosen = [step for p, step in steps if rng.random() < p]
        out = np.ascontiguousarray(image, dtype=np.float32)
        for index in rng.permutation(len(chosen)):
            out = chosen[index](out, rng)
        return np.clip(out, 0.0, 1.0).astype(np.float32, copy=False)
