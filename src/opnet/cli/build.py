"""Build the run's components from a Hydra config — the only place that instantiates configs."""

from __future__ import annotations

import contextlib
import inspect
import pickle
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
from hydra.errors import InstantiationException
from hydra.utils import get_object, instantiate
from omegaconf import DictConfig, OmegaConf, open_dict

from opnet._repr import short_repr
from opnet.cli.trusted import saved_config, short
from opnet.fileio.files import require_regular_file
from opnet.objects.config import object_from_config
from opnet.objects.model import ObjectModel
from opnet.parameterizations.base import Parameterization
from opnet.run_settings import CHECKPOINT_KEY, DecodingSettings, InputSettings, RunSettings
from opnet.settings_schema import METADATA, TRAINING, check_value, read_settings

if TYPE_CHECKING:
    from opnet.estimator import PoseEstimator
    from opnet.system import OPNetSystem


@dataclass
class Components:
    obj: ObjectModel
    parameterization: Parameterization
    system: OPNetSystem


def absolutize_paths(cfg: DictConfig) -> None:
    """Make ``paths.root_dir`` absolute so every derived path stored in checkpoints stays valid."""
    root = cfg.paths.root_dir
    OmegaConf.update(cfg, "paths.root_dir", str(Path(root).resolve()), force_add=True)


def plain(cfg: Any) -> Any:
    """A resolved plain-Python copy of a config node (or the value itself)."""
    return OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else cfg


def run_config(cfg: DictConfig) -> dict[str, Any]:
    """The parts of the config a checkpoint needs to rebuild the model, resolved."""
    keys = ("object", "rotation", "parameterization", "model", "loss", "optim", "data", "seed", "presence_prior_logit")
    return {k: plain(cfg[k]) for k in keys if k in cfg}


@contextlib.contextmanager
def config_group(group: str) -> Iterator[None]:
    """Name the config group whose component could not be built from its keys: an unknown or a
    missing keyword (a typo, or a config edited by hand) is a ``ValueError`` naming ``group``,
    not a traceback from inside Hydra. Other errors pass unchanged."""
    try:
        yield
    except (InstantiationException, TypeError) as e:
        cause = e.__cause__ if isinstance(e, InstantiationException) and e.__cause__ is not None else e
        text = str(cause)
        if not isinstance(cause, TypeError) or "argument" not in text:
            raise
        raise ValueError(f"config group '{group}': its keys do not fit its component ({short(text.splitlines()[0], 200)})") from e


def check_keys(node: Any, section: str) -> None:
    """Every key of the config ``node`` (``_target_`` and Hydra's other ``_`` keys apart) is a keyword its
    component takes: a typo (``+data.bogus_key=1``) is named before anything runs, not a TypeError from
    inside the component. A component that takes any keyword, or a node without a ``_target_``, is not checked.

    Raises:
        ValueError: ``<section>.<key>=<value>: not a setting of <section> (<component>); expected some of ...``.
    """
    if not isinstance(node, DictConfig) or not isinstance(node.get("_target_"), str):
        return
    try:
        target = get_object(node._target_)
        parameters = _keywords(target)
    except (ImportError, AttributeError, TypeError, ValueError):
        return  # instantiation names what it cannot find
    if parameters is None:
        return
    for key in node:
        if not str(key).startswith("_") and key not in parameters:
            value = OmegaConf.to_container(node, resolve=False)[key]
            raise ValueError(f"{section}.{key}={short_repr(value)}: not a setting of {section} "
                             f"({getattr(target, '__name__', node._target_)}); expected some of "
                             f"{', '.join(parameters)}")


def _keywords(target: Any) -> list[str] | None:
    """The keywords ``target`` takes, those its class's bases take through ``**kwargs`` too; None for any."""
    names: list[str] = []
    for owner in inspect.getmro(target) if inspect.isclass(target) else (target,):
        init = owner.__init__ if inspect.isclass(owner) else owner
        if inspect.isclass(owner) and "__init__" not in vars(owner):
            continue
        parameters = inspect.signature(init).parameters
        names += [p.name for p in parameters.values() if p.name != "self" and p.kind in
                  (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)]  # fmt: skip
        if not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in parameters.values()):
            return list(dict.fromkeys(names))
    return None


def check_pixels(key: str, value: Any) -> None:
    """An input side: the schema's ``input_size`` (a whole number of pixels in 8..4096, never a boolean);
    a ``SettingError`` naming ``key`` otherwise."""
    check_value("input_size", value, key)


def check_input_grid(cfg: DictConfig) -> None:
    """The network is built for ``model.in_size``; a fully convolutional network fed ``data.input_size`` pixels
    instead would put out another grid than the parameterization's ``grid`` (the loss would fail at the first
    step). Raises ValueError naming the keys and the two ways to a larger input."""
    size = (cfg.get("data") or {}).get("input_size")
    in_size = (cfg.get("model") or {}).get("in_size")
    if size is None or in_size is None:
        return
    check_pixels("data.input_size", size)
    check_pixels("model.in_size", in_size)
    if size == in_size:
        return
    message = (f"data.input_size={size} but model.in_size={in_size}: the network is built for the input it is fed; "
               f"set model.in_size={size}")
    grid = (cfg.get("parameterization") or {}).get("grid")
    if isinstance(grid, int) and grid * size % in_size == 0:
        message += (f" with parameterization.grid={grid * size // in_size} (the same network, each output cell as many "
                    "input pixels), or alone (one halving more, the grid kept)")
    raise ValueError(message)


def check_scene_address(cfg: DictConfig) -> None:
    """Scene settings have one address, ``scene.*``, in ``train.py`` as in ``generate.py``;
    ``data.generate.scene`` is that group (``${scene}``). Set apart (``+data.generate.scene.camera_file=...``)
    it would replace every scene setting, the dataset's resolution among them, while the data folder is still
    named after ``scene.resolution``: refused, naming the key to use."""
    generate = (cfg.get("data") or {}).get("generate")
    if not isinstance(generate, DictConfig) or "scene" not in generate or OmegaConf.is_interpolation(generate, "scene"):
        return
    given = OmegaConf.to_container(generate.scene, resolve=False) if isinstance(generate.scene, DictConfig) else {}
    keys = ", ".join(f"scene.{k}=..." for k in given) or "scene.<key>=..."
    raise ValueError(f"data.generate.scene is set apart from scene: scene settings have one address, scene.* (as in "
                     f"generate.py); write {keys} instead of data.generate.scene.<key>")


def _network(cfg: DictConfig | dict[str, Any]) -> tuple[DictConfig, ObjectModel, Parameterization, Any, RunSettings]:
    """The config (as a DictConfig), object, parameterization, backbone and settings of a (run) config."""
    if not isinstance(cfg, DictConfig):
        cfg = OmegaConf.create(cfg)
    for section in ("rotation", "parameterization", "model", "loss"):
        check_keys(cfg.get(section), section)
    obj = object_from_config(plain(cfg.object))
    # _partial_: the object goes in as it is (a dataclass keyword would be turned into a config)
    rotation = None
    if cfg.get("rotation") is not None:  # checkpoints of before conf/rotation: the Euler default
        with config_group("rotation"):
            rotation = instantiate(cfg.rotation, _partial_=True)(symmetry=obj.symmetry)
    with config_group("parameterization"):
        parameterization = instantiate(cfg.parameterization, _partial_=True)(obj=obj, rotation=rotation)
    check_input_grid(cfg)
    with config_group("model"):
        backbone = instantiate(cfg.model, out_channels=parameterization.out_channels, out_grid=parameterization.grid_size)
    presence_prior = cfg.get("presence_prior_logit")
    if presence_prior is not None and hasattr(backbone, "set_head_bias"):
        # start every slot's presence near the share of occupied cells (stabilizes early training)
        backbone.set_head_bias(parameterization.presence_channels(), float(presence_prior))
    settings = RunSettings.from_training_config(cfg, decoding=DecodingSettings.of(parameterization))
    return cfg, obj, parameterization, backbone, settings


def build_components(cfg: DictConfig | dict[str, Any]) -> Components:
    """Object, parameterization, backbone, loss and the LightningModule from a (run) config."""
    from opnet.system import OPNetSystem

    cfg, obj, parameterization, backbone, settings = _network(cfg)
    with config_group("loss"):
        loss = instantiate(cfg.loss)
    optim = plain(cfg.get("optim", {})) or {}
    system = OPNetSystem(backbone, parameterization, loss, config=run_config(cfg), settings=settings, **optim)
    return Components(obj, parameterization, system)


def build_estimator(cfg: DictConfig | dict[str, Any]) -> PoseEstimator:
    """The model for inference (:class:`~opnet.estimator.PoseEstimator`: no loss, no optimizer, no Lightning)
    from a (run) config; ``optim.max_occlusion`` is kept for scoring."""
    from opnet.estimator import PoseEstimator

    cfg, _, parameterization, backbone, settings = _network(cfg)
    occlusion = (plain(cfg.get("optim", {})) or {}).get("max_occlusion", 0.5)
    return PoseEstimator(backbone, parameterization, config=run_config(cfg), settings=settings, max_occlusion=occlusion)


#: data modules whose scenes a command that does not train reads through the plain class (no Lightning)
READ_ONLY_DATA = {"opnet.data.datamodule.OPNetDataModule": "opnet.data.scene_data.SceneData"}


def build_datamodule(cfg: DictConfig, obj: ObjectModel, train: bool = True) -> Any:
    """The DataModule of the config: with the augmentation config for training; without training
    (``train=False``) the same scenes, splits and loaders through :class:`~opnet.data.scene_data.SceneData`."""
    data = cfg.get("data")
    if not train and isinstance(data, DictConfig) and data.get("_target_") in READ_ONLY_DATA:
        data = OmegaConf.create(OmegaConf.to_container(data, resolve=True))  # the same class without Lightning
        data._target_ = READ_ONLY_DATA[data._target_]
    check_keys(data, "data")
    if train:
        check_keys(cfg.get("augmentation"), "augmentation")
    augmenter = instantiate(cfg.augmentation) if train and cfg.get("augmentation") is not None else None
    make = instantiate(data, _partial_=True, _recursive_=False)
    return make(obj=obj, augmenter=augmenter, object_config=plain(cfg.object))


def require_checkpoint_file(path: str | Path, option: str = "") -> Path:
    """``path`` as a checkpoint file, before anything reads it.

    Raises:
        FileNotFoundError: nothing there ("<path>: checkpoint not found", `` (<option>)`` after it if given).
        ValueError: a folder, FIFO, socket or device there, said which (a FIFO would block the reader).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: checkpoint not found" + (f" ({option})" if option else ""))
    return require_regular_file(path)


def read_checkpoint(path: str | Path, map_location: str = "cpu") -> dict[str, Any]:
    """The contents of a checkpoint file, read as data: tensors and plain values only.

    Raises:
        FileNotFoundError: no such file.
        ValueError: naming ``path``: not a PyTorch checkpoint, unreadable, or holding other objects.
    """
    path = require_checkpoint_file(path)
    with open(path, "rb") as f:
        magic = f.read(4)
    if magic[:2] != b"PK" and magic[:1] != b"\x80":  # a zip archive (torch.save) or a pickle (legacy)
        raise ValueError(f"{path}: cannot read checkpoint (not a PyTorch checkpoint file: neither a zip archive "
                         "nor a pickle; give the .ckpt that train.py wrote under <run>/checkpoints/)")
    try:
        # weights_only: a checkpoint is data (tensors, numbers, strings, containers); a pickle that
        # would construct other objects, i.e. run code, is refused
        ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as e:
        raise ValueError(
            f"{path}: refused: the checkpoint holds objects other than tensors and plain data "
            "(loading it could run arbitrary code); opnet checkpoints never do"
        ) from e
    except Exception as e:  # corrupt or foreign file
        raise ValueError(f"{path}: cannot read checkpoint ({type(e).__name__}: {short(str(e), 200)})") from e
    if not isinstance(ckpt, dict):
        raise ValueError(f"{path}: not an opnet checkpoint (holds a {type(ckpt).__name__}, not a dict)")
    return ckpt


def checkpoint_config(ckpt: dict[str, Any], path: str | Path) -> DictConfig:
    """The run config saved in a checkpoint (``hyper_parameters.config``), checked to name only
    opnet's own components (:func:`opnet.cli.trusted.saved_config`): a checkpoint is data.

    Raises:
        ValueError: naming ``path``: no run config, or one that names anything else.
    """
    hparams = ckpt.get("hyper_parameters")
    config = hparams.get("config") if isinstance(hparams, dict) else None
    if not config:
        raise ValueError(f"{path}: checkpoint holds no opnet run config (was it written by train.py?)")
    cfg = saved_config(config, path)
    param = cfg.get("parameterization")
    if isinstance(param, DictConfig) and str(param.get("_target_", "")).endswith(".APParameterization"):
        with open_dict(param):  # trained before AP had placements: its points were the extent's ends
            param.setdefault("placement", "extent")
    return cfg


def check_saved_settings(cfg: DictConfig, path: str | Path) -> None:
    """The values of a checkpoint's config that other sources set too (decoding, framing, region of
    interest, ``trained_clip``), checked by the schema (:mod:`opnet.settings_schema`) before anything
    is built from them.

    Raises:
        SettingError: ``<path>: the checkpoint's config <key>=<value>: expected ...``.
    """
    read_settings(cfg, TRAINING, f"{path}: the checkpoint's config")


def checkpoint_settings(ckpt: dict[str, Any], path: str | Path) -> RunSettings | None:
    """The settings a checkpoint saved as their own entry (:data:`opnet.run_settings.CHECKPOINT_KEY`),
    every key checked; None for a checkpoint written before the entry existed (its settings are
    in its run config: :func:`saved_settings`).

    Raises:
        SettingError: ``<path>: the checkpoint's opnet_settings <key>=<value>: expected ...``.
    """
    if CHECKPOINT_KEY not in ckpt:
        return None
    return RunSettings.from_dict(ckpt[CHECKPOINT_KEY], f"{path}: the checkpoint's {CHECKPOINT_KEY}")


def saved_settings(cfg: DictConfig, path: str | Path, decoding: DecodingSettings) -> RunSettings:
    """The settings of a checkpoint written before the settings entry existed, read from its run
    config: the framing (``data.*``) and the clip planes train.py recorded there (``trained_clip``),
    the object (``object``), and ``decoding``, the parameterization's built from that config.

    Raises:
        SettingError: ``<path>: the checkpoint's config <key>=<value>: expected ...``.
    """
    return RunSettings.from_training_config(cfg, f"{path}: the checkpoint's config", decoding=decoding)


def check_framing_agrees(cfg: DictConfig, settings: RunSettings, path: str | Path) -> None:
    """The framing a checkpoint's config sets (``data.input_size``, ``data.fit``, ``data.interpolation``,
    ``data.roi``) against the one its settings entry records, which is what runs: a value edited in one
    and not in the other would be ignored without a word.

    Raises:
        ValueError: ``<path>: the checkpoint's config data.<key>=<value> but its opnet_settings input.<key>=...``.
    """
    framing = InputSettings.from_training_config(cfg, f"{path}: the checkpoint's config")
    if differences := framing.framing_differences(settings.input):
        name, theirs, ours = differences[0]
        raise ValueError(f"{path}: the checkpoint's config {TRAINING[name]}={theirs!r} but its {CHECKPOINT_KEY} "
                         f"{METADATA[name]}={ours!r}, which is what runs: one was edited without the other; "
                         "edit both, or neither")


def load_checkpoint(path: str | Path, map_location: str = "cpu") -> tuple[PoseEstimator, DictConfig]:
    """Rebuild the trained model (a :class:`~opnet.estimator.PoseEstimator`, without Lightning) from a checkpoint
    written by ``train.py``: the network from its run config and weights, its
    :attr:`~opnet.estimator.PoseEstimator.settings` from its settings entry
    (:func:`checkpoint_settings`; the system decodes as they say) or, in a checkpoint written before
    the entry, from its run config (:func:`saved_settings`)."""
    ckpt = read_checkpoint(path, map_location)
    cfg = checkpoint_config(ckpt, path)
    check_saved_settings(cfg, path)
    settings = checkpoint_settings(ckpt, path)
    if not isinstance(ckpt.get("state_dict"), dict):
        raise ValueError(f"{path}: checkpoint holds no state_dict (was it written by train.py?)")
    try:
        system = build_estimator(cfg)
    except (ValueError, FileNotFoundError) as e:  # keys its components do not take, a mesh it names is gone
        raise ValueError(f"{path}: the checkpoint's config: {e}") from None
    if settings is None:
        system.settings = saved_settings(cfg, path, DecodingSettings.of(system.parameterization))
    else:
        if settings.object != system.settings.object:
            raise ValueError(f"{path}: the checkpoint's {CHECKPOINT_KEY} object differs from its config's object "
                             "(one was edited without the other); the system is built from the config's")
        system.settings = settings  # the system decodes as they say
    size, in_size = system.settings.input.size, getattr(system.backbone, "in_size", None)
    if isinstance(in_size, int) and size != in_size:  # every image would fail on the network's shapes
        key = f"{CHECKPOINT_KEY} input.size" if settings is not None else "config data.input_size"
        raise ValueError(f"{path}: the checkpoint's {key}={size} but its network takes {in_size} x {in_size} pixels "
                         "(model.in_size): one was edited without the other")
    if settings is not None:
        check_framing_agrees(cfg, settings, path)
    try:
        system.load_state_dict(ckpt["state_dict"])
    except (RuntimeError, TypeError, ValueError) as e:  # missing or unexpected keys, wrong tensor shapes
        first = str(e).strip().splitlines()
        detail = " ".join(line.strip() for line in first[:3])[:300]
        raise ValueError(f"{path}: the checkpoint's weights do not fit its config ({detail})") from None
    bad = [name for name, value in system.state_dict().items()
           if value.is_floating_point() and not bool(torch.isfinite(value).all())]
    if bad:
        raise ValueError(f"{path}: the checkpoint's weights hold NaN or inf ({len(bad)} tensor(s), e.g. {bad[0]}): "
                         "a diverged training; use an earlier checkpoint")
    system.eval()
    return system, cfg
