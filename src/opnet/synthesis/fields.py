"""How a settings dataclass declares its fields: a scene setting's group and roles (:func:`_setting`), and
building a dataclass from a mapping whose unknown keys are an error (:func:`from_known_keys`)."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

#: the groups of scene settings (a field's ``group``): what a user measures for a real cell apart from the
#: generator's internals (docs/extending.md#a-scene-setting)
SETTING_GROUPS = {
    "cell": "measured for a real cell: the camera file and its pose, the working volume, the working area, the bin",
    "camera": "the built-in camera, the rendered pixels and the views per pile",
    "randomization": "per-cycle jitters of the camera and the bin, foreign pieces",
    "bin": "the automatic bin and the bins a cell swaps",
    "physics": "the physics engine, collision shapes, contacts and when a pile is at rest",
    "rendering": "caches of the renderer",
    "sizing": "how the lengths follow the part's diameter",
}


def _setting(default: Any, group: str, *, later: bool = False, rig: bool = False, part: bool = False,
             bin_model: bool = False) -> Any:
    """A :class:`SceneConfig` field declared once, with what the rest of the code needs to know of it.

    group: one of :data:`SETTING_GROUPS`.
    later: added after the first datasets were made: left out of :meth:`SceneConfig.to_dict` at its default,
        so the ``generation.json`` of those datasets still matches (every new field sets it).
    rig: a length of the camera rig, scaled by D / ``rig_d`` (:meth:`SceneConfig.for_part`).
    part: a length set for parts of ``small_part_d`` and more, scaled down for a smaller part.
    bin_model: a key each entry of ``bin_models`` may set."""
    if group not in SETTING_GROUPS:
        raise ValueError(f"scene setting group {group!r}: expected one of {list(SETTING_GROUPS)}")
    return dataclasses.field(default=default, metadata={"group": group, "later": later, "rig": rig, "part": part,
                                                        "bin_model": bin_model})

def from_known_keys(cls: type, values: Mapping[str, Any] | None, section: str) -> Any:
    """``cls(**values)`` for a dataclass; keys that are not its fields are an error naming ``section``."""
    values = dict(values or {})
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ValueError(f"{section}: unknown keys {unknown}; expected some of {sorted(known)}")
    return cls(**values)


def _number(value: Any) -> bool:
    """A finite int or float (not a boolean)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _numbers(value: Any, n: int) -> tuple[float, ...] | None:
    """``value`` as a tuple of ``n`` floats when it is a sequence of ``n`` finite numbers, else None."""
    if value is None or isinstance(value, (str, bytes)):
        return None
    try:
        items = list(value)
    except TypeError:
        return None
    if len(items) != n or not all(_number(v) for v in items):
        return None
    return tuple(float(v) for v in items)


__all__ = ["SETTING_GROUPS", "_number", "_numbers", "_setting", "from_known_keys"]
