"""The working volume of the generated scenes: the one setting ``scene.clip``.

``clip`` says where the near and far clip planes come from, in one value:

- ``null`` (the default): both derived from the bin and the part (:mod:`opnet.synthesis.layout`);
- ``camera``: both the camera file's (``scene.camera_file``; a real rig at a known ``camera_height``);
- ``[near, far]``: metres; an entry may instead be ``null`` (that plane derived) or ``camera`` (that plane the
  camera file's), but not one of each.

A dataset records the planes as it always did (``clip_start``, ``clip_end`` and, when the camera file's
planes were used, ``camera_file_clip: true`` in ``generation.json``): :func:`from_recorded` reads those keys
back into ``clip`` and :func:`to_recorded` writes them, so every dataset made before keeps matching its
settings.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from opnet.synthesis.fields import _number

CAMERA = "camera"
#: the keys a dataset's ``generation.json`` records the working volume with
RECORDED_KEYS = ("clip_start", "clip_end", "camera_file_clip")

Plane = float | str | None
EXPECTED = ("null (derived), camera, or [near, far] metres (an entry may be null: derived, or camera: the camera file's; "
            "not one of each)")


def parse_clip(value: Any, max_m: float) -> tuple[Plane, Plane]:
    """``value`` of ``scene.clip`` as ``(near, far)``, each a number of metres, None (derived) or
    :data:`CAMERA`; a ValueError naming ``scene config: clip`` and what it expects otherwise."""

    def bad(why: str = "") -> ValueError:
        return ValueError(f"scene config: clip={value!r}, expected {EXPECTED}{why}")

    if value is None:
        return None, None
    if isinstance(value, str):
        if value != CAMERA:
            raise bad()
        return CAMERA, CAMERA
    if not isinstance(value, Sequence) or len(value) != 2:  # a list, a tuple, a config's list
        raise bad()
    planes: list[Plane] = []
    for entry in value:
        if entry is None or entry == CAMERA:
            planes.append(entry)
        elif _number(entry) and entry > 0:
            if entry > max_m:
                raise bad(f": at most {max_m:g} metres (a bin-picking cell)")
            planes.append(float(entry))
        else:
            raise bad()
    if None in planes and CAMERA in planes:
        raise bad(": one plane derived and the other the camera file's")
    near, far = planes
    if isinstance(near, float) and isinstance(far, float) and not near < far:
        raise bad(": near below far")
    return near, far


def metres(plane: Plane) -> float | None:
    """A plane's metres, None where it is derived or the camera file's."""
    return plane if isinstance(plane, float) else None


def camera_planes(clip: tuple[Plane, Plane], camera: Any) -> tuple[float | None, float | None]:
    """``clip`` with each :data:`CAMERA` entry replaced by ``camera``'s plane (``clip_start`` / ``clip_end``): metres
    where the planes are given or the camera's, None where derived. ``camera`` may be None without such entries."""
    return (camera.clip_start if clip[0] == CAMERA else clip[0], camera.clip_end if clip[1] == CAMERA else clip[1])


def to_recorded(clip: tuple[Plane, Plane]) -> dict[str, Any]:
    """The keys a dataset records ``clip`` with (``camera_file_clip`` only when true, as every dataset made
    before it existed left it out)."""
    out: dict[str, Any] = {"clip_start": metres(clip[0]), "clip_end": metres(clip[1])}
    if CAMERA in clip:
        out["camera_file_clip"] = True
    return out


def from_recorded(values: Mapping[str, Any], section: str) -> dict[str, Any]:
    """``values`` with a dataset's recorded keys (:data:`RECORDED_KEYS`) read back into ``clip``; given
    beside ``clip`` they are an error naming ``section``."""
    recorded = [k for k in RECORDED_KEYS if k in values]
    if not recorded:
        return dict(values)
    if "clip" in values:
        raise ValueError(f"{section}: {', '.join(recorded)} and clip both given; the working volume is clip alone "
                         f"({EXPECTED})")
    out = {k: v for k, v in values.items() if k not in RECORDED_KEYS}
    camera = values.get("camera_file_clip", False)
    if not isinstance(camera, bool):
        raise ValueError(f"{section}: camera_file_clip={camera!r}, expected true or false")
    fill = CAMERA if camera else None
    out["clip"] = [fill if values.get(k) is None else values[k] for k in ("clip_start", "clip_end")]
    return out


def normal_recorded(scene: Mapping[str, Any], max_m: float) -> dict[str, Any]:
    """A dataset's recorded ``scene`` with its working volume in today's recorded form (``camera_file_clip``
    left out where both planes are metres: the camera file's were not used); as it is where unreadable."""
    try:
        clip = parse_clip(from_recorded(scene, "scene")["clip"], max_m)
    except (KeyError, TypeError, ValueError):
        return dict(scene)
    return {**{k: v for k, v in scene.items() if k not in RECORDED_KEYS}, **to_recorded(clip)}


__all__ = ["CAMERA", "RECORDED_KEYS", "camera_planes", "from_recorded", "metres", "normal_recorded", "parse_clip",
           "to_recorded"]
