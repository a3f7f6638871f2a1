"""The opnet metadata of an exported ONNX file, checked like a checkpoint's config before any use.

Every field the runtime reads is typed and bounded here (booleans are not numbers, numbers are
finite, names come from their closed sets); a bad value raises a one-line ``ValueError`` naming
the file and the key (``<file>: opnet metadata decoding.threshold = nan, expected ...``) and never
quotes more than a short repr of the value.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from opnet._repr import short_repr
from opnet.data.preprocess import CANVAS_FITS
from opnet.data.roi import parse_roi
from opnet.geometry.camera import parse_clip
from opnet.geometry.symmetry import MAX_GROUP_SIZE, symmetry_from_rotations
from opnet.parameterizations.averaging import CLUSTER_SCORES

MAX_ICP_POINTS = 20_000  # points of the ICP model cloud in the metadata
REQUIRED = ("parameterization", "grid_size", "slots", "channels_per_slot", "input", "decoding", "pose_space", "outputs")
SCORES = ("p", "p*v", "v")
INTERPOLATIONS = ("area",)
MAX_INPUT_SIZE = 4096
MAX_GRID = 1024
MAX_SLOTS = 64


class _Fields:
    """Typed reads of one metadata mapping; errors name ``<file>: opnet metadata <key>``."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def fail(self, key: str, value: Any, expected: str) -> ValueError:
        return ValueError(f"{self.path}: opnet metadata {key} = {short_repr(value)}, expected {expected}")

    def mapping(self, parent: dict[str, Any], key: str, prefix: str = "") -> dict[str, Any]:
        value = self.get(parent, key, prefix)
        if not isinstance(value, dict):
            raise self.fail(prefix + key, value, "a mapping")
        return value

    def get(self, parent: dict[str, Any], key: str, prefix: str = "") -> Any:
        if key not in parent:
            raise ValueError(f"{self.path}: opnet metadata lacks {prefix}{key}; export it again with python export.py")
        return parent[key]

    def number(self, parent: dict[str, Any], key: str, low: float, high: float, prefix: str = "",
               high_open: bool = False, low_open: bool = False) -> float:
        value = self.get(parent, key, prefix)
        ok = isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
        ok = ok and (value > low if low_open else value >= low) and (value < high if high_open else value <= high)
        if not ok:
            raise self.fail(prefix + key, value, f"a number in {'(' if low_open else '['}{low:g}, {high:g}"
                                                 f"{')' if high_open else ']'}")
        return float(value)

    def integer(self, parent: dict[str, Any], key: str, low: int, high: int, prefix: str = "") -> int:
        value = self.get(parent, key, prefix)
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise self.fail(prefix + key, value, f"a whole number in [{low}, {high}]")
        return int(value)

    def choice(self, parent: dict[str, Any], key: str, choices: tuple[str, ...], prefix: str = "",
               default: str | None = None) -> str:
        value = parent.get(key, default) if default is not None else self.get(parent, key, prefix)
        if not isinstance(value, str) or value not in choices:
            raise self.fail(prefix + key, value, f"one of {', '.join(choices)}")
        return value

    def flag(self, parent: dict[str, Any], key: str, prefix: str = "", default: bool | None = None) -> bool:
        value = parent.get(key, default) if default is not None else self.get(parent, key, prefix)
        if not isinstance(value, bool):
            raise self.fail(prefix + key, value, "true or false")
        return value

    def array(self, parent: dict[str, Any], key: str, shape: tuple[int, ...], prefix: str = "",
              max_size: int = 100_000) -> np.ndarray:
        value = self.get(parent, key, prefix)
        try:
            if isinstance(value, list) and len(value) > max_size:
                raise ValueError
            arr = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError, OverflowError):
            raise self.fail(prefix + key, value, f"numbers of shape {shape}") from None
        if arr.dtype == bool or arr.size > max_size * 9 or not np.isfinite(arr).all():
            raise self.fail(prefix + key, value, f"finite numbers of shape {shape}")
        try:
            return arr.reshape(shape)
        except ValueError:
            raise self.fail(prefix + key, value, f"numbers of shape {shape}") from None


def validate_metadata(meta: Any, path: str | Path) -> dict[str, Any]:
    """The typed decoding settings of ONNX metadata ``meta`` read from ``path``.

    Returns:
        ``{"grid_size", "slots", "channels_per_slot", "input_size", "fit", "interpolation",
        "threshold", "score", "min_visibility", "averaging" (None or eps, min_samples,
        cluster_score, keep_noise), "pose_space" (Lambda, group, delta, revolution, lam),
        "icp_model" (None or points, normals, diameter), "trained_clip" (None or (near, far))}``.
    Raises:
        ValueError: ``<path>: opnet metadata <key> = <value>, expected <what>`` for the first bad field.
    """
    f = _Fields(Path(path))
    if not isinstance(meta, dict):
        raise ValueError(f"{f.path}: opnet metadata is a {type(meta).__name__}, expected a JSON object")
    missing = [k for k in REQUIRED if k not in meta]
    if missing:
        raise ValueError(f"{f.path}: opnet metadata lacks {missing}; export it again with python export.py")
    if not isinstance(meta["parameterization"], str):
        raise f.fail("parameterization", meta["parameterization"], "a parameterization name")
    name = meta.get("object", "")
    if not isinstance(name, str) or len(name) > 200:
        raise f.fail("object", name, "an object name")
    outputs = meta["outputs"]
    if not isinstance(outputs, list) or not all(isinstance(o, str) for o in outputs) or len(outputs) > 16:
        raise f.fail("outputs", outputs, "a list of output names")
    out: dict[str, Any] = {
        "grid_size": f.integer(meta, "grid_size", 1, MAX_GRID),
        "slots": f.integer(meta, "slots", 1, MAX_SLOTS),
        "channels_per_slot": f.integer(meta, "channels_per_slot", 1, 1024),
    }
    inp = f.mapping(meta, "input")
    out["input_size"] = f.integer(inp, "size", 8, MAX_INPUT_SIZE, "input.")
    out["fit"] = f.choice(inp, "fit", CANVAS_FITS, "input.", default="pad")
    out["interpolation"] = f.choice(inp, "interpolation", INTERPOLATIONS, "input.", default="area")
    try:
        out["roi"] = parse_roi(inp.get("roi"), "input.roi")
    except ValueError as e:
        raise ValueError(f"{f.path}: opnet metadata {e}") from None
    dec = f.mapping(meta, "decoding")
    out["threshold"] = f.number(dec, "threshold", 0.0, 1.0, "decoding.", high_open=True)
    out["score"] = f.choice(dec, "score", SCORES, "decoding.")
    out["min_visibility"] = f.number(dec, "min_visibility", 0.0, 1.0, "decoding.", high_open=True)
    avg = dec.get("averaging")
    if avg is not None:
        if not isinstance(avg, dict):
            raise f.fail("decoding.averaging", avg, "null or a mapping")
        avg = {"eps": f.number(avg, "eps", 0.0, 100.0, "decoding.averaging.", low_open=True),
               "min_samples": f.integer(avg, "min_samples", 1, 10_000, "decoding.averaging."),
               "cluster_score": f.choice(avg, "cluster_score", CLUSTER_SCORES, "decoding.averaging."),
               "keep_noise": f.flag(avg, "keep_noise", "decoding.averaging.", default=False)}
    out["averaging"] = avg
    ps = f.mapping(meta, "pose_space")
    group = f.array(ps, "group", (-1, 3, 3), "pose_space.", max_size=8 * MAX_GROUP_SIZE)
    try:
        symmetry_from_rotations(group)  # proper rotations, a group, within the size cap
    except ValueError as e:
        raise ValueError(f"{f.path}: opnet metadata pose_space.group: {e}") from None
    icp = meta.get("icp_model")
    if icp is not None:
        if not isinstance(icp, dict):
            raise f.fail("icp_model", icp, "null or a mapping")
        points = f.array(icp, "points", (-1, 3), "icp_model.", max_size=MAX_ICP_POINTS)
        normals = f.array(icp, "normals", (-1, 3), "icp_model.", max_size=MAX_ICP_POINTS)
        if len(points) != len(normals) or not len(points):
            raise f.fail("icp_model.normals", f"{len(normals)} normals", f"one per point ({len(points)})")
        icp = {"points": points, "normals": normals,
               "diameter": f.number(icp, "diameter", 0.0, 1000.0, "icp_model.", low_open=True)}
    out["icp_model"] = icp
    try:
        out["trained_clip"] = parse_clip(meta.get("trained_clip"), "trained_clip")  # absent: exported before
    except ValueError as e:
        raise ValueError(f"{f.path}: opnet metadata {e}") from None
    out["pose_space"] = {
        "Lambda": f.array(ps, "Lambda", (3, 3), "pose_space."),
        "group": group,
        "delta": f.number(ps, "delta", 0.0, 100.0, "pose_space.", low_open=True),
        "revolution": f.flag(ps, "revolution", "pose_space."),
        "lam": f.number(ps, "lam", 0.0, 100.0, "pose_space."),
    }
    return out
