"""From a scene record to a network sample, and batches of samples (docs/method.md#network-input)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np
import torch

from opnet.data.preprocess import RESIZE_INTERPOLATIONS, resize_segmentation, to_network_input
from opnet.datasets.record import SceneRecord
from opnet.geometry.camera import Camera
from opnet.metrics.records import GroundTruthSet
from opnet.parameterizations.base import GroundTruthBatch

if TYPE_CHECKING:  # the augmenter (and albumentations) only where training loads it
    from opnet.data.augment import DepthAugmenter


@dataclass
class Sample:
    """One network input with its ground truth.

    Attributes:
        image: (1, S, S) float32 normalized depth in [0, 1].
        camera: the camera of the S x S network input.
        R_cam_obj: (N, 3, 3) float32; t_cam_obj: (N, 3) float32 metres, camera frame.
        visibility: (N,) float32; instance_id: (N,) int64.
        segmentation: (S, S) int64 instance ids at input resolution, or None.
        name: scene name.
    """

    image: np.ndarray
    camera: Camera
    R_cam_obj: np.ndarray
    t_cam_obj: np.ndarray
    visibility: np.ndarray
    instance_id: np.ndarray
    segmentation: np.ndarray | None
    name: str


@dataclass
class Batch:
    """A collated batch: the network input, the parameterization's ground truth and the metric's."""

    images: torch.Tensor  # (B, 1, S, S) float32
    cameras: list[Camera]
    gt: GroundTruthBatch
    gt_sets: list[GroundTruthSet]
    names: list[str]

    def to(self, device: torch.device | str) -> Batch:
        self.images = self.images.to(device)
        self.gt = self.gt.to(device)
        return self

    def __len__(self) -> int:
        return len(self.names)


def make_sample(
    record: SceneRecord,
    size: int = 128,
    interpolation: int = cv2.INTER_AREA,
    augmenter: DepthAugmenter | None = None,
    rng: np.random.Generator | None = None,
    fit: str = "pad",
) -> Sample:
    """Preprocess one scene: crop to the canvas, resize, fill missing depth, normalize, augment.

    With an augmenter, its in-plane rotation (labels turned too) and random view (zoom window,
    clip planes) come first and the sample's
    camera is the camera of that view, so the targets stay consistent with the image. ``fit`` is
    the framing rule (:func:`opnet.data.preprocess.square_canvas`).
    """
    camera, canvas = record.camera, None
    if augmenter is not None:
        rng = rng if rng is not None else np.random.default_rng()
        record = augmenter.turn(record, rng)
        camera, canvas = augmenter.view(record.depth, record.camera, rng, fit)
    image, net_camera = to_network_input(record.depth, camera, size=size, interpolation=interpolation, fit=fit,
                                         canvas=canvas)
    if augmenter is not None:
        image = augmenter(image, rng)
    seg = None
    if record.segmentation is not None:
        seg = resize_segmentation(record.segmentation, camera, size, fit=fit, canvas=canvas).astype(np.int64)
    return Sample(
        image=image[None].astype(np.float32),
        camera=net_camera,
        R_cam_obj=record.R_cam_obj.astype(np.float32),
        t_cam_obj=record.t_cam_obj.astype(np.float32),
        visibility=np.clip(record.visibility, 0.0, 1.0).astype(np.float32),
        instance_id=record.instance_id.astype(np.int64),
        segmentation=seg,
        name=record.name,
    )


def random_interpolation(rng: np.random.Generator) -> int:
    """One of OpenCV's resize interpolations, drawn uniformly (domain randomization, docs/method.md#network-input)."""
    flags = list(RESIZE_INTERPOLATIONS.values())
    return int(flags[rng.integers(len(flags))])


def collate(samples: Sequence[Sample]) -> Batch:
    """Stack samples into a :class:`Batch`."""
    images = torch.from_numpy(np.stack([s.image for s in samples]))
    gt = GroundTruthBatch.from_arrays(
        [(s.R_cam_obj, s.t_cam_obj, s.visibility, s.instance_id, s.segmentation) for s in samples]
    )
    gt_sets = [
        GroundTruthSet(s.R_cam_obj, s.t_cam_obj, 1.0 - s.visibility, s.instance_id) for s in samples
    ]
    return Batch(images, [s.camera for s in samples], gt, gt_sets, [s.name for s in samples])
