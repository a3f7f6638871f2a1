"""Position channels: per-image cameras as tensors, cell-relative and enlarged-image positions.

Pixel coordinates follow :class:`opnet.geometry.Camera` (pixel centres at integers, so the image
spans ``[-0.5, W - 0.5]``). An ``S x S`` grid splits that span evenly; the continuous grid
coordinate of a pixel ``u`` is ``s = (u + 0.5) S / W``, its cell ``floor(s)`` and its sub-cell
offset ``s - floor(s)`` (docs/method.md#the-six-parameterizations, vanilla / Z / MP). Variants that assign an object to
several cells (EVE, AP, SI) regress the origin relative to the image enlarged by the object
diameter projected at the near clip plane, ``m = fx D / clip_start``: ``x = (u + m) / (W + 2m)``,
likewise for ``y`` (with fy).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import torch

from opnet.geometry.camera import Camera

_FIELDS = ("fx", "fy", "cx", "cy", "width", "height", "clip_start", "clip_end")

#: (slot, row, col) of decoded cells, each (N,) long
CellIndex = tuple[torch.Tensor, torch.Tensor, torch.Tensor]
#: (u, v) pixels and normalized depth of decoded origins, each (N,) float64
DecodedPosition = tuple[torch.Tensor, torch.Tensor, torch.Tensor]


@dataclass(frozen=True)
class CameraBatch:
    """Cameras of a batch (or of gathered elements) as one tensor.

    Attributes:
        params: (N, 8) float64, columns fx, fy, cx, cy, width, height, clip_start, clip_end.
    """

    params: torch.Tensor

    @classmethod
    def of(
        cls, camera: Camera | Sequence[Camera], batch_size: int, device: torch.device | str = "cpu"
    ) -> CameraBatch:
        """One camera for the whole batch, or one per image (network-input resolution)."""
        if isinstance(camera, Camera):
            row = torch.tensor(
                [[getattr(camera, f) for f in _FIELDS]], dtype=torch.float64, device=device
            )
            return cls(row.expand(batch_size, len(_FIELDS)))
        cams = list(camera)
        if len(cams) != batch_size:
            raise ValueError(f"camera: got {len(cams)} cameras for a batch of {batch_size} images")
        rows = [[getattr(c, f) for f in _FIELDS] for c in cams]
        return cls(
            torch.tensor(rows, dtype=torch.float64, device=device).reshape(batch_size, len(_FIELDS))
        )

    def take(self, index: torch.Tensor) -> CameraBatch:
        """The cameras of elements with batch index ``index`` (N,) long."""
        return CameraBatch(self.params[index])

    @property
    def width(self) -> torch.Tensor:
        """(N,) float64 image width in pixels."""
        return self.params[:, 4]

    @property
    def height(self) -> torch.Tensor:
        """(N,) float64 image height in pixels."""
        return self.params[:, 5]

    def project(self, points: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Camera-frame points (N, 3) metres, one per camera row -> u, v (N,) pixels, depth (N,)."""
        p = self.params
        z = points[:, 2]
        return p[:, 0] * points[:, 0] / z + p[:, 2], p[:, 1] * points[:, 1] / z + p[:, 3], z

    def backproject(self, u: torch.Tensor, v: torch.Tensor, depth: torch.Tensor) -> torch.Tensor:
        """Pixels u, v (N,) and z-depth (N,) metres -> camera-frame points (N, 3) metres."""
        p = self.params
        return torch.stack(
            ((u - p[:, 2]) * depth / p[:, 0], (v - p[:, 3]) * depth / p[:, 1], depth), -1
        )

    def normalize_depth(self, depth: torch.Tensor) -> torch.Tensor:
        """Depth (N,) metres -> (z - clip_start) / (clip_end - clip_start)."""
        return (depth - self.params[:, 6]) / (self.params[:, 7] - self.params[:, 6])

    def denormalize_depth(self, z: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`normalize_depth`."""
        return self.params[:, 6] + z * (self.params[:, 7] - self.params[:, 6])

    def margins(self, diameter: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Enlargement margins (N,) in pixels: the diameter (metres) seen at the near clip plane."""
        p = self.params
        return p[:, 0] * diameter / p[:, 6], p[:, 1] * diameter / p[:, 6]


@dataclass(frozen=True)
class CellPosition:
    """Where pixels fall on an ``S x S`` grid.

    Attributes:
        row, col: (N,) long cell indices (may lie outside the grid; see ``inside``).
        x, y: (N,) float64 sub-cell offsets in [0, 1).
        inside: (N,) bool, the pixel lies inside the image.
    """

    row: torch.Tensor
    col: torch.Tensor
    x: torch.Tensor
    y: torch.Tensor
    inside: torch.Tensor


def cell_position(u: torch.Tensor, v: torch.Tensor, cams: CameraBatch, grid: int) -> CellPosition:
    """Pixels u, v (N,) of images with cameras ``cams`` (N rows) -> cells of a grid x grid grid."""
    s_u = (u + 0.5) * grid / cams.width
    s_v = (v + 0.5) * grid / cams.height
    col_f, row_f = torch.floor(s_u), torch.floor(s_v)
    inside = (s_u >= 0) & (s_u < grid) & (s_v >= 0) & (s_v < grid)
    return CellPosition(row_f.long(), col_f.long(), s_u - col_f, s_v - row_f, inside)


def cell_pixel(
    row: torch.Tensor,
    col: torch.Tensor,
    x: torch.Tensor,
    y: torch.Tensor,
    cams: CameraBatch,
    grid: int,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Inverse of :func:`cell_position`: cells and offsets (N,) -> pixels u, v (N,)."""
    return (col + x) * cams.width / grid - 0.5, (row + y) * cams.height / grid - 0.5


def enlarged_position(
    u: torch.Tensor, v: torch.Tensor, cams: CameraBatch, diameter: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixels u, v (N,) -> x, y (N,) relative to the image enlarged by the projected diameter."""
    m_u, m_v = cams.margins(diameter)
    return (u + m_u) / (cams.width + 2 * m_u), (v + m_v) / (cams.height + 2 * m_v)


def enlarged_pixel(
    x: torch.Tensor, y: torch.Tensor, cams: CameraBatch, diameter: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Inverse of :func:`enlarged_position`."""
    m_u, m_v = cams.margins(diameter)
    return x * (cams.width + 2 * m_u) - m_u, y * (cams.height + 2 * m_v) - m_v


def in_unit_interval(*values: torch.Tensor) -> torch.Tensor:
    """(N,) bool: every value lies in [0, 1] (what a sigmoid output channel can represent)."""
    ok = torch.ones_like(values[0], dtype=torch.bool)
    for val in values:
        ok &= (val >= 0) & (val <= 1)
    return ok


@dataclass(frozen=True)
class ObjectProjection:
    """Ground-truth origins seen by their image's camera.

    Attributes:
        u, v: (M,) float64 pixel coordinates of the origin (network-input resolution).
        depth: (M,) float64 z-depth of the origin, metres.
        z_norm: (M,) float64 depth normalized between the clip planes.
        cams: the camera of each instance (M rows).
        in_range: (M,) bool, the origin lies between the clip planes.
    """

    u: torch.Tensor
    v: torch.Tensor
    depth: torch.Tensor
    z_norm: torch.Tensor
    cams: CameraBatch
    in_range: torch.Tensor

    def cells(self, grid: int) -> CellPosition:
        """Cells of the origins on a ``grid x grid`` grid."""
        return cell_position(self.u, self.v, self.cams, grid)

    def enlarged(self, diameter: float) -> tuple[torch.Tensor, torch.Tensor]:
        """Enlarged-image position channels (M, 3) = (x, y, z_norm) and (M,) bool: representable."""
        x, y = enlarged_position(self.u, self.v, self.cams, diameter)
        return torch.stack((x, y, self.z_norm), -1), self.in_range & in_unit_interval(x, y)


def project_origins(
    t_cam_obj: torch.Tensor, batch_index: torch.Tensor, cams: CameraBatch
) -> ObjectProjection:
    """Project origins (M, 3) metres, camera frame, of images ``batch_index`` (M,)."""
    per_object = cams.take(batch_index)
    points = t_cam_obj.to(torch.float64)
    u, v, depth = per_object.project(points)
    z_norm = per_object.normalize_depth(depth)
    in_range = (depth > 0) & in_unit_interval(z_norm)
    return ObjectProjection(u, v, depth, z_norm, per_object, in_range)


class CellRelativePosition:
    """Mixin of parameterizations whose x, y channels are sub-cell offsets (vanilla, MP).

    The z channel is the origin depth normalized between the clip planes.
    """

    grid_size: int

    def decode_position(
        self, position: torch.Tensor, cells: CellIndex, cams: CameraBatch
    ) -> DecodedPosition:
        """Position channels (N, 3) of cells -> u, v (N,) pixels, normalized depth (N,)."""
        _, row, col = cells
        u, v = cell_pixel(row, col, position[:, 0], position[:, 1], cams, self.grid_size)
        return u, v, position[:, 2]


POSITION_MODES = ("enlarged", "cell_offset")


def offset_margins(cams: CameraBatch, diameter: float, grid: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Half ranges (N,) in pixels of the ``cell_offset`` position channels: the diameter seen at
    the near clip plane, and at least two cells."""
    m_u, m_v = cams.margins(diameter)
    return torch.maximum(m_u, 2 * cams.width / grid), torch.maximum(m_v, 2 * cams.height / grid)


def cell_offset_position(
    u: torch.Tensor, v: torch.Tensor, row: torch.Tensor, col: torch.Tensor, cams: CameraBatch, grid: int,
    diameter: float,
) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """Pixels u, v (N,) seen from cells (row, col) (N,) -> x, y (N,): ``0.5 + offset / (2 M)``
    with the offset from the cell centre and M of :func:`offset_margins`."""
    u_c, v_c = cell_pixel(row, col, 0.5, 0.5, cams, grid)
    m_u, m_v = offset_margins(cams, diameter, grid)
    return 0.5 + (u - u_c) / (2 * m_u), 0.5 + (v - v_c) / (2 * m_v)


def cell_offset_pixel(
    x: torch.Tensor, y: torch.Tensor, row: torch.Tensor, col: torch.Tensor, cams: CameraBatch, grid: int,
    diameter: float,
) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """Inverse of :func:`cell_offset_position`."""
    u_c, v_c = cell_pixel(row, col, 0.5, 0.5, cams, grid)
    m_u, m_v = offset_margins(cams, diameter, grid)
    return u_c + (x - 0.5) * 2 * m_u, v_c + (y - 0.5) * 2 * m_v


class MultiCellPosition:
    """Mixin of parameterizations that assign an object to several cells (EVE, AP, SI).

    Two ways to write the origin into the x, y channels of a cell (``position``):

    - ``enlarged`` (the paper): relative to the image enlarged by the object diameter projected
      at the near clip plane, ``x = (u + m) / (W + 2m)``. Every cell of an object holds the same
      values, absolute image coordinates, which a fully convolutional network (translation
      equivariant) can only produce from the zero padding at the borders: slow to learn.
    - ``cell_offset``: relative to the centre of the cell, ``x = 0.5 + (u - u_cell) / (2 M)``
      with ``M`` the projected diameter (at least two cells), so the channels say where the
      origin lies *from here*, as vanilla's sub-cell offsets do, and still reach origins outside
      the cell and outside the image.

    The z channel is the origin depth normalized between the clip planes in both.
    """

    obj: Any  # ObjectModel: only its diameter is used
    grid_size: int
    position_mode: str = "enlarged"

    def _set_position_mode(self, position: str) -> None:
        if position not in POSITION_MODES:
            raise ValueError(f"parameterization.position must be one of {POSITION_MODES}, got {position!r}")
        self.position_mode = position

    def _candidate_positions(
        self, proj: ObjectProjection, index: torch.Tensor, row: torch.Tensor, col: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Position channels (K, 3) of instances ``index`` (K,) in cells (row, col) (K,), and (K,)
        bool: representable (channels in [0, 1], origin between the clip planes)."""
        if self.position_mode == "enlarged":
            position, ok = proj.enlarged(self.obj.diameter)
            return position[index], ok[index]
        cams = proj.cams.take(index)
        x, y = cell_offset_position(proj.u[index], proj.v[index], row, col, cams, self.grid_size, self.obj.diameter)
        ok = proj.in_range[index] & in_unit_interval(x, y)
        return torch.stack((x, y, proj.z_norm[index]), -1), ok

    def decode_position(
        self, position: torch.Tensor, cells: CellIndex, cams: CameraBatch
    ) -> DecodedPosition:
        """Position channels (N, 3) -> u (N,), v (N,) pixels, normalized depth (N,)."""
        if self.position_mode == "enlarged":
            u, v = enlarged_pixel(position[:, 0], position[:, 1], cams, self.obj.diameter)
        else:
            _, row, col = cells
            u, v = cell_offset_pixel(position[:, 0], position[:, 1], row, col, cams, self.grid_size, self.obj.diameter)
        return u, v, position[:, 2]
