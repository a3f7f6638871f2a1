"""The network-input preprocessing of :func:`opnet.data.preprocess.to_network_input` as torch
operations on any device (``inference.device_side``, docs/deployment.md "Device-side inference").

The same steps, in the same order and float32 arithmetic: the square canvas of the framing rule
(outside the image: missing depth), depth outside the clip planes held at the plane it crosses,
OpenCV's ``INTER_AREA`` resize of the zero-filled depth and of its validity (normalized convolution,
an output pixel less than half valid is missing), normalization between the clip planes, the fill
of missing depth (linear along rows and columns, weighted by the inverse gap) over the input pixels
that show the image, the padding replicated from the filled border, and the clip to [0, 1].

The resize is OpenCV's own: :func:`area_taps` reproduces its table of source pixels and weights
(``computeResizeAreaTab`` when shrinking, the linear taps of its area mode when enlarging), so the
result equals ``cv2.resize(..., INTER_AREA)`` up to float32 summation order (1e-7). Images of a
batch share one camera (one frame size); the canvas padding is never materialized: taps that fall
outside the image are dropped, which is what multiplying zeros did.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import torch

from opnet.data.preprocess import (
    _MIN_VALID_WEIGHT,
    _check_matches_camera,
    _image_window,
    check_depth,
    square_canvas,
)
from opnet.geometry import Camera

#: on the CPU the full-resolution steps take images in chunks of about this many pixels (cache-sized)
CPU_CHUNK_PIXELS = 1 << 19


@functools.lru_cache(maxsize=64)
def area_taps(source: int, size: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """OpenCV's ``INTER_AREA`` resize of a line of ``source`` pixels to ``size`` as taps:
    (output pixel, source pixel, float32 weight), each (T,), in OpenCV's order.

    Shrinking (``source >= size``): each output pixel averages the source pixels its cell covers,
    partial pixels by their covered share (shares under 1e-3 dropped, as OpenCV does). Enlarging:
    OpenCV's area mode interpolates linearly between two neighbours with its own fractions.
    """
    if source < 1 or size < 1:
        raise ValueError(f"area_taps: source={source}, size={size}, expected positive sides")
    dst: list[int] = []
    src: list[int] = []
    weight: list[float] = []

    def tap(d: int, s: int, w: float) -> None:
        dst.append(d)
        src.append(s)
        weight.append(w)

    scale = source / size
    if scale >= 1:
        for dx in range(size):
            f1 = dx * scale
            f2 = f1 + scale
            cell = min(scale, source - f1)
            s2 = min(math.floor(f2), source - 1)
            s1 = min(math.ceil(f1), s2)
            if s1 - f1 > 1e-3:
                tap(dx, s1 - 1, float(np.float32((s1 - f1) / cell)))
            for sx in range(s1, s2):
                tap(dx, sx, float(np.float32(1.0 / cell)))
            if f2 - s2 > 1e-3:
                tap(dx, s2, float(np.float32(min(min(f2 - s2, 1.0), cell) / cell)))
    else:
        inverse = size / source
        for dx in range(size):
            sx = math.floor(dx * scale)
            fx = np.float32((dx + 1) - (sx + 1) * inverse)
            fx = np.float32(0) if fx <= 0 else fx - np.float32(math.floor(fx))
            if sx >= source - 1:
                fx, sx = np.float32(0), source - 1
            tap(dx, sx, float(np.float32(1) - fx))
            if fx:
                tap(dx, sx + 1, float(fx))
    return np.asarray(dst, np.int64), np.asarray(src, np.int64), np.asarray(weight, np.float32)


@functools.lru_cache(maxsize=64)
def _line_table(side: int, size: int, offset: int, extent: int, device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """(size, K) indices into the image line ``[0, extent)`` and their weights, of the resize of the
    canvas line ``[offset, offset + side)`` to ``size`` (taps outside the image: weight 0)."""
    dst, src, weight = area_taps(side, size)
    src = src + offset  # canvas pixel -> image pixel
    inside = (src >= 0) & (src < extent)
    dst, src, weight = dst[inside], src[inside], weight[inside]
    count = np.bincount(dst, minlength=size)
    k = max(1, int(count.max(initial=0)))
    slot = np.arange(len(dst)) - np.repeat(np.cumsum(count) - count, count)
    index, weights = np.zeros((size, k), np.int64), np.zeros((size, k), np.float32)
    index[dst, slot], weights[dst, slot] = src, weight
    return torch.from_numpy(index).to(device), torch.from_numpy(weights).to(device)


def _resize_axis(x: torch.Tensor, table: tuple[torch.Tensor, torch.Tensor], dim: int) -> torch.Tensor:
    """Every line of ``x`` along ``dim`` (-2: columns, -1: rows) resized through a table, one
    weighted gather of whole lines per tap slot (no (..., size, K) temporary)."""
    index, weights = table
    shape = (-1, 1) if dim == -2 else (-1,)
    out = x.index_select(dim, index[:, 0]).mul_(weights[:, 0].reshape(shape))
    for k in range(1, index.shape[1]):
        out.addcmul_(x.index_select(dim, index[:, k]), weights[:, k].reshape(shape))
    return out


def area_resize(x: torch.Tensor, canvas: tuple[int, int, int], size: int) -> torch.Tensor:
    """``cv2.resize(c, (size, size), interpolation=cv2.INTER_AREA)`` of the canvas ``c``
    ``(x0, y0, side)`` cut from every (H, W) image of ``x`` (..., H, W) with zeros outside:
    (..., size, size). The columns are resized first (whole rows gathered: the full-resolution
    pass reads each pixel about once), then the rows of the ``size``-row result."""
    x0, y0, side = canvas
    height, width = x.shape[-2:]
    vertical = _resize_axis(x, _line_table(side, size, y0, height, x.device), -2)  # (..., size, W)
    return _resize_axis(vertical, _line_table(side, size, x0, width, x.device), -1)


def _line_estimates(img: torch.Tensor, valid: torch.Tensor, dim: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Every pixel's estimate along image axis ``dim`` (-1: rows, -2: columns) with its two-sided
    and one-sided weights: :func:`opnet.data.preprocess._line_estimates` for all pixels at once."""
    n = img.shape[dim]
    shape = [1] * img.dim()
    shape[dim] = n
    pos = torch.arange(n, device=img.device).reshape(shape)
    before = torch.where(valid, pos, -1).cummax(dim).values  # nearest valid pixel before (-1: none)
    after = torch.where(valid, pos, n).flip(dim).cummin(dim).values.flip(dim)  # and after (n: none)
    has_b, has_a = before >= 0, after < n
    b = torch.where(has_b, before, after).clamp(0, n - 1)  # one-sided: both ends on the neighbour
    a = torch.where(has_a, after, b)
    v_b, v_a = img.gather(dim, b), img.gather(dim, a)
    span = (a - b).clamp_min(1).to(img.dtype)
    est = torch.where(has_b | has_a, v_b + (pos - b).to(img.dtype) / span * (v_a - v_b), 0.0)
    two_sided = (has_b & has_a) / span
    one_sided = (has_b ^ has_a) * (0.5 / (pos - b).abs().clamp_min(1).to(img.dtype))
    return est, two_sided, one_sided


def _blend(estimates: tuple[torch.Tensor, torch.Tensor], weights: tuple[torch.Tensor, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    total = weights[0] + weights[1]
    return (estimates[0] * weights[0] + estimates[1] * weights[1]) / total.clamp_min(1e-12), total > 0


def fill_missing_depth(images: torch.Tensor, fill_value: float, static: bool = False) -> torch.Tensor:
    """:func:`opnet.data.preprocess.fill_missing_depth` of every (H, W) image of ``images``
    (..., H, W) float32, NaN = missing; an image without any valid pixel becomes ``fill_value``.

    The numpy version fills only the missing pixels, in at most two passes (after the first, every
    row and column through a valid pixel is full); here each pass computes every pixel's estimate
    and keeps those of the missing ones. A pass is skipped when nothing is missing (one device sync),
    unless ``static``: then both passes run (they change nothing where nothing is missing) and no
    value is read back, so the fill can be captured in a CUDA graph.
    """
    valid = ~torch.isnan(images)
    out = torch.where(valid, images, 0.0)
    for _ in range(2):
        if not static and bool(valid.all()):
            return out
        row_est, row_two, row_one = _line_estimates(out, valid, -1)
        col_est, col_two, col_one = _line_estimates(out, valid, -2)
        two, has_two = _blend((row_est, col_est), (row_two, col_two))
        one, has_one = _blend((row_est, col_est), (row_one, col_one))
        done = (has_two | has_one) & ~valid
        out = torch.where(done, torch.where(has_two, two, one), out)
        valid = valid | done
    return torch.where(valid, out, fill_value)  # images without any valid pixel


def _resized_depth(batch: torch.Tensor, camera: Camera, canvas: tuple[int, int, int], size: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The resized depth (missing pixels as 0, the clip planes applied) and the resized validity."""
    weight = (batch > 0).to(torch.float32)  # NaN and z <= 0 are missing
    values = torch.where(weight > 0, batch.clamp(camera.clip_start, camera.clip_end), 0.0)
    return area_resize(values, canvas, size), area_resize(weight, canvas, size)


def as_depth_batch(depth: np.ndarray | torch.Tensor | list[np.ndarray], device: torch.device | str,
                   static: bool = False) -> torch.Tensor:  # fmt: skip
    """(B, H, W) float32 depth on ``device`` from one (H, W) image, a list of them or a (B, H, W)
    array or tensor; numpy images are validated as :func:`opnet.data.preprocess.check_depth` does,
    tensors too unless ``static`` (no value read back: the caller checks for infinite depth)."""
    if isinstance(depth, torch.Tensor):
        if depth.dim() not in (2, 3) or not depth.is_floating_point() or depth.numel() == 0:
            raise ValueError(f"depth: expected a non-empty (H, W) or (B, H, W) float tensor, got "
                             f"{tuple(depth.shape)} {depth.dtype}")
        if not static and bool(torch.isinf(depth).any()):
            raise ValueError("depth: contains infinite values; use NaN for missing depth")
        batch = depth if depth.dim() == 3 else depth[None]
        return batch.to(device=device, dtype=torch.float32)
    images = [depth] if isinstance(depth, np.ndarray) and depth.ndim == 2 else list(depth)
    for image in images:
        check_depth(image)
    stacked = np.stack([np.asarray(image, np.float32) for image in images])
    return torch.from_numpy(stacked).to(device)


def to_network_input(
    depth: np.ndarray | torch.Tensor | list[np.ndarray],
    camera: Camera,
    size: int = 128,
    fit: str = "pad",
    canvas: tuple[int, int, int] | None = None,
    device: torch.device | str | None = None,
    static: bool = False,
) -> tuple[torch.Tensor, Camera]:
    """:func:`opnet.data.preprocess.to_network_input` (``INTER_AREA``) of images of one camera, on
    ``device`` (default: the depth tensor's, else the CPU).

    Args:
        depth: (H, W) or (B, H, W) depth in metres (NaN or z <= 0 = missing), numpy or a tensor, or
            a list of (H, W) numpy images; (H, W) must match ``camera``.
        camera, size, fit, canvas: as :func:`opnet.data.preprocess.to_network_input`.
        static: read no value back (a tensor's infinite depth is not refused: the caller checks),
            so that the preprocessing can be captured in a CUDA graph.
    Returns:
        ``(images, camera_in)``: (B, 1, size, size) float32 normalized depth in [0, 1] on the device,
        and the camera of the network input.
    Raises:
        ValueError: as the numpy version, for a bad image or a shape that does not match ``camera``.
    """
    if size < 1:
        raise ValueError(f"to_network_input: size={size}, expected a positive input side")
    if device is None:
        device = depth.device if isinstance(depth, torch.Tensor) else "cpu"
    batch = as_depth_batch(depth, device, static)
    _check_matches_camera(batch[0], camera, "depth")
    x0, y0, side = canvas if canvas is not None else square_canvas(camera, fit)
    # on the CPU a few images at a time, so that the full-resolution temporaries stay in the caches
    step = len(batch) if batch.device.type != "cpu" else max(1, CPU_CHUNK_PIXELS // batch[0].numel())
    parts = [_resized_depth(batch[i : i + step], camera, (x0, y0, side), size) for i in range(0, len(batch), step)]
    values, weight = (torch.cat(p) for p in zip(*parts, strict=True)) if len(parts) > 1 else parts[0]
    keep = weight >= _MIN_VALID_WEIGHT
    depth_in = torch.where(keep, values / torch.where(keep, weight, 1.0), torch.nan)
    normalized = (depth_in - camera.clip_start) / (camera.clip_end - camera.clip_start)
    rows, cols = _image_window(camera, x0, y0, side, size)
    if rows.start >= rows.stop or cols.start >= cols.stop:
        image = fill_missing_depth(normalized, 1.0, static)
    else:  # the padding is all missing: replicating the filled border is what the fill would do
        inner = fill_missing_depth(normalized[:, rows, cols], 1.0, static)
        borders = (cols.start, size - cols.stop, rows.start, size - rows.stop)
        image = inner if not any(borders) else torch.nn.functional.pad(inner[:, None], borders, mode="replicate")[:, 0]
    return image.clamp(0.0, 1.0)[:, None], camera.cropped(x0, y0, side, side).resized(size, size)
