"""Random ground-truth scenes for tests, benchmarks and ceiling studies (no renderer needed).

Objects get uniformly random rotations and origins spread over (and a little beyond) the image
between the clip planes. Each object is painted as a disc of its projected radius, nearer objects
on top, which gives a consistent instance segmentation and visibility (visible disc pixels / full
disc area). A stand-in for real renders, good enough to exercise every assignment rule.
"""

from __future__ import annotations

import math

import torch

from opnet.geometry.camera import Camera
from opnet.geometry.rotations import quaternion_to_matrix
from opnet.objects.model import ObjectModel
from opnet.parameterizations.base import GroundTruthBatch


def random_rotations(n: int, generator: torch.Generator) -> torch.Tensor:
    """(n, 3, 3) float64 rotations, uniform on SO(3)."""
    q = torch.randn(n, 4, generator=generator, dtype=torch.float64)
    return quaternion_to_matrix(q)


def random_scene_batch(
    obj: ObjectModel,
    camera: Camera,
    batch_size: int,
    num_objects: int | tuple[int, int],
    generator: torch.Generator,
    overhang: float = 0.1,
    depth_margin: float = 0.05,
    disc_scale: float = 0.35,
) -> GroundTruthBatch:
    """A batch of random scenes with segmentation at the camera's resolution.

    Args:
        obj: the object (its diameter sizes the discs).
        camera: the network-input camera (e.g. 128 x 128).
        batch_size: number of images B.
        num_objects: objects per image, or a (low, high) inclusive range drawn per image.
        generator: torch random generator (deterministic scenes).
        overhang: origins are drawn up to this fraction of the image size beyond its borders.
        depth_margin: metres kept free near each clip plane.
        disc_scale: disc radius as a fraction of the object diameter.
    Returns:
        ground truth, camera frame, metres; visibility from the painted discs.
    """
    lo, hi = (num_objects, num_objects) if isinstance(num_objects, int) else num_objects
    counts = torch.randint(lo, hi + 1, (batch_size,), generator=generator)
    M = int(counts.sum())
    batch_index = torch.repeat_interleave(torch.arange(batch_size), counts)
    u = (
        torch.rand(M, generator=generator, dtype=torch.float64) * (1 + 2 * overhang) - overhang
    ) * camera.width - 0.5
    v = (
        torch.rand(M, generator=generator, dtype=torch.float64) * (1 + 2 * overhang) - overhang
    ) * camera.height - 0.5
    near, far = camera.clip_start + depth_margin, camera.clip_end - depth_margin
    depth = near + torch.rand(M, generator=generator, dtype=torch.float64) * (far - near)
    t = torch.stack(
        ((u - camera.cx) * depth / camera.fx, (v - camera.cy) * depth / camera.fy, depth), -1
    )
    radius = camera.fx * disc_scale * obj.diameter / depth  # (M,) pixels
    instance_id = (
        torch.arange(M) - torch.repeat_interleave(torch.cumsum(counts, 0) - counts, counts) + 1
    )  # 1-based per image
    segmentation, visibility = _paint_discs(
        camera, batch_size, batch_index, instance_id, u, v, depth, radius
    )
    return GroundTruthBatch(
        batch_index=batch_index,
        R_cam_obj=random_rotations(M, generator).float(),
        t_cam_obj=t.float(),
        visibility=visibility.float(),
        instance_id=instance_id,
        batch_size=batch_size,
        segmentation=segmentation,
    )


def _paint_discs(
    camera: Camera,
    batch_size: int,
    batch_index: torch.Tensor,
    instance_id: torch.Tensor,
    u: torch.Tensor,
    v: torch.Tensor,
    depth: torch.Tensor,
    radius: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Z-buffer discs: (B, H, W) long instance ids (0 = background), (M,) visibility."""
    H, W = camera.height, camera.width
    rows = torch.arange(H, dtype=torch.float64)[None, :, None]
    cols = torch.arange(W, dtype=torch.float64)[None, None, :]
    covers = (cols - u[:, None, None]) ** 2 + (rows - v[:, None, None]) ** 2 <= radius[
        :, None, None
    ] ** 2  # (M, H, W)
    zbuf = torch.where(
        covers, depth[:, None, None], torch.full_like(depth[:, None, None], math.inf)
    )
    per_image = batch_index[:, None, None].expand(len(u), H, W)
    nearest = torch.full((batch_size, H, W), math.inf, dtype=torch.float64).scatter_reduce(
        0, per_image, zbuf, "amin"
    )
    visible = covers & (zbuf <= nearest[batch_index])  # (M, H, W)
    ids = visible.long() * instance_id[:, None, None]  # (M, H, W)
    segmentation = torch.zeros(batch_size, H, W, dtype=torch.long).scatter_reduce(
        0, per_image, ids, "amax"
    )
    visibility = visible.sum((1, 2)).double() / (math.pi * radius**2).clamp_min(1.0)
    return segmentation, visibility.clamp(0.0, 1.0)
