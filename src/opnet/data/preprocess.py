"""Network input preprocessing of a depth image (docs/method.md#network-input, paper "Setup" and "Sim-to-Real").

Pipeline of :func:`to_network_input`: square canvas centred on the principal point -> NaN-aware
resize to ``size x size`` -> fill of missing depth (linear between valid pixels) -> normalization
between the clip planes, clipped to [0, 1]. The returned :class:`Camera` is the camera of the
network input, so that projecting a 3D point with it lands on the same content.

Square canvas rule **[decision]**: the canvas is centred on the principal point, so OP-Net's volume
elements are symmetric about the optical axis whatever the crop (IPA images are crops of a square
``resolution_big`` canvas centred on it; Siléane principal points are far off-centre, e.g.
cu = 139.5 in a 506 px wide image). ``fit="pad"`` (default) takes the smallest such square that
contains the whole image (no depth is lost; for an IPA crop it is not necessarily the full
``resolution_big`` canvas), padding with missing depth; ``fit="crop"`` takes the largest such
square inside the image. The canvas origin is rounded to whole pixels (no resampling), so its
centre is within half a pixel of the principal point; the returned camera is exact regardless.

Framing (``data.fit``, the same for training, evaluation, predict.py and the ONNX export): for
an off-centre principal point the centred square wastes input. ``fit="image"`` takes the square
centred on the *image* (side = the longer image side: only the short side is padded) and
``fit="image_crop"`` the centred square of the shorter side (the long side is cut); the input
camera's principal point is then off-centre, which the decoding handles (it back-projects with
the input camera). ``scripts/experiments/framing/framing_table.py`` measures the input pixels each uses and the AP:
on a Siléane-like camera ``image`` scored 0.78 against 0.61 for ``pad``, so the configs default to
``image`` (identical canvases for centred principal points); the functions here keep ``pad`` as
their default, the framing of checkpoints trained before ``data.fit`` existed.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from opnet.geometry import Camera
from opnet.settings_schema import check_value

RESIZE_INTERPOLATIONS: dict[str, int] = {
    "nearest": cv2.INTER_NEAREST,
    "linear": cv2.INTER_LINEAR,
    "area": cv2.INTER_AREA,
    "cubic": cv2.INTER_CUBIC,
    "lanczos4": cv2.INTER_LANCZOS4,
    "nearest-exact": cv2.INTER_NEAREST_EXACT,
    "linear-exact": cv2.INTER_LINEAR_EXACT,
}
"""The OpenCV resize options drawn at random during training (paper "Sim-to-Real")."""

# A resized pixel is valid when at least this fraction of its (interpolation-weighted) support is.
_MIN_VALID_WEIGHT = 0.5


def check_depth(depth: np.ndarray, name: str = "depth") -> None:
    """Validate a depth image: (H, W) floating point, NaN = missing, no infinity.

    Raises:
        ValueError: naming ``name`` and what was expected.
    """
    if not isinstance(depth, np.ndarray):
        raise ValueError(f"{name}: expected a numpy array, got {type(depth).__name__}")  # noqa: TRY004
    if depth.ndim != 2:
        raise ValueError(f"{name}: expected an (H, W) image, got shape {depth.shape}")
    if depth.size == 0:
        raise ValueError(f"{name}: expected a non-empty image, got shape {depth.shape}")
    if not np.issubdtype(depth.dtype, np.floating):
        raise ValueError(f"{name}: expected a float dtype (NaN = missing), got {depth.dtype}")
    if np.isinf(depth).any():
        raise ValueError(f"{name}: contains infinite values; use NaN for missing depth")


def _check_matches_camera(image: np.ndarray, camera: Camera, name: str) -> None:
    if image.shape != (camera.height, camera.width):
        raise ValueError(
            f"{name}: shape {image.shape} does not match the camera's (height, width) = "
            f"{(camera.height, camera.width)}"
        )


def _line_estimates(
    img: np.ndarray, valid: np.ndarray, rows: np.ndarray, cols: np.ndarray, axis: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Estimates at the missing pixels ``(rows, cols)`` along image ``axis`` (1: rows, 0: columns).

    Returns ``(estimate, two_sided, one_sided)``, each (M,) float32: the linear interpolation
    between the nearest valid pixels before and after (held constant where only one side has
    one); the weight ``1 / span`` where both sides exist (else 0); the weight
    ``1 / (2·distance)`` where only one side exists (else 0). Written without Python loops and
    with few ``np.where`` (the fill must stay well under 2 ms at 128 x 128).
    """
    n, w = img.shape[axis], img.shape[1]
    pos = np.arange(n, dtype=np.int32)
    pos = pos if axis == 1 else pos[:, None]
    flat = rows * w + cols
    # index of the nearest valid pixel before (-1: none) and after (n: none), for every pixel
    before = np.maximum.accumulate((pos + 1) * valid - 1, axis=axis).ravel()[flat]
    after = np.flip(np.minimum.accumulate(np.flip((pos - n) * valid + n, axis), axis=axis), axis)
    after = after.ravel()[flat]
    p = cols if axis == 1 else rows
    has_b, has_a = before >= 0, after < n
    any_side = has_b | has_a
    b = np.clip(np.where(has_b, before, after), 0, n - 1)  # one-sided: both ends on the neighbour
    a = np.where(has_a, after, b)
    stride = 1 if axis == 1 else w
    base = flat - p * stride
    values = img.ravel()
    v_b, v_a = values[base + b * stride], values[base + a * stride]
    span = np.maximum(a - b, 1).astype(np.float32)
    est = np.where(any_side, v_b + (p - b).astype(np.float32) / span * (v_a - v_b), np.float32(0))
    two_sided = (has_b & has_a) / span
    one_sided = (has_b ^ has_a) * (np.float32(0.5) / np.maximum(np.abs(p - b), 1))
    return est, two_sided.astype(np.float32), one_sided.astype(np.float32)


def _blend(
    estimates: tuple[np.ndarray, np.ndarray], weights: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    total = weights[0] + weights[1]
    value = (estimates[0] * weights[0] + estimates[1] * weights[1]) / np.maximum(total, 1e-12)
    return value, total > 0


def fill_missing_depth(depth: np.ndarray, fill_value: float | None = None) -> np.ndarray:
    """Fill NaN pixels by linear interpolation between valid pixels (docs/method.md#network-input, "bilinear").

    Each missing pixel gets the average of the linear interpolations along its row and along its
    column between the nearest valid pixels on both sides, weighted by the inverse distance between
    those two pixels (the shorter, more local gap dominates). Only where neither the row nor the
    column brackets the pixel (holes touching the border) is the nearest valid value held constant.
    A plane with holes that don't touch the border is reproduced exactly. Pixels whose row and
    column hold no valid pixel at all are filled by a second pass over the first one's result.

    Args:
        depth: (H, W) float image, any unit (metres or normalized), NaN = missing.
        fill_value: value of an image without any valid pixel (e.g. the far clip plane).

    Returns:
        (H, W) float32 without NaN; valid pixels are unchanged.

    Raises:
        ValueError: for a non-float / non-2D / infinite input, or an all-NaN image without
            ``fill_value``.
    """
    check_depth(depth)
    out = depth.astype(np.float32, copy=True)
    valid = ~np.isnan(out)
    if valid.all():
        return out
    if not valid.any():
        if fill_value is None:
            raise ValueError("depth: every pixel is missing (NaN) and no fill_value was given")
        out.fill(fill_value)
        return out
    # At most two passes: after the first, every row and column through a valid pixel is full.
    while not valid.all():
        rows, cols = np.nonzero(~valid)
        row_est, row_two, row_one = _line_estimates(out, valid, rows, cols, axis=1)
        col_est, col_two, col_one = _line_estimates(out, valid, rows, cols, axis=0)
        two, has_two = _blend((row_est, col_est), (row_two, col_two))
        one, has_one = _blend((row_est, col_est), (row_one, col_one))
        done = has_two | has_one
        out[rows[done], cols[done]] = np.where(has_two, two, one)[done]
        valid[rows[done], cols[done]] = True
    return out


def square_canvas(camera: Camera, fit: str = "pad") -> tuple[int, int, int]:
    """The square canvas of a framing rule, as ``(x0, y0, side)`` in input pixels: centred on the
    principal point (``pad``, ``crop``) or on the image (``image``, ``image_crop``; module doc).

    The canvas covers input pixels ``[y0:y0+side, x0:x0+side]``; negative ``x0``/``y0`` or an
    extent beyond the image mean padding.

    Raises:
        ValueError: for an unknown ``fit``, or ``fit="crop"`` with the principal point outside
            the image.
    """
    check_value("fit", fit)
    if fit in ("image", "image_crop"):  # centred on the image, not on the principal point
        W, H = camera.width, camera.height
        side = max(W, H) if fit == "image" else min(W, H)
        return (W - side) // 2, (H - side) // 2, side
    # Edge coordinates: the image spans [0, W] x [0, H], the principal point lies at c + 0.5.
    ex, ey = camera.cx + 0.5, camera.cy + 0.5
    reach = (ex, camera.width - ex, ey, camera.height - ey)
    if fit == "pad":
        side = math.ceil(2.0 * max(reach) - 1e-9)
    else:
        side = math.floor(2.0 * min(reach) + 1e-9)
        if side < 1:
            raise ValueError(
                f"square canvas: principal point ({camera.cx}, {camera.cy}) is outside the "
                f"{camera.width}x{camera.height} image, fit='crop' is impossible"
            )
    return round(ex - side / 2.0), round(ey - side / 2.0), side


def framing_coverage(camera: Camera, fit: str = "pad") -> tuple[float, float]:
    """(share of the network input that shows image pixels, share of the image that reaches the
    input) of a framing rule: what ``fit`` wastes (padding) and what it loses (cropping)."""
    x0, y0, side = square_canvas(camera, fit)
    w = max(0, min(x0 + side, camera.width) - max(x0, 0))
    h = max(0, min(y0 + side, camera.height) - max(y0, 0))
    return w * h / side**2, w * h / (camera.width * camera.height)


def _overlap(
    x0: int, y0: int, side: int, height: int, width: int
) -> tuple[tuple[slice, slice], tuple[slice, slice]] | None:
    """Where the image and the canvas overlap: (canvas slices, image slices), None if nowhere."""
    sx0, sy0 = max(x0, 0), max(y0, 0)
    sx1, sy1 = min(x0 + side, width), min(y0 + side, height)
    if sx1 <= sx0 or sy1 <= sy0:
        return None
    return (slice(sy0 - y0, sy1 - y0), slice(sx0 - x0, sx1 - x0)), (
        slice(sy0, sy1),
        slice(sx0, sx1),
    )


def _canvas(image: np.ndarray, x0: int, y0: int, side: int) -> np.ndarray:
    """``image[y0:y0+side, x0:x0+side]`` with out-of-image pixels set to 0."""
    out = np.zeros((side, side), dtype=image.dtype)
    overlap = _overlap(x0, y0, side, *image.shape)
    if overlap is not None:
        out[overlap[0]] = image[overlap[1]]
    return out


def _depth_canvas(depth: np.ndarray, x0: int, y0: int, side: int) -> tuple[np.ndarray, np.ndarray]:
    """Zero-padded (side, side) float32 canvases of the depth (missing -> 0) and of its validity.

    Written straight into the canvases (two passes over the image, no temporaries): at a
    Siléane-sized image this is most of the preprocessing time.
    """
    values = np.zeros((side, side), np.float32)
    weight = np.zeros((side, side), np.float32)
    overlap = _overlap(x0, y0, side, *depth.shape)
    if overlap is not None:
        region = depth[overlap[1]]
        np.fmax(region, 0.0, out=values[overlap[0]])  # fmax drops NaN: missing -> 0
        np.greater(region, 0.0, out=weight[overlap[0]])  # NaN and z <= 0 are missing
    return values, weight


def _resize_weighted(
    values: np.ndarray, weight: np.ndarray, size: int, interpolation: int
) -> np.ndarray:
    """Normalized-convolution resize: resize ``values·weight`` (given as ``values`` with missing
    pixels at 0) and the 0/1 ``weight``, divide; output pixels with weight < 0.5 are NaN."""
    values = cv2.resize(values, (size, size), interpolation=interpolation)
    weight = cv2.resize(weight, (size, size), interpolation=interpolation)
    keep = weight >= _MIN_VALID_WEIGHT
    return np.where(keep, values / np.where(keep, weight, 1.0), np.nan).astype(np.float32)


def resize_depth(depth: np.ndarray, size: int, interpolation: int = cv2.INTER_AREA) -> np.ndarray:
    """NaN-aware resize of an (H, W) depth image to (size, size) float32 (NaN = missing).

    Missing pixels are resized as a validity mask alongside the zero-filled depth, and the result is
    renormalized by the resized mask (normalized convolution), so missing pixels don't smear into
    valid ones. An output pixel whose support is less than half valid is missing.
    """
    check_depth(depth)
    valid = ~np.isnan(depth)
    if valid.all():
        return cv2.resize(depth.astype(np.float32), (size, size), interpolation=interpolation)
    values = np.where(valid, depth, 0.0).astype(np.float32)
    return _resize_weighted(values, valid.astype(np.float32), size, interpolation)


def to_network_input(
    depth: np.ndarray,
    camera: Camera,
    size: int = 128,
    interpolation: int = cv2.INTER_AREA,
    fit: str = "pad",
    canvas: tuple[int, int, int] | None = None,
) -> tuple[np.ndarray, Camera]:
    """Turn a depth image into the network input and its camera (docs/method.md#network-input).

    Args:
        depth: (H, W) float depth in metres, camera frame z, NaN (or z <= 0) = missing; (H, W)
            must match ``camera``.
        camera: the camera of ``depth`` (clip planes define the normalization).
        size: side of the square network input (128 in the paper).
        interpolation: OpenCV resize flag, e.g. a value of :data:`RESIZE_INTERPOLATIONS`.
        fit: square canvas rule, one of :data:`opnet.settings_schema.CANVAS_FITS` (see :func:`square_canvas`).
        canvas: ``(x0, y0, side)`` to use instead of the rule (e.g. a random zoom window of the
            training augmentation; its centre need not be the principal point).

    Returns:
        ``(image, camera_in)``: image (size, size) float32 normalized depth in [0, 1], no NaN (an
        image without valid depth is all 1, the far plane); ``camera_in`` the camera of that image.
        Depth outside the clip planes counts as the plane it crosses (before the resize's
        average). Missing pixels inside the image are filled with :func:`fill_missing_depth`; the padding
        (input pixels whose centre lies outside the image) holds no depth at all, and is filled
        by replicating the filled image's border, which is what the fill's constant
        extrapolation gives, at a fraction of the cost.

    Raises:
        ValueError: for a non-float, non-2D or infinite ``depth``, or a shape that does not match
            ``camera``.
    """
    check_depth(depth)
    if size < 1:
        raise ValueError(f"to_network_input: size={size}, expected a positive input side")
    _check_matches_camera(depth, camera, "depth")
    x0, y0, side = canvas if canvas is not None else square_canvas(camera, fit)
    values, weight = _depth_canvas(depth, x0, y0, side)
    # depth outside the working volume counts as the plane it crosses *before* the area average:
    # a real frame's ground 0.5 m past the far plane would otherwise outweigh the bin floor it is
    # averaged with (generated depth holds it at the plane: scene.outside_clip=clamp)
    np.clip(values, camera.clip_start, camera.clip_end, out=values, where=weight > 0)
    normalized = camera.normalize_depth(_resize_weighted(values, weight, size, interpolation))
    rows, cols = _image_window(camera, x0, y0, side, size)
    if rows.start >= rows.stop or cols.start >= cols.stop:
        image = fill_missing_depth(normalized, fill_value=1.0)
    else:  # the padding is all missing: replicating the filled border is what the fill would do
        inner = fill_missing_depth(normalized[rows, cols], fill_value=1.0)
        borders = (rows.start, size - rows.stop, cols.start, size - cols.stop)
        image = cv2.copyMakeBorder(inner, *borders, cv2.BORDER_REPLICATE)
    return np.clip(image, 0.0, 1.0), camera.cropped(x0, y0, side, side).resized(size, size)


def network_camera(camera: Camera, size: int = 128, fit: str = "pad") -> Camera:
    """The camera of the (size, size) network input of :func:`to_network_input`, without the image."""
    x0, y0, side = square_canvas(camera, fit)
    return camera.cropped(x0, y0, side, side).resized(size, size)


def _image_window(camera: Camera, x0: int, y0: int, side: int, size: int) -> tuple[slice, slice]:
    """Rows and columns of the (size, size) input whose pixel centres lie inside the image."""
    scale = side / size

    def span(offset: int, extent: int) -> slice:
        # canvas edge coordinates: the image spans [-offset, extent - offset)
        lo = math.ceil(-offset / scale - 0.5)
        hi = math.ceil((extent - offset) / scale - 0.5)
        return slice(max(lo, 0), min(hi, size))

    return span(y0, camera.height), span(x0, camera.width)


def resize_segmentation(
    segmentation: np.ndarray,
    camera: Camera,
    size: int,
    fit: str = "pad",
    canvas: tuple[int, int, int] | None = None,
) -> np.ndarray:
    """Instance segmentation through the same canvas as :func:`to_network_input`, nearest resize.

    Args:
        segmentation: (H, W) integer instance ids, 0 = background, matching ``camera``.
        camera: the camera of the image.
        size: output side (e.g. 32 for the SI grid, 128 for the network input).
        fit: square canvas rule (see :func:`square_canvas`).
        canvas: ``(x0, y0, side)`` instead of the rule (as in :func:`to_network_input`).

    Returns:
        (size, size) array of the input's integer dtype; padding is background (0). Each output
        pixel takes the input pixel under its centre (pixel-centre aligned, as ``Camera.resized``).
    """
    if not isinstance(segmentation, np.ndarray) or segmentation.ndim != 2:
        raise ValueError(
            f"segmentation: expected an (H, W) numpy array, got {getattr(segmentation, 'shape', type(segmentation))}"
        )
    if not np.issubdtype(segmentation.dtype, np.integer):
        raise ValueError(f"segmentation: expected an integer dtype, got {segmentation.dtype}")
    _check_matches_camera(segmentation, camera, "segmentation")
    x0, y0, side = canvas if canvas is not None else square_canvas(camera, fit)
    canvas = _canvas(segmentation, x0, y0, side)
    index = np.minimum(((np.arange(size) + 0.5) * side / size).astype(np.int64), side - 1)
    return canvas[np.ix_(index, index)]
