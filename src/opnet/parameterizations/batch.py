"""What every parameterization shares besides its class: the channel layout of one slot
(:class:`ChannelLayout`, owned by the parameterization and read by the loss, the decodings and the export) and
the ground truth of a batch (:class:`GroundTruthBatch`, what ``encode`` reads)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

POSE_CHANNEL_NAMES = ("p", "v", "x", "y", "z")
#: the name of the quality channel (:attr:`ChannelLayout.quality`)
QUALITY_CHANNEL_NAME = "q"


@dataclass(frozen=True)
class ChannelLayout:
    """Where each quantity lies among the ``channels`` of one slot: ``[p, v, x, y, z, rotation..., (q)]``.

    Index the channel axis of one slot with these: ``grid5[:, :, layout.presence]`` of a
    :meth:`Parameterization.split_slots` view is the (B, L, S, S) presence, ``feat[:, layout.position]``
    of gathered feature vectors (N, channels) their (N, 3) position channels.

    Attributes:
        presence: index of p, the slot holds an object.
        visibility: index of v, the object's visible fraction.
        position: slice of the three position channels x, y, z.
        rotation: slice of the rotation codec's channels.
        channels: channels per slot; every one belongs to exactly one of the above.
        quality: index of q, the network's estimate of how right the slot's orientation is (its target: how
            close the orientation decoded from the slot's rotation channels lies to the truth); None: no such
            channel (the paper's layout).
    """

    presence: int
    visibility: int
    position: slice
    rotation: slice
    channels: int
    quality: int | None = None

    def __post_init__(self) -> None:
        every = range(self.channels)
        used = [self.presence, self.visibility, *every[self.position], *every[self.rotation]]
        if self.quality is not None:
            used.append(self.quality)
        if sorted(used) != list(every) or len(every[self.position]) != 3:
            raise ValueError(f"{self}: each of the {self.channels} channels must belong to exactly one quantity, "
                             "three of them to the position")

    @classmethod
    def for_rotation(cls, rotation_channels: int, quality: bool = False) -> ChannelLayout:
        """The layout of a slot whose rotation codec writes ``rotation_channels`` channels (``quality``: one
        more channel after them, q)."""
        head = len(POSE_CHANNEL_NAMES)
        end = head + rotation_channels
        return cls(0, 1, slice(2, head), slice(head, end), end + int(quality), end if quality else None)


@dataclass
class GroundTruthBatch:
    """Ground truth of a batch, flat with a batch index (one row per instance).

    Attributes:
        batch_index: (M,) long, the image of each instance.
        R_cam_obj: (M, 3, 3) float32 object -> camera rotations.
        t_cam_obj: (M, 3) float32 metres, object origins in the camera frame.
        visibility: (M,) float32 visible fraction in [0, 1].
        instance_id: (M,) long, the instance's value in ``segmentation``.
        batch_size: number of images B (images may have no instance).
        segmentation: (B, H, W) long instance ids at network-input resolution (0 = background),
            or None (only SI needs it).
    """

    batch_index: torch.Tensor
    R_cam_obj: torch.Tensor
    t_cam_obj: torch.Tensor
    visibility: torch.Tensor
    instance_id: torch.Tensor
    batch_size: int
    segmentation: torch.Tensor | None = None

    def __post_init__(self) -> None:
        m = len(self.batch_index)
        expected = {
            "R_cam_obj": (m, 3, 3),
            "t_cam_obj": (m, 3),
            "visibility": (m,),
            "instance_id": (m,),
        }
        for name, shape in expected.items():
            if tuple(getattr(self, name).shape) != shape:
                raise ValueError(
                    f"GroundTruthBatch.{name}: expected shape {shape}, "
                    f"got {tuple(getattr(self, name).shape)}"
                )
        if m and (
            int(self.batch_index.min()) < 0 or int(self.batch_index.max()) >= self.batch_size
        ):
            raise ValueError(
                f"GroundTruthBatch.batch_index: expected values in [0, {self.batch_size}), "
                f"got {self.batch_index.tolist()}"
            )
        if self.segmentation is not None and (
            self.segmentation.ndim != 3 or len(self.segmentation) != self.batch_size
        ):
            raise ValueError(
                f"GroundTruthBatch.segmentation: expected shape ({self.batch_size}, H, W), "
                f"got {tuple(self.segmentation.shape)}"
            )

    def __len__(self) -> int:
        return len(self.batch_index)

    @classmethod
    def from_arrays(cls, images: Sequence[tuple[Any, Any, Any, Any, Any]]) -> GroundTruthBatch:
        """Collate per-image ground truth into one flat batch.

        Args:
            images: per image ``(R (N,3,3), t (N,3) metres, visibility (N,), instance_id (N,),
                segmentation (H,W) | None)``, numpy arrays or tensors.
        """
        segs = [img[4] for img in images]
        if any(s is None for s in segs) and not all(s is None for s in segs):
            raise ValueError(
                "GroundTruthBatch.from_arrays: segmentation must be given for every image "
                "or for none"
            )
        counts = [len(img[1]) for img in images]

        def cat(k: int, dtype: torch.dtype, tail: tuple[int, ...]) -> torch.Tensor:
            parts = [
                torch.as_tensor(np.asarray(img[k])).to(dtype).reshape((-1,) + tail)
                for img in images
            ]
            return torch.cat(parts) if parts else torch.zeros((0,) + tail, dtype=dtype)

        return cls(
            batch_index=torch.repeat_interleave(
                torch.arange(len(images)), torch.tensor(counts, dtype=torch.long)
            ),
            R_cam_obj=cat(0, torch.float32, (3, 3)),
            t_cam_obj=cat(1, torch.float32, (3,)),
            visibility=cat(2, torch.float32, ()),
            instance_id=cat(3, torch.long, ()),
            batch_size=len(images),
            segmentation=None
            if not segs or segs[0] is None
            else torch.stack([torch.as_tensor(np.asarray(s)).long() for s in segs]),
        )

    def to(self, device: torch.device | str) -> GroundTruthBatch:
        """The same batch on another device."""
        seg = None if self.segmentation is None else self.segmentation.to(device)
        return GroundTruthBatch(
            self.batch_index.to(device),
            self.R_cam_obj.to(device),
            self.t_cam_obj.to(device),
            self.visibility.to(device),
            self.instance_id.to(device),
            self.batch_size,
            seg,
        )


__all__ = ["POSE_CHANNEL_NAMES", "ChannelLayout", "GroundTruthBatch"]
