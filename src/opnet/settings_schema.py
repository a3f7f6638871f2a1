"""One schema for the values a run takes from several sources (docs/reliability.md#one-schema-for-every-source).

The decoding settings, the framing, the region of interest and the training clip planes reach a run
from a YAML config, a checkpoint's saved config, eval.py / predict.py overrides and the metadata of
an ONNX export. Each value is declared once here (:data:`SETTINGS`: type, bounds, allowed values;
booleans are never numbers, NaN and inf never bounded numbers); each source spells the keys its own
way (:data:`TRAINING`, :data:`OVERRIDE`, :data:`METADATA`). :func:`check_settings` and
:func:`read_settings` check them and raise one :class:`SettingError`, one line that names the key
as the source spells it: ``[<source> ]<key>=<value>: <what was expected>``.

Standard library and numpy only: the torch-free ONNX runtime imports it.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from opnet._repr import short_repr

#: how an image becomes the square network input (:func:`opnet.data.preprocess.square_canvas`)
CANVAS_FITS = ("pad", "crop", "image", "image_crop")
def hypothesis_score(score: str, p: Any, v: Any, q: Any = None) -> Any:
    """A hypothesis' score (one of :data:`SCORES`) from the presence ``p``, visibility ``v`` and quality ``q``
    (arrays or tensors alike; ``q`` None where the network writes none)."""
    if score in QUALITY_SCORES and q is None:
        raise ValueError(f"score {score!r} needs the quality channel q, which this network does not write")
    return {"p": lambda: p, "p*v": lambda: p * v, "v": lambda: v, "p*q": lambda: p * q,
            "p*v*q": lambda: p * v * q}[score]()


#: a hypothesis' score: the presence p̂, p̂ v̂, or the visibility v̂; with a quality channel also p̂ q̂ and p̂ v̂ q̂
#: (q̂: the network's own estimate of how right the cell's orientation is, docs/method.md#orientation-quality)
SCORES = ("p", "p*v", "v", "p*q", "p*v*q")
#: the scores that read the quality channel (a network trained with ``parameterization.quality``)
QUALITY_SCORES = ("p*q", "p*v*q")
#: a cluster's score from its members' scores
CLUSTER_SCORES = ("max", "sum", "mean")
#: the input's quarter-turned copies the decoding may pool (:mod:`opnet.parameterizations.turns`)
TURNS = (1, 2, 4)
#: the decoding's settings of one value each, by their schema names (the averaging is a group of its own)
DECODING_SCALARS = ("threshold", "min_visibility", "score", "turns")
#: the resize the exported network's input is made with
INTERPOLATIONS = ("area",)
#: the largest network input side
MAX_INPUT_SIZE = 4096
#: clip planes beyond this are surely not metres (bin-picking cameras work at 0.2 .. 5 m)
MAX_CLIP_END_M = 50.0
#: ``auto`` region of interest: the bin found per image; ``auto:S`` a square of S metres on it
AUTO = "auto"
#: the largest side ``auto:S`` takes, metres
MAX_AUTO_SIDE = 20.0
#: the smallest side ``auto:S`` takes, metres (the image of a smaller square is checked against
#: :data:`MIN_BOX_SIDE` pixels where the bin is found, :mod:`opnet.data.bin_finder`)
MIN_AUTO_SIDE = 0.01
#: the smallest side of a fixed box, pixels (a smaller one holds less than a pixel per output cell of a 16-cell grid)
MIN_BOX_SIDE = 16

Box = tuple[int, int, int, int]


class SettingError(ValueError):
    """A value refused: ``[<source> ]<key>=<value>: <problem>``, one line.

    Attributes:
        key: the key as the source spells it; value: the value given; problem: what was expected;
        source: where it was read (``<file>: opnet metadata``, ``<file>: the checkpoint's config``), or "".
    """

    def __init__(self, key: str, value: Any, problem: str, source: str = "") -> None:
        self.key, self.value, self.problem, self.source = key, value, problem, source
        super().__init__(f"{source + ' ' if source else ''}{key}={short_repr(value)}: {problem}")


class Refused(Exception):
    """A spec's refusal of a value, ``problem`` saying what was expected (no key yet); ``shown``: the
    value to quote, where it is not the one given (a box read from text)."""

    def __init__(self, problem: str, shown: Any = None) -> None:
        super().__init__(problem)
        self.problem, self.shown = problem, shown


def is_real(value: Any) -> bool:
    """A real number (numpy's too) that is no boolean."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool | np.bool_)


def is_whole(value: Any) -> bool:
    """An integer (numpy's too) that is no boolean."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool | np.bool_)


class Spec:
    """The type and bounds of one value; :meth:`parse` returns it typed or raises :class:`Refused`."""

    def parse(self, value: Any) -> Any:
        raise NotImplementedError

    def check(self, value: Any, key: str, source: str = "") -> Any:
        """``value`` typed; :class:`SettingError` naming ``key`` (and ``source``) otherwise."""
        try:
            return self.parse(value)
        except Refused as r:
            raise SettingError(key, value if r.shown is None else r.shown, r.problem, source) from None


@dataclass(frozen=True)
class Number(Spec):
    """A finite real number in an interval (open or closed at each end)."""

    low: float
    high: float
    low_open: bool = False
    high_open: bool = False
    what: str = "a number"

    def parse(self, value: Any) -> float:
        ok = is_real(value) and math.isfinite(value)
        ok = ok and (value > self.low if self.low_open else value >= self.low)
        if not (ok and (value < self.high if self.high_open else value <= self.high)):
            interval = f"{'(' if self.low_open else '['}{self.low:g}, {self.high:g}{')' if self.high_open else ']'}"
            raise Refused(f"expected {self.what} in {interval}")
        return float(value)


@dataclass(frozen=True)
class Whole(Spec):
    """A whole number in ``[low, high]``."""

    low: int
    high: int
    what: str = "a whole number"

    def parse(self, value: Any) -> int:
        if not (is_whole(value) and self.low <= value <= self.high):
            raise Refused(f"expected {self.what} in [{self.low}, {self.high}]")
        return int(value)


@dataclass(frozen=True)
class Turns(Spec):
    """How many quarter-turned copies of the input the decoding pools: 1 (the image alone), 2 (and its half
    turn) or 4 (its four quarter turns)."""

    def parse(self, value: Any) -> int:
        if not (is_whole(value) and value in TURNS):
            raise Refused("expected 1, 2 or 4 (the image alone, with its half turn, or its four quarter turns)")
        return int(value)


@dataclass(frozen=True)
class Choice(Spec):
    """One of a few names."""

    choices: tuple[str, ...]

    def parse(self, value: Any) -> str:
        if not (isinstance(value, str) and value in self.choices):
            raise Refused(f"expected one of {', '.join(self.choices)}")
        return value


@dataclass(frozen=True)
class Flag(Spec):
    """True or false (never 1, 0 or text)."""

    def parse(self, value: Any) -> bool:
        if not isinstance(value, bool | np.bool_):
            raise Refused("expected true or false")
        return bool(value)


@dataclass(frozen=True)
class ClipPlanes(Spec):
    """``[near, far]`` metres, ``0 < near < far <=`` :data:`MAX_CLIP_END_M`, or None."""

    def parse(self, value: Any) -> tuple[float, float] | None:
        if value is None:
            return None
        numbers_given = (not isinstance(value, str | bytes) and isinstance(value, Sequence) and len(value) == 2
                         and all(is_real(v) for v in value))  # fmt: skip
        if not numbers_given:  # true is no distance, "1.5" no number
            raise Refused("expected [near, far] in metres")
        near, far = (float(v) for v in value)
        if not (0 < near < far <= MAX_CLIP_END_M):  # NaN fails too
            raise Refused(f"expected 0 < near < far <= {MAX_CLIP_END_M:g} metres")
        return near, far


@dataclass(frozen=True)
class RegionOfInterest(Spec):
    """None, ``"auto"``, ``"auto:S"`` (S metres in [:data:`MIN_AUTO_SIDE`, :data:`MAX_AUTO_SIDE`], written as ``%g``) or an
    ``(x0, y0, x1, y1)`` pixel box at least :data:`MIN_BOX_SIDE` a side (:mod:`opnet.data.roi`)."""

    def parse(self, value: Any) -> Box | str | None:
        if value is None or value == "null":
            return None
        if isinstance(value, str):
            return self._text(value)
        if isinstance(value, str | bytes) or not isinstance(value, Sequence) or len(value) != 4:
            raise Refused("expected null, auto, auto:<metres> or [x0, y0, x1, y1] pixels")
        if not all(is_whole(v) for v in value):
            raise Refused("the box needs whole pixel numbers")
        x0, y0, x1, y1 = (int(v) for v in value)
        if x0 < 0 or y0 < 0:
            raise Refused(f"the box starts at pixel ({x0}, {y0}), outside the image; pixels count from 0 at the "
                          "image's top-left corner")  # fmt: skip
        if x1 < x0 or y1 < y0:
            raise Refused("the corners are reversed; give [x0, y0, x1, y1] with the top-left corner (x0, y0) first, "
                          "then the bottom-right one (x1, y1, exclusive)")  # fmt: skip
        if x1 == x0 or y1 == y0:
            raise Refused("an empty box; expected x0 < x1 and y0 < y1")
        if min(x1 - x0, y1 - y0) < MIN_BOX_SIDE:
            raise Refused(f"a box of {x1 - x0} x {y1 - y0} pixels; the network needs at least {MIN_BOX_SIDE} a "
                          "side (its input would blow each pixel up into a block)")  # fmt: skip
        return (x0, y0, x1, y1)

    def _text(self, value: str) -> Box | str:
        if value == AUTO:
            return AUTO
        if value.startswith(AUTO + ":"):
            try:
                metres = float(value.split(":", 1)[1].strip())
            except ValueError:
                metres = math.nan
            if not (math.isfinite(metres) and MIN_AUTO_SIDE <= metres <= MAX_AUTO_SIDE):
                raise Refused(f"auto:S takes the side S of the box in metres, a number in [{MIN_AUTO_SIDE:g}, "
                              f"{MAX_AUTO_SIDE:g}]")
            return f"{AUTO}:{metres:g}"
        parts = value.replace("[", "").replace("]", "").split(",")
        try:
            box = [int(p) for p in parts] if len(parts) == 4 else None
        except ValueError:
            box = None
        if box is None:
            raise Refused("expected null, auto, auto:<metres> or [x0, y0, x1, y1] pixels")
        try:
            return self.parse(box)  # a box of whole numbers: what is wrong with it (not "expected a box")
        except Refused as r:
            raise Refused(r.problem, box) from None


#: every value that reaches a run from more than one source, by its name here
SETTINGS: dict[str, Spec] = {
    "threshold": Number(0.0, 1.0, high_open=True),
    "min_visibility": Number(0.0, 1.0, high_open=True),
    "turns": Turns(),
    "min_target_visibility": Number(0.0, 1.0, high_open=True),
    "score": Choice(SCORES),
    "averaging": Flag(),
    "quality": Flag(),
    "averaging.eps": Number(0.0, 100.0, low_open=True, what="a fraction of delta"),
    "averaging.min_samples": Whole(1, 10_000),
    "averaging.cluster_score": Choice(CLUSTER_SCORES),
    "averaging.keep_noise": Flag(),
    "grid": Whole(1, 1024),
    "slots": Whole(1, 64),
    "input_size": Whole(8, MAX_INPUT_SIZE, what="a whole number of pixels"),
    "fit": Choice(CANVAS_FITS),
    "interpolation": Choice(INTERPOLATIONS),
    "roi": RegionOfInterest(),
    "trained_clip": ClipPlanes(),
}

#: the keys of a run config: a YAML config composed by train.py, a checkpoint's saved config
TRAINING = {
    "threshold": "parameterization.threshold", "min_visibility": "parameterization.min_visibility",
    "min_target_visibility": "parameterization.min_target_visibility",
    "score": "parameterization.score", "averaging": "parameterization.averaging", "turns": "parameterization.turns",
    "quality": "parameterization.quality",
    "averaging.eps": "parameterization.averaging_eps", "averaging.min_samples": "parameterization.averaging_min_samples",
    "averaging.cluster_score": "parameterization.averaging_score", "grid": "parameterization.grid",
    "slots": "parameterization.slots", "input_size": "data.input_size", "fit": "data.fit", "roi": "data.roi",
    "trained_clip": "trained_clip",
}  # fmt: skip
#: the keys of eval.py's and predict.py's ``+decoding.*`` overrides
OVERRIDE = {
    "threshold": "decoding.threshold", "min_visibility": "decoding.min_visibility", "score": "decoding.score",
    "turns": "decoding.turns",
    "averaging": "decoding.averaging", "averaging.eps": "decoding.averaging.eps",
    "averaging.min_samples": "decoding.averaging.min_samples",
    "averaging.cluster_score": "decoding.averaging.cluster_score",
    "averaging.keep_noise": "decoding.averaging.keep_noise",
}
#: the keys of an ONNX export's opnet metadata (:mod:`opnet.deploy.metadata`)
METADATA = {
    "threshold": "decoding.threshold", "min_visibility": "decoding.min_visibility", "score": "decoding.score",
    "turns": "decoding.turns",
    "averaging": "decoding.averaging", "averaging.eps": "decoding.averaging.eps",
    "averaging.min_samples": "decoding.averaging.min_samples",
    "averaging.cluster_score": "decoding.averaging.cluster_score",
    "averaging.keep_noise": "decoding.averaging.keep_noise", "grid": "grid_size", "slots": "slots",
    "input_size": "input.size", "fit": "input.fit", "interpolation": "input.interpolation", "roi": "input.roi",
    "trained_clip": "trained_clip",
}


def check_value(name: str, value: Any, key: str | None = None, source: str = "") -> Any:
    """``value`` of the setting ``name`` typed; :class:`SettingError` naming ``key`` (default ``name``)."""
    return SETTINGS[name].check(value, name if key is None else key, source)


def check_settings(values: Mapping[str, Any], keys: Mapping[str, str], source: str = "") -> dict[str, Any]:
    """The settings ``values`` (by name) typed, in order; the first bad one raises a
    :class:`SettingError` naming its key as ``keys`` spells it (``keys[name]``) and ``source``."""
    return {name: check_value(name, value, keys[name], source) for name, value in values.items()}


_ABSENT = object()


def _lookup(config: Any, key: str) -> Any:
    node = config
    for part in key.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return _ABSENT
        node = node[part]
    return node


def _children(keys: Mapping[str, str], section: str) -> list[str]:
    return [k.removeprefix(section + ".") for k in keys.values() if k.startswith(section + ".")]


def read_settings(config: Any, keys: Mapping[str, str], source: str = "", closed: Sequence[str] = ()) -> dict[str, Any]:
    """The settings a nested mapping ``config`` holds under the keys ``keys`` spells, typed (absent
    ones left out); see :func:`check_settings`.

    A flag whose settings ``keys`` spells beneath it (``decoding.averaging``) takes a mapping of them
    too, which turns it on; None there leaves it out. Every key under a ``closed`` section must be one
    of ``keys`` (a misspelt override is named, not ignored).
    """
    for section in closed:
        node = _lookup(config, section)
        known = [k for k in _children(keys, section) if "." not in k]
        for child in node if isinstance(node, Mapping) else ():
            if child not in known:
                raise SettingError(f"{section}.{child}", node[child],
                                   f"unknown setting; expected one of {', '.join(known)}", source)
    given = {}
    for name, key in keys.items():
        value = _lookup(config, key)
        below = _children(keys, key)
        if below and isinstance(SETTINGS[name], Flag) and not isinstance(value, bool | np.bool_):
            if value is None or value is _ABSENT:
                continue
            if not isinstance(value, Mapping):
                raise SettingError(key, value, f"expected true, false or a mapping of {', '.join(below)}", source)
            value = True
        if value is not _ABSENT:
            given[name] = value
    return check_settings(given, keys, source)


def _first_leaf(node: Any, key: str) -> tuple[str, Any]:
    while isinstance(node, Mapping) and node:
        child = next(iter(node))
        node, key = node[child], f"{key}.{child}"
    return key, node


def refuse_foreign(config: Any, foreign: Mapping[str, str], own: Mapping[str, str], reader: str,
                   source: str = "") -> None:  # fmt: skip
    """Refuse a value ``config`` holds under a section of the keys another source spells (``foreign``:
    eval.py's ``decoding.*`` overrides) that this source (``own``: a training config) has none of: it
    would be read by nobody. A :class:`SettingError` naming the key, and how ``reader`` takes it."""
    own_sections = {key.split(".")[0] for key in own.values()}
    for section in dict.fromkeys(key.split(".")[0] for key in foreign.values()):
        node = _lookup(config, section)
        if section in own_sections or node is _ABSENT:
            continue
        key, value = _first_leaf(node, section)
        name = next((n for n, k in foreign.items() if k == key), None)
        where = own[name] if name in own else ", ".join(f"{s}.*" for s in sorted(own_sections))
        raise SettingError(key, value, f"not a setting of {reader}, which takes it as {where}", source)


# ---------------------------------------------------------------------- helpers of the typed settings


class _Missing:
    def __repr__(self) -> str:
        return "<missing>"


MISSING = _Missing()


def spelled(names: Sequence[str], keys: Mapping[str, str]) -> dict[str, str]:
    """The spellings ``keys`` gives of ``names`` (those it has)."""
    return {name: keys[name] for name in names if name in keys}


def nest(values: Mapping[str, Any], keys: Mapping[str, str]) -> dict[str, Any]:
    """The settings ``values`` (by name) as the nested mapping ``keys`` spells (``decoding.averaging.eps``)."""
    tree: dict[str, Any] = {}
    for name, value in values.items():
        *parents, leaf = keys[name].split(".")
        node = tree
        for part in parents:
            node = node.setdefault(part, {})
        node[leaf] = value
    return tree


def require(tree: Any, keys: Sequence[str], source: str) -> None:
    """Every key of ``keys`` (dotted) is in ``tree``; a missing one is a :class:`SettingError` naming it."""
    for key in keys:
        node = tree
        for part in key.split("."):
            if not isinstance(node, Mapping) or part not in node:
                raise SettingError(key, MISSING, "missing; the entry is written whole", source)
            node = node[part]


def plain(value: Any, key: str, source: str) -> Any:
    """``value`` as JSON-able data (mappings with text keys, lists, text, numbers, booleans, None)."""
    if value is None or isinstance(value, str | bool):
        return value
    if isinstance(value, int | float):
        if isinstance(value, float) and not math.isfinite(value):
            raise SettingError(key, value, "expected a finite number", source)
        return value
    if isinstance(value, Mapping):
        if not all(isinstance(k, str) for k in value):
            raise SettingError(key, value, "expected a mapping with text keys", source)
        return {k: plain(v, f"{key}.{k}", source) for k, v in value.items()}
    if isinstance(value, Sequence) and not isinstance(value, bytes):
        return [plain(v, f"{key}.{i}", source) for i, v in enumerate(value)]
    raise SettingError(key, value, "expected plain data (text, numbers, lists, mappings)", source)


def checked_fields(instance: Any, values: Mapping[str, Any], fields: Mapping[str, str]) -> None:
    """Set the frozen ``instance``'s fields to the schema's typed ``values`` (by schema name)."""
    typed = check_settings(values, METADATA)
    for name, field in fields.items():
        object.__setattr__(instance, field, typed[name])
