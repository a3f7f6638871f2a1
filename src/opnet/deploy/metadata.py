"""The opnet metadata of an exported ONNX file, checked like a checkpoint's config before any use.

Every field the runtime reads is typed and bounded here; the values other sources set too (decoding,
framing, region of interest, ``trained_clip``) by the one schema (:mod:`opnet.settings_schema`,
under its :data:`~opnet.settings_schema.METADATA` keys), the rest with the schema's types. A bad
value raises a one-line ``SettingError`` naming the file and the key
(``<file>: opnet metadata decoding.threshold=nan: expected a number in [0, 1)``) and never quotes
more than a short repr of the value.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from opnet.geometry.frames import BASE_POSE_KEY
from opnet.geometry.symmetry import MAX_GROUP_SIZE, symmetry_from_rotations
from opnet.run_settings import DecodingSettings, InputSettings, RunSettings, check_format
from opnet.settings_schema import METADATA, Flag, Number, SettingError, Spec, Whole, read_settings

#: the exported graph's outputs, every cell's (:mod:`opnet.deploy.export`)
OUTPUTS = ("presence", "visibility", "translation", "rotation")
#: the output a network with a quality channel adds after :data:`OUTPUTS`
QUALITY_OUTPUT = "quality"
MAX_ICP_POINTS = 20_000  # points of the ICP model cloud in the metadata
REQUIRED = ("format", "parameterization", "grid_size", "slots", "channels_per_slot", "input", "decoding", "pose_space",
            "outputs")
#: every key an export writes (:func:`opnet.deploy.export.export_metadata`), and those of its mappings
KEYS = ("format", "opnet_version", "checkpoint", "object", "parameterization", "rotation", "grid_size", "slots",
        "slot_conditional", "channels_per_slot", "out_channels", "input", "camera_input", "trained_clip", "outputs",
        "decoding", "pose_space", "icp_model", "refine", BASE_POSE_KEY, "camera")
INPUT_KEYS = (*(k.removeprefix("input.") for k in METADATA.values() if k.startswith("input.")), "layout")
POSE_SPACE_KEYS = ("Lambda", "group", "delta", "revolution", "lam")
ICP_KEYS = ("points", "normals", "diameter", "rank_points", "rank_normals")
#: the settings an export always writes (the others have defaults: fit pad, interpolation area, no roi)
REQUIRED_SETTINGS = ("decoding.threshold", "decoding.score", "decoding.min_visibility", "input.size")
AVERAGING_REQUIRED = ("eps", "min_samples", "cluster_score")


class _Fields:
    """Typed reads of one metadata mapping; errors name ``<file>: opnet metadata <key>``."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.source = f"{path}: opnet metadata"

    def fail(self, key: str, value: Any, expected: str) -> SettingError:
        return SettingError(key, value, f"expected {expected}", self.source)

    def mapping(self, parent: dict[str, Any], key: str, prefix: str = "") -> dict[str, Any]:
        value = self.get(parent, key, prefix)
        if not isinstance(value, dict):
            raise self.fail(prefix + key, value, "a mapping")
        return value

    def get(self, parent: dict[str, Any], key: str, prefix: str = "") -> Any:
        if key not in parent:
            raise ValueError(f"{self.source} lacks {prefix}{key}; export it again with python export.py")
        return parent[key]

    def known(self, parent: dict[str, Any], keys: tuple[str, ...], prefix: str = "") -> None:
        """Every key of ``parent`` is one of ``keys`` (an edited or foreign file is refused, not half read)."""
        for key in parent:
            if key not in keys:
                raise SettingError(f"{prefix}{key}", parent[key], f"unknown key; expected some of {', '.join(keys)}",
                                   self.source)  # fmt: skip

    def value(self, parent: dict[str, Any], key: str, spec: Spec, prefix: str = "") -> Any:
        """``parent[key]`` as ``spec`` (a type of :mod:`opnet.settings_schema`) types it."""
        return spec.check(self.get(parent, key, prefix), prefix + key, self.source)

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
        ``{"grid_size", "slots", "slot_conditional", "channels_per_slot", "input_size", "fit", "interpolation",
        "threshold", "score", "min_visibility", "averaging" (None or eps, min_samples,
        cluster_score, keep_noise), "pose_space" (Lambda, group, delta, revolution, lam),
        "icp_model" (None or points, normals, diameter), "trained_clip" (None or (near, far)),
        "input" (:class:`~opnet.run_settings.InputSettings`), "decoding"
        (:class:`~opnet.run_settings.DecodingSettings`), "refine" (the recorded refinement's name or None),
        "T_base_cam" (the camera's pose in the robot's base frame, 4 x 4 rows, or None), "camera" (the
        training camera's values, :data:`~opnet.run_settings.CAMERA_KEYS`, or None)}``:
        the flat keys are those two's values.
    Raises:
        ValueError: ``<path>: opnet metadata <key>=<value>: expected <what>`` (a ``SettingError``) for the
        first bad field, ``<path>: opnet metadata lacks <key>; ...`` for a missing one.
    """
    f = _Fields(Path(path))
    if not isinstance(meta, dict):
        raise ValueError(f"{f.path}: opnet metadata is a {type(meta).__name__}, expected a JSON object")
    missing = [k for k in REQUIRED if k not in meta]
    if missing:
        raise ValueError(f"{f.path}: opnet metadata lacks {missing}; export it again with python export.py")
    check_format(meta["format"], f.source)
    f.known(meta, KEYS)
    if not isinstance(meta["parameterization"], str):
        raise f.fail("parameterization", meta["parameterization"], "a parameterization name")
    name = meta.get("object", "")
    if not isinstance(name, str) or len(name) > 200:
        raise f.fail("object", name, "an object name")
    outputs = meta["outputs"]
    if not isinstance(outputs, list) or not all(isinstance(o, str) for o in outputs) or len(outputs) > 16:
        raise f.fail("outputs", outputs, "a list of output names")
    dec = f.mapping(meta, "decoding")
    for key in REQUIRED_SETTINGS:
        section, _, leaf = key.partition(".")
        f.get(f.mapping(meta, section), leaf, section + ".")
    avg = dec.get("averaging")
    if avg is not None and not isinstance(avg, dict):
        raise f.fail("decoding.averaging", avg, "null or a mapping")
    for key in AVERAGING_REQUIRED if avg is not None else ():
        f.get(avg, key, "decoding.averaging.")
    f.known(f.mapping(meta, "input"), INPUT_KEYS, "input.")
    # every value the schema knows, in its order; no other decoding setting
    s = read_settings(meta, METADATA, f.source, closed=("decoding", "decoding.averaging"))
    framing = InputSettings.from_metadata(meta, f.source)  # absent trained_clip: exported before it was recorded
    decoding = DecodingSettings.from_metadata(meta, f.source)
    averaging = decoding.averaging
    out: dict[str, Any] = {
        "grid_size": s["grid"], "slots": s["slots"],
        # absent: exported before the key, when only MP's slots were conditional
        "slot_conditional": (f.value(meta, "slot_conditional", Flag()) if "slot_conditional" in meta
                             else meta["parameterization"] == "mp"),
        "channels_per_slot": f.value(meta, "channels_per_slot", Whole(1, 1024)),
        "input_size": framing.size, "fit": framing.fit, "interpolation": framing.interpolation, "roi": framing.roi,
        "threshold": decoding.threshold, "score": decoding.score, "min_visibility": decoding.min_visibility,
        "averaging": None if averaging is None else {"eps": averaging.eps, "min_samples": averaging.min_samples,
                                                     "cluster_score": averaging.cluster_score,
                                                     "keep_noise": averaging.keep_noise},
        "trained_clip": framing.trained_clip, "input": framing, "decoding": decoding,
        # absent: exported before the key (no refinement recorded)
        "refine": RunSettings.checked_refine(meta.get("refine"), "refine", f.source),
        # absent: no base pose recorded
        BASE_POSE_KEY: RunSettings.checked_base_pose(meta.get(BASE_POSE_KEY), BASE_POSE_KEY, f.source),
        "camera": RunSettings.checked_camera(meta.get("camera"), "camera", f.source),  # absent: none recorded
    }
    ps = f.mapping(meta, "pose_space")
    f.known(ps, POSE_SPACE_KEYS, "pose_space.")
    group = f.array(ps, "group", (-1, 3, 3), "pose_space.", max_size=8 * MAX_GROUP_SIZE)
    try:
        symmetry_from_rotations(group)  # proper rotations, a group, within the size cap
    except ValueError as e:
        raise ValueError(f"{f.path}: opnet metadata pose_space.group: {e}") from None
    icp = meta.get("icp_model")
    if icp is not None:
        if not isinstance(icp, dict):
            raise f.fail("icp_model", icp, "null or a mapping")
        f.known(icp, ICP_KEYS, "icp_model.")
        points = f.array(icp, "points", (-1, 3), "icp_model.", max_size=MAX_ICP_POINTS)
        normals = f.array(icp, "normals", (-1, 3), "icp_model.", max_size=MAX_ICP_POINTS)
        if len(points) != len(normals) or not len(points):
            raise f.fail("icp_model.normals", f"{len(normals)} normals", f"one per point ({len(points)})")
        rank: dict[str, Any] = {}
        if "rank_points" in icp or "rank_normals" in icp:  # the points the final agreements are measured on
            rank = {k: f.array(icp, k, (-1, 3), "icp_model.", max_size=MAX_ICP_POINTS)
                    for k in ("rank_points", "rank_normals")}  # fmt: skip
            if len(rank["rank_points"]) != len(rank["rank_normals"]) or not len(rank["rank_points"]):
                raise f.fail("icp_model.rank_normals", f"{len(rank['rank_normals'])} normals",
                             f"one per rank point ({len(rank['rank_points'])})")  # fmt: skip
        icp = {"points": points, "normals": normals,
               "diameter": f.value(icp, "diameter", Number(0.0, 1000.0, low_open=True), "icp_model."), **rank}
    out["icp_model"] = icp
    out["pose_space"] = {
        "Lambda": f.array(ps, "Lambda", (3, 3), "pose_space."),
        "group": group,
        "delta": f.value(ps, "delta", Number(0.0, 100.0, low_open=True), "pose_space."),
        "revolution": f.value(ps, "revolution", Flag(), "pose_space."),
        "lam": f.value(ps, "lam", Number(0.0, 100.0), "pose_space."),
    }
    return out
