"""Exact in-plane rotation of a scene: the camera turned about its optical axis, labels with it.

A camera turned by ``theta`` about its optical axis sees every point ``p`` at ``p' = Q p`` with
``Q = [[c, -s, 0], [s, c, 0], [0, 0, 1]]``: the depth ``z`` of every ray is unchanged, and the
image moves by the affine map ``u' = A (u - m) + m'`` with ``A = S Q2 S^-1``, ``S = diag(fx, fy)``
(non-square pixels make ``A`` a rotation of the normalized image, a shear of the pixel one).
The image is turned about its own centre ``m`` (pixel centres at integers), so the content
stays in view; the principal point moves with it to ``c' = A (c - m) + m``, which is again a
pinhole camera with the same focal lengths — the scene is *exactly* what that camera would
see. Positions are regressed in pixels and normalized depth from each sample's own camera, so
nothing the network is taught depends on the principal point.

Labels: ``R' = Q R``, ``t' = Q t``. Depth and segmentation are resampled with nearest neighbours
(depth is never blended across an edge; a rotation by 0 or 180 degrees is an exact pixel
permutation), pixels from outside the image are missing depth. A part that leaves the image
loses visibility: ``visibility' = visibility x (visible pixels after / before)``, counted in the
segmentation, so scenes without a segmentation (real frames) can only be turned by 0 or 180
degrees.
"""

from __future__ import annotations

import dataclasses
import math

import cv2
import numpy as np

from opnet.datasets.record import SceneRecord

#: angles (degrees) that map the image onto itself pixel for pixel
EXACT_TURNS = (0.0, 180.0)


def exact_without_segmentation(low: float, high: float) -> bool:
    """Whether every turn drawn from ``[low, high]`` degrees maps the image onto itself pixel for
    pixel (0 or 180 degrees), so scenes without a segmentation can take it."""
    return low == high and float(low) % 360.0 in EXACT_TURNS


def rotation_about_axis(theta: float) -> np.ndarray:
    """(3, 3) float64 ``Q``: the camera frame turned by ``theta`` radians about its optical axis."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def image_map(record: SceneRecord, theta: float) -> np.ndarray:
    """(2, 3) float64 affine map from source to turned pixels, ``u' = A (u - m) + m``."""
    cam = record.camera
    S = np.diag([cam.fx, cam.fy])
    A = S @ rotation_about_axis(theta)[:2, :2] @ np.linalg.inv(S)
    m = np.array([(cam.width - 1) / 2.0, (cam.height - 1) / 2.0])
    return np.hstack([A, (m - A @ m)[:, None]])


def rotate_record(record: SceneRecord, degrees: float) -> SceneRecord:
    """``record`` seen by its camera turned ``degrees`` about the optical axis (module docstring).

    Raises:
        ValueError: a turn other than 0 or 180 degrees of a scene without segmentation (its
            visibilities could not follow), naming the scene.
    """
    turn = float(degrees) % 360.0
    if turn == 0.0:
        return record
    if record.segmentation is None and turn not in EXACT_TURNS:
        raise ValueError(f"scene {record.name!r}: augmentation.rotate_deg turns by {turn:.1f} degrees, but the scene "
                         "has no segmentation to recount its parts' visibility; use rotate_deg: [180, 180] or p_rotate: 0")
    theta = math.radians(turn)
    M = image_map(record, theta)
    cam = record.camera
    size = (cam.width, cam.height)
    if turn == 180.0:  # exact: every pixel lands on a pixel
        depth = record.depth[::-1, ::-1].copy()
        seg = None if record.segmentation is None else record.segmentation[::-1, ::-1].copy()
    else:
        depth = cv2.warpAffine(record.depth.astype(np.float32), M, size, flags=cv2.INTER_NEAREST,
                               borderMode=cv2.BORDER_CONSTANT, borderValue=float("nan"))
        seg = cv2.warpAffine(record.segmentation.astype(np.int32), M, size, flags=cv2.INTER_NEAREST,
                             borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    c_new = M[:, :2] @ np.array([cam.cx, cam.cy]) + M[:, 2]
    camera = dataclasses.replace(cam, cx=float(c_new[0]), cy=float(c_new[1]))
    Q = rotation_about_axis(theta)
    visibility = np.asarray(record.visibility, dtype=np.float64)
    if seg is not None and turn != 180.0 and len(visibility):
        visibility = visibility * _kept_fraction(record.segmentation, seg, record.instance_id)
    return dataclasses.replace(
        record, depth=depth, camera=camera, segmentation=seg, R_cam_obj=Q @ record.R_cam_obj,
        t_cam_obj=record.t_cam_obj @ Q.T, visibility=np.clip(visibility, 0.0, 1.0),
    )


def _kept_fraction(seg_before: np.ndarray, seg_after: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """(N,) visible pixels after / before of each instance (1 where none were visible)."""
    top = int(max(seg_before.max(initial=0), seg_after.max(initial=0), np.max(ids, initial=0))) + 1
    before = np.bincount(seg_before.ravel().clip(0), minlength=top)[np.asarray(ids, dtype=np.int64)]
    after = np.bincount(seg_after.ravel().clip(0), minlength=top)[np.asarray(ids, dtype=np.int64)]
    return np.where(before > 0, after / np.maximum(before, 1), 1.0)
