"""Quarter turns of the network input: the decoding's ``turns`` (docs/method.md#decoding).

The square network input turned by a quarter turn (``np.rot90`` / ``torch.rot90`` with ``k = 1`` over
the last two axes: pixel ``(u, v)`` of an ``S x S`` input moves to ``(v, S - 1 - u)``, pixel centres at
integers) is exactly what another pinhole camera sees: the camera turned about its optical axis, every
point ``X`` seen at ``X' = Q X`` with ``Q = [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]``, and the intrinsics
``fx' = fy``, ``fy' = fx``, ``cx' = cy``, ``cy' = S - 1 - cx``. Depth along the optical axis is unchanged,
so the turned input is a depth image the network may see (training turns its scenes the same way when
``augmentation.p_rotate`` is on). A pose decoded from it in the turned camera, ``R'``, ``t'``, is ``R = Q^T
R'``, ``t = Q^T t'`` in the image's own camera: every pixel maps onto a pixel, so nothing is resampled.

``turns`` 2 pools the hypotheses of the image and of its half turn, ``turns`` 4 those of its four quarter
turns, before the pose averaging clusters and averages them: each pose the network gives is averaged with
the ones it gives for the same part seen turned. numpy only (:mod:`opnet.deploy` runs without PyTorch).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from opnet.settings_schema import TURNS

#: one quarter turn of the camera frame: ``X' = Q X`` for the input turned by ``rot90(k=1)``
QUARTER = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def quarters(turns: int) -> tuple[int, ...]:
    """The quarter turns (0-3) of the input that ``turns`` pools: 1 -> (0,), 2 -> (0, 2), 4 -> (0, 1, 2, 3)."""
    if turns not in TURNS:
        raise ValueError(f"turns={turns!r}: expected one of {', '.join(map(str, TURNS))}")
    return tuple(range(0, 4, 4 // turns))


def turn_matrix(q: int) -> np.ndarray:
    """(3, 3) float64 ``Q^q``: camera-frame points of the input turned by ``q`` quarter turns."""
    return np.linalg.matrix_power(QUARTER, q % 4)


def turned_camera(camera: Any, q: int) -> Any:
    """The pinhole camera that sees the input of ``camera`` turned by ``q`` quarter turns (module docstring)."""
    for _ in range(q % 4):
        camera = dataclasses.replace(camera, fx=camera.fy, fy=camera.fx, cx=camera.cy, cy=camera.width - 1 - camera.cx,
                                     width=camera.height, height=camera.width)  # fmt: skip
    return camera


def turned_back(R: Any, t: Any, q: int) -> tuple[Any, Any]:
    """Poses ``R`` (N, 3, 3), ``t`` (N, 3) decoded in the camera turned by ``q`` quarter turns, in the
    image's own camera (numpy arrays or torch tensors, returned as the same type)."""
    Q = turn_matrix(q)
    if isinstance(R, np.ndarray):
        return Q.T @ R, t @ Q
    import torch

    Qt = torch.as_tensor(Q, dtype=R.dtype, device=R.device)
    return Qt.T @ R, t @ Qt


__all__ = ["QUARTER", "quarters", "turn_matrix", "turned_back", "turned_camera"]
