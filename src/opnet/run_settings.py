"""What a trained model needs at inference, typed: its framing, its decoding and its object.

A run's settings are made once at the edge (train.py, from its Hydra config, in
:func:`opnet.cli.build.build_components`), held by the model (``PoseEstimator.settings``) and saved
as their own checkpoint entry (:data:`CHECKPOINT_KEY`, :meth:`RunSettings.to_dict`); predict.py,
eval.py, the ONNX export and its runtime read them back from there (:func:`opnet.cli.build.load_checkpoint`,
:meth:`RunSettings.from_dict`), not from the run config. A checkpoint written before the entry
existed is read from its run config (:meth:`RunSettings.from_training_config`).

One vocabulary: the entry, the ONNX metadata and eval.py's / predict.py's ``+decoding.*`` overrides
spell the keys alike (``decoding.averaging.eps``, :data:`~opnet.settings_schema.METADATA`); a run
config's own spellings (``parameterization.averaging_eps``, :data:`~opnet.settings_schema.TRAINING`)
are read only where a config is. Every value is checked by the one schema
(:mod:`opnet.settings_schema`): a bad one is one :class:`~opnet.settings_schema.SettingError`
naming the source file and the key.

Standard library and numpy only: the torch-free ONNX runtime imports it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

from opnet.datasets.camera_file import YAML_CAMERA_KEYS
from opnet.geometry.camera import Camera
from opnet.geometry.frames import BASE_POSE_KEY, rigid_transform
from opnet.settings_schema import (
    DECODING_SCALARS,
    METADATA,
    OVERRIDE,
    TRAINING,
    MISSING,
    Box,
    SettingError,
    checked_fields as _checked,
    nest as _nest,
    plain as _plain,
    read_settings,
    refuse_foreign,
    require as _require,
    spelled as _spelled,
)

#: the checkpoint entry that holds :meth:`RunSettings.to_dict`
CHECKPOINT_KEY = "opnet_settings"
#: the layout of that entry
FORMAT = 1

#: the settings of the decoding and of the input, by their schema names
DECODING_NAMES = (*DECODING_SCALARS, "averaging", "averaging.eps", "averaging.min_samples",
                  "averaging.cluster_score", "averaging.keep_noise")  # fmt: skip
INPUT_NAMES = ("input_size", "fit", "interpolation", "roi", "trained_clip")
#: the top-level keys of the checkpoint entry
ENTRY_KEYS = ("format", "input", "trained_clip", "decoding", "object", "refine", BASE_POSE_KEY, "camera")
#: the training camera's values, in this order (a camera YAML's keys)
CAMERA_KEYS = YAML_CAMERA_KEYS
#: the refinements a model may be meant to run with (``deploy_refine``; conf/refine/<name>.yaml)
REFINE_NAMES = ("icp", "search", "search_fast", "search_flat")


def check_format(value: Any, source: str = "") -> None:
    """``value`` is the layout :data:`FORMAT` of a checkpoint's entry and an ONNX export's metadata; a
    :class:`SettingError` naming ``format`` otherwise."""
    if value != FORMAT or isinstance(value, bool):
        raise SettingError("format", value, f"expected {FORMAT} (written by another opnet version)", source)


@dataclass(frozen=True)
class AveragingSettings:
    """The pose averaging of the decoding (:class:`opnet.parameterizations.averaging.PoseAveraging`).

    Attributes:
        eps: DBSCAN radius as a fraction of δ.
        min_samples: DBSCAN core-point threshold.
        cluster_score: a cluster's score from its members': "max", "sum" or "mean".
        keep_noise: keep DBSCAN noise points (only with min_samples > 1) as single hypotheses.
    """

    eps: float = 0.5
    min_samples: int = 1
    cluster_score: str = "max"
    keep_noise: bool = False

    def __post_init__(self) -> None:
        _checked(self, {"averaging.eps": self.eps, "averaging.min_samples": self.min_samples,
                        "averaging.cluster_score": self.cluster_score, "averaging.keep_noise": self.keep_noise},
                 {"averaging.eps": "eps", "averaging.min_samples": "min_samples",
                  "averaging.cluster_score": "cluster_score", "averaging.keep_noise": "keep_noise"})  # fmt: skip


@dataclass(frozen=True)
class DecodingSettings:
    """How a network output becomes pose hypotheses (docs/method.md#decoding).

    Attributes:
        threshold: presence threshold τ of a hypothesis.
        min_visibility: decode only cells whose predicted visibility reaches this (0: all).
        score: a hypothesis' score: "p", "p*v" or "v"; from a network with a quality channel also "p*q", "p*v*q".
        averaging: the pose averaging, or None (every cell's hypothesis kept).
        turns: 1, or the 2 or 4 quarter-turned copies of the input whose hypotheses are pooled before the
            averaging (:mod:`opnet.parameterizations.turns`).
    """

    threshold: float = 0.1
    min_visibility: float = 0.0
    score: str = "p"
    averaging: AveragingSettings | None = None
    turns: int = 1

    def __post_init__(self) -> None:
        _checked(self, self._scalars(), {k: k for k in DECODING_SCALARS})
        if self.averaging is not None and not isinstance(self.averaging, AveragingSettings):
            raise SettingError("decoding.averaging", self.averaging, "expected None or AveragingSettings")

    @classmethod
    def _from_values(cls, s: Mapping[str, Any]) -> DecodingSettings:
        """From typed settings by schema name; absent ones take the defaults."""
        averaging = None
        if s.get("averaging"):
            given = {name.split(".")[1]: value for name, value in s.items() if name.startswith("averaging.")}
            averaging = AveragingSettings(**given)
        return cls(**{k: s[k] for k in DECODING_SCALARS if k in s}, averaging=averaging)

    def _scalars(self) -> dict[str, Any]:
        """The settings of one value each (:data:`DECODING_SCALARS`) by name."""
        return {k: getattr(self, k) for k in DECODING_SCALARS}

    def _values(self) -> dict[str, Any]:
        """The settings by schema name (the averaging's only when it is on)."""
        values: dict[str, Any] = self._scalars()
        if self.averaging is None:
            values["averaging"] = None
        else:
            values.update({f"averaging.{f.name}": getattr(self.averaging, f.name)
                           for f in dataclasses.fields(AveragingSettings)})
        return values

    @classmethod
    def from_training_config(cls, cfg: Any, source: str = "") -> DecodingSettings:
        """The decoding a run config (train.py's, a checkpoint's saved one) sets under
        ``parameterization.*``; absent keys take this class's defaults (averaging off).

        Raises:
            SettingError: ``[<source> ]parameterization.<key>=<value>: expected ...``.
        """
        keys = _spelled(DECODING_NAMES, TRAINING)
        return cls._from_values(read_settings(cfg, keys, source))

    @classmethod
    def of(cls, parameterization: Any) -> DecodingSettings:
        """The decoding a parameterization (:class:`opnet.parameterizations.base.Parameterization`) is set to."""
        avg = parameterization.averaging
        averaging = None if avg is None else AveragingSettings(avg.eps, avg.min_samples, avg.cluster_score,
                                                              avg.keep_noise)
        return cls(parameterization.threshold, parameterization.min_visibility, parameterization.score, averaging,
                   parameterization.turns)

    def with_overrides(self, overrides: Any, source: str = "") -> DecodingSettings:
        """These settings with eval.py's / predict.py's ``decoding=`` overrides: ``threshold``,
        ``min_visibility``, ``score``, ``turns`` and ``averaging`` (false, true, or a mapping of ``eps``,
        ``min_samples``, ``cluster_score``, ``keep_noise`` over the current ones, which turns it on); None
        or empty: unchanged.

        Raises:
            SettingError: a bad value or an unknown key, named as written (``decoding.averaging.eps``).
        """
        if not overrides:
            return self
        if not isinstance(overrides, Mapping):
            raise SettingError("decoding", overrides, "expected a mapping of threshold, score, min_visibility, "
                               "turns, averaging", source)  # fmt: skip
        given = read_settings({"decoding": overrides}, OVERRIDE, source, closed=("decoding", "decoding.averaging"))
        changes = {k: given[k] for k in DECODING_SCALARS if k in given}
        if given.get("averaging") is False:
            changes["averaging"] = None
        elif given.get("averaging"):
            tuned = {name.split(".")[1]: value for name, value in given.items() if name.startswith("averaging.")}
            changes["averaging"] = dataclasses.replace(self.averaging or AveragingSettings(), **tuned)
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_overrides(cls, overrides: Any, base: DecodingSettings | None = None, source: str = "") -> DecodingSettings:
        """``base`` (default: the defaults) with the ``decoding=`` overrides (:meth:`with_overrides`)."""
        return (base or cls()).with_overrides(overrides, source)

    def overrides(self) -> dict[str, Any]:
        """These settings as ``decoding=`` overrides spell them (``Parameterization.with_decoding``)."""
        out: dict[str, Any] = self._scalars()
        avg = self.averaging
        out["averaging"] = False if avg is None else dataclasses.asdict(avg)
        return out

    def to_metadata(self) -> dict[str, Any]:
        """``{"decoding": {...}}``: the settings as the ONNX metadata and the checkpoint entry spell them."""
        return _nest(self._values(), METADATA)

    @classmethod
    def from_metadata(cls, meta: Any, source: str = "", required: bool = False) -> DecodingSettings:
        """The settings of :meth:`to_metadata`'s layout (an ONNX export's metadata, a checkpoint's
        entry); absent ones take the defaults unless ``required``.

        Raises:
            SettingError: ``[<source> ]decoding.<key>=<value>: expected ...``; with ``required``, a
            missing key (``<missing>``) or an unknown one too.
        """
        keys = _spelled(DECODING_NAMES, METADATA)
        if required:
            _require(meta, [keys[n] for n in ("threshold", "min_visibility", "score", "averaging")], source)
            avg = meta["decoding"]["averaging"]
            if isinstance(avg, Mapping):
                _require(meta, [keys[n] for n in DECODING_NAMES if n.startswith("averaging.")], source)
        closed = ("decoding", "decoding.averaging") if required else ()
        return cls._from_values(read_settings(meta, keys, source, closed=closed))


@dataclass(frozen=True)
class InputSettings:
    """How a depth image becomes the network input (docs/method.md#network-input).

    Attributes:
        size: the side of the square network input, pixels.
        fit: how the image becomes the square canvas: "pad", "crop", "image" or "image_crop".
        roi: the region of interest (:mod:`opnet.data.roi`): None, an ``(x0, y0, x1, y1)`` pixel box,
            ``"auto"`` or ``"auto:S"``.
        interpolation: the resize the input is made with ("area").
        trained_clip: the clip planes (near, far) of the training scenes' cameras, metres, with which
            a new image's depth is normalized; None where the run recorded none.
    """

    size: int = 128
    fit: str = "pad"
    roi: Box | str | None = None
    interpolation: str = "area"
    trained_clip: tuple[float, float] | None = None

    _FIELDS: ClassVar[dict[str, str]] = {"input_size": "size", "fit": "fit", "interpolation": "interpolation",
                                         "roi": "roi", "trained_clip": "trained_clip"}  # fmt: skip

    def __post_init__(self) -> None:
        _checked(self, {name: getattr(self, field) for name, field in self._FIELDS.items()}, self._FIELDS)

    @classmethod
    def _from_values(cls, s: Mapping[str, Any]) -> InputSettings:
        return cls(**{field: s[name] for name, field in cls._FIELDS.items() if name in s})

    def _values(self) -> dict[str, Any]:
        values = {name: getattr(self, field) for name, field in self._FIELDS.items()}
        values["roi"] = list(self.roi) if isinstance(self.roi, tuple) else self.roi
        values["trained_clip"] = None if self.trained_clip is None else list(self.trained_clip)
        return values

    @classmethod
    def from_training_config(cls, cfg: Any, source: str = "") -> InputSettings:
        """The framing a run config sets (``data.input_size``, ``data.fit``, ``data.roi``) and the
        clip planes train.py recorded in it (``trained_clip``, checkpoints written before the
        settings entry); absent keys take the defaults.

        Raises:
            SettingError: ``[<source> ]<key>=<value>: expected ...``, the key as the config spells it.
        """
        return cls._from_values(read_settings(cfg, _spelled(INPUT_NAMES, TRAINING), source))

    def to_metadata(self) -> dict[str, Any]:
        """``{"input": {"size", "fit", "interpolation", "roi"}, "trained_clip": ...}``: the settings as
        the ONNX metadata and the checkpoint entry spell them."""
        return _nest(self._values(), METADATA)

    @classmethod
    def from_metadata(cls, meta: Any, source: str = "", required: bool = False) -> InputSettings:
        """The settings of :meth:`to_metadata`'s layout; absent ones take the defaults (an export of
        before ``trained_clip`` was recorded: None) unless ``required``.

        Raises:
            SettingError: ``[<source> ]<key>=<value>: expected ...``, the key as the metadata spells it.
        """
        keys = _spelled(INPUT_NAMES, METADATA)
        if required:
            _require(meta, list(keys.values()), source)
        return cls._from_values(read_settings(meta, keys, source, closed=("input",) if required else ()))

    def framing_differences(self, other: InputSettings) -> list[tuple[str, Any, Any]]:
        """``(schema name, this value, other's)`` of each framing setting (size, fit, interpolation, region
        of interest; not the clip planes, recorded apart) on which ``other`` differs."""
        names = [name for name in INPUT_NAMES if name != "trained_clip"]
        return [(name, mine, theirs) for name in names
                if (mine := getattr(self, self._FIELDS[name])) != (theirs := getattr(other, self._FIELDS[name]))]

    def with_trained_clip(self, planes: Sequence[float] | None) -> InputSettings:
        """These settings with the training scenes' clip planes ``planes`` (None: none recorded)."""
        return dataclasses.replace(self, trained_clip=None if planes is None else (float(planes[0]), float(planes[1])))


@dataclass(frozen=True)
class ObjectSettings:
    """The object a model was trained for: its object config (``conf/object/``: name, mesh, mesh_scale,
    symmetry, model_rotation, ...) as plain data, from which :func:`opnet.objects.config.object_from_config`
    builds it again.

    Attributes:
        config: the object config, JSON-able; read it, do not change it.
    """

    config: Mapping[str, Any]

    def __post_init__(self) -> None:
        object.__setattr__(self, "config", self.checked(self.config))

    @staticmethod
    def checked(config: Any, key: str = "object", source: str = "") -> dict[str, Any]:
        """``config`` as a plain dict holding a ``name``; a :class:`SettingError` naming ``key`` otherwise."""
        if not isinstance(config, Mapping):
            raise SettingError(key, config, "expected an object config (a mapping with a name)", source)
        name = config.get("name")
        if not isinstance(name, str) or not name:
            raise SettingError(f"{key}.name", name, "expected the object's name", source)
        return _plain(config, key, source)

    @property
    def name(self) -> str:
        return self.config["name"]

    @classmethod
    def from_training_config(cls, cfg: Any, source: str = "") -> ObjectSettings | None:
        """The ``object`` section of a run config (None when it has none)."""
        config = cfg.get("object") if isinstance(cfg, Mapping) else None
        return None if config is None else cls(cls.checked(config, "object", source))


@dataclass(frozen=True)
class RunSettings:
    """Everything a trained model needs at inference besides its weights and its network.

    Attributes:
        input: the framing and the training clip planes.
        decoding: the decoding.
        object: the object, or None (a system built without an object config).
        refine: the refinement the model is meant to run with (train.py's ``deploy_refine``: a
            conf/refine/ name of :data:`REFINE_NAMES`), applied by eval.py and predict.py with their
            default ``refine=model``; None: the poses as decoded.
        T_base_cam: the pose of the training's camera in the robot's base frame (4 x 4 rows, metres,
            camera to base; the cell file's ``cell.T_base_cam``), or None: predict.py and the ONNX
            runtime write base-frame poses with it when the camera file gives none.
        camera: the training scenes' camera (:data:`CAMERA_KEYS`: pixels and metres, at the image's full
            size), or None: predict.py and the ONNX runtime take it for an image with no camera file
            above it and no intrinsics given, when the image is of its size.
    """

    input: InputSettings = InputSettings()
    decoding: DecodingSettings = DecodingSettings()
    object: ObjectSettings | None = None
    refine: str | None = None
    T_base_cam: tuple[tuple[float, ...], ...] | None = None
    camera: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "T_base_cam", self.checked_base_pose(self.T_base_cam))
        object.__setattr__(self, "camera", self.checked_camera(self.camera))

    @staticmethod
    def checked_camera(value: Any, key: str = "camera", source: str = "") -> tuple[float, ...] | None:
        """``value`` (the :data:`CAMERA_KEYS` in order, or a mapping of them) as a camera's values (None:
        none); a :class:`SettingError` naming ``key`` otherwise."""
        if value is None:
            return None
        given = [value.get(k) for k in CAMERA_KEYS] if isinstance(value, Mapping) else value
        try:
            values = tuple(float(x) for x in given)
            if len(values) != len(CAMERA_KEYS) or not all(math.isfinite(x) for x in values):
                raise ValueError
            Camera.from_row(values)
        except (TypeError, ValueError):
            raise SettingError(key, value, f"expected a camera: {', '.join(CAMERA_KEYS)} (pixels, metres)",
                               source) from None
        return values

    def with_camera(self, camera: Any) -> RunSettings:
        """The settings with the training scenes' camera (a :class:`~opnet.geometry.camera.Camera`, or None)."""
        values = None if camera is None else tuple(camera.row())
        return dataclasses.replace(self, camera=values)

    def camera_entry(self) -> dict[str, Any]:
        """``{"camera": {key: value}}`` when the settings hold the training camera, else nothing."""
        return {} if self.camera is None else {"camera": dict(zip(CAMERA_KEYS, self.camera, strict=True))}

    @staticmethod
    def checked_base_pose(value: Any, key: str = BASE_POSE_KEY, source: str = "") -> tuple[tuple[float, ...], ...] | None:
        """``value`` as the rows of a rigid transform (None: none); a ValueError naming ``source`` and ``key``
        otherwise (:func:`opnet.geometry.frames.rigid_transform`)."""
        if value is None:
            return None
        T = rigid_transform(value, source or "run settings", key)
        return tuple(tuple(float(x) for x in row) for row in T)

    @staticmethod
    def checked_refine(value: Any, key: str = "deploy_refine", source: str = "") -> str | None:
        """``value`` as a refinement name (None: none); a SettingError naming ``key`` otherwise."""
        if value is None or value == "none":
            return None
        if not isinstance(value, str) or value not in REFINE_NAMES:
            raise SettingError(key, value, f"expected null or one of {', '.join(REFINE_NAMES)} (conf/refine/)", source)
        return value

    @classmethod
    def from_training_config(cls, cfg: Any, source: str = "", decoding: DecodingSettings | None = None) -> RunSettings:
        """The settings of a run config: train.py's, or the saved one of a checkpoint written before
        the settings entry (with its ``trained_clip``). ``decoding``: the decoding the parameterization
        built from it has (its class's defaults fill keys the config lacks); default: the config's
        keys (:meth:`DecodingSettings.from_training_config`).

        Raises:
            SettingError: ``[<source> ]<key>=<value>: expected ...``, the key as the config spells it.
        """
        refine = cfg.get("deploy_refine") if isinstance(cfg, Mapping) else None
        cell = cfg.get("cell") if isinstance(cfg, Mapping) else None
        pose = cell.get(BASE_POSE_KEY) if isinstance(cell, Mapping) else None
        # eval.py's and predict.py's +decoding.* in a training config would be read by nobody
        refuse_foreign(cfg, OVERRIDE, TRAINING, "train.py (+decoding.* overrides eval.py's and predict.py's decoding)",
                       source)
        return cls(InputSettings.from_training_config(cfg, source),
                   decoding if decoding is not None else DecodingSettings.from_training_config(cfg, source),
                   ObjectSettings.from_training_config(cfg, source),
                   cls.checked_refine(refine, "deploy_refine", source),
                   cls.checked_base_pose(pose, f"cell.{BASE_POSE_KEY}", source))  # fmt: skip

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able data: ``{"format", "input", "trained_clip", "decoding", "object", "refine"}``
        and ``T_base_cam`` and ``camera`` when there are, the input and the decoding spelt as in the ONNX metadata
        (:mod:`opnet.deploy.metadata`)."""
        return {"format": FORMAT, **self.input.to_metadata(), **self.decoding.to_metadata(),
                "object": None if self.object is None else _plain(self.object.config, "object", ""),
                "refine": self.refine, **self.base_pose_entry(), **self.camera_entry()}

    def base_pose_entry(self) -> dict[str, Any]:
        """``{"T_base_cam": rows}`` when the settings hold a base pose, else nothing (the entry and the metadata)."""
        return {} if self.T_base_cam is None else {BASE_POSE_KEY: [list(row) for row in self.T_base_cam]}

    @classmethod
    def from_dict(cls, d: Any, source: str = "") -> RunSettings:
        """The settings :meth:`to_dict` wrote, every key checked (``source``: ``<file>: the checkpoint's
        opnet_settings``).

        Raises:
            SettingError: one line, ``<source> <key>=<value>: expected ...``: a missing, unknown or bad key.
        """
        if not isinstance(d, Mapping):
            raise SettingError(CHECKPOINT_KEY, d, "expected a mapping", source)
        for key in d:
            if key not in ENTRY_KEYS:
                raise SettingError(str(key), d[key], f"unknown setting; expected one of {', '.join(ENTRY_KEYS)}",
                                   source)  # fmt: skip
        _require(d, ["format"], source)
        check_format(d["format"], source)
        _require(d, ["object"], source)
        obj = None if d["object"] is None else ObjectSettings(ObjectSettings.checked(d["object"], "object", source))
        # "refine" may be missing: entries written before it recorded no refinement; T_base_cam: none recorded
        return cls(InputSettings.from_metadata(d, source, required=True),
                   DecodingSettings.from_metadata(d, source, required=True), obj,
                   cls.checked_refine(d.get("refine"), "refine", source),
                   cls.checked_base_pose(d.get(BASE_POSE_KEY), BASE_POSE_KEY, source),
                   cls.checked_camera(d.get("camera"), "camera", source))  # fmt: skip

    def with_decoding(self, decoding: DecodingSettings) -> RunSettings:
        return dataclasses.replace(self, decoding=decoding)

    def with_trained_clip(self, planes: Sequence[float] | None) -> RunSettings:
        return dataclasses.replace(self, input=self.input.with_trained_clip(planes))
