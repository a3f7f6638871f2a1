"""Configs read back from files are data: what they may name for ``hydra.utils.instantiate``.

A checkpoint carries its run's config (``hyper_parameters.config``), and the entry points rebuild
the model from it with ``instantiate``. Checkpoints travel between people, so a ``_target_`` in
such a config could name any importable callable (``{_target_: <writes a file>, _args_: [...]}``).
Every config read back from a file passes :func:`check_saved_config` first: each ``_target_`` at
any depth of the node of a config group must be one that the shipped ``conf/<group>/*.yaml`` files
name, i.e. one of opnet's own components for that group. The other Hydra keys (``_args_``,
``_partial_``, ``_convert_``, ``_recursive_``) only change how an allowed target is called; what
they hold is checked like any other value. Interpolations (``${...}``) are refused as well: a
saved config is resolved when written, and resolving one from a file would build nodes (and
``_target_`` keys) that the check never saw. The user's own command-line config stays unrestricted.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from functools import cache
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from opnet.paths import config_dir

TARGET = "_target_"
#: longest excerpt of a value from the file that an error message quotes
QUOTE_CHARS = 80


@cache
def shipped_targets(group: str) -> frozenset[str]:
    """The ``_target_`` values named at any depth of ``conf/<group>/*.yaml`` (empty for a name
    that is no config group, or a group whose files name no class)."""
    folder = config_dir() / group
    if not group.isidentifier() or not folder.is_dir():  # never a path out of conf/
        return frozenset()
    nodes = [OmegaConf.to_container(OmegaConf.load(f), resolve=False) for f in sorted(folder.glob("*.yaml"))]
    return frozenset(value for node in nodes for _, name, value in _walk(node, group) if name == TARGET)


def _walk(node: Any, path: str) -> Iterator[tuple[str, Any, Any]]:
    """(dotted key, own key, value) of every entry at any depth under ``node`` (at ``path``)."""
    if isinstance(node, Mapping):
        for name, value in node.items():
            yield from _entry(f"{path}.{name}", name, value)
    elif isinstance(node, (list, tuple)):
        for i, value in enumerate(node):
            yield from _entry(f"{path}[{i}]", i, value)


def _entry(path: str, name: Any, value: Any) -> Iterator[tuple[str, Any, Any]]:
    """The entry itself, then every entry under it."""
    yield path, name, value
    yield from _walk(value, path)


def short(text: str, limit: int = QUOTE_CHARS) -> str:
    """``text`` cut to ``limit`` characters (keys, values and errors from files can be huge)."""
    return text if len(text) <= limit else text[: limit - 3] + "..."


def quote(value: Any) -> str:
    """``repr(value)``, cut to :data:`QUOTE_CHARS` characters."""
    return short(repr(value))


def saved_config(config: Any, source: str | Path) -> DictConfig:
    """The config read from ``source`` (a checkpoint, a run directory) as a ``DictConfig``, once
    :func:`check_saved_config` has passed what ``instantiate`` will see of it.

    Raises:
        ValueError: naming ``source``: not a mapping of plain values, or refused by the check.
    """
    if not isinstance(config, Mapping):
        raise ValueError(f"{source}: the saved config is a {type(config).__name__}, not a mapping of config groups")
    try:
        cfg = OmegaConf.create(dict(config))
        plain = OmegaConf.to_container(cfg, resolve=False)
    except (OmegaConfBaseException, ValueError, TypeError, RecursionError) as e:
        raise ValueError(f"{source}: the saved config is not a plain config ({type(e).__name__}: "
                         f"{short(str(e).strip())})") from None
    check_saved_config(plain, source)
    return cfg


def check_saved_config(config: Mapping[str, Any], source: str | Path) -> None:
    """Refuse a config read from ``source`` that names anything other than opnet's own
    components, before any of it is instantiated.

    Args:
        config: the plain config as read, each top-level key a config group (``loss``, ``model``, ...).
        source: the file it was read from, for the message.
    Raises:
        ValueError: naming ``source``, the key and the offending value: a ``_target_`` that is not
            one of the shipped ``conf/<group>/*.yaml`` ones of its group, or an interpolation.
    """
    try:
        for group, node in config.items():
            for key, name, value in _entry(str(group), group, node):
                if isinstance(value, str) and "${" in value:
                    raise ValueError(f"{source}: config key {quote(key)} holds the interpolation {quote(value)}; a "
                                     "saved config is resolved when written, so this one was altered; refused")
                if name == TARGET:
                    _check_target(key, str(group), value, source)
    except RecursionError:
        raise ValueError(f"{source}: the saved config is nested implausibly deep; refused") from None


def _check_target(key: str, group: str, value: Any, source: str | Path) -> None:
    """``value`` of the ``_target_`` at dotted ``key`` is one of ``group``'s shipped targets."""
    allowed = shipped_targets(group)
    if isinstance(value, str) and value in allowed:
        return
    listed = ", ".join(sorted(allowed)) or f"none: conf/{short(group)}/ names no class"
    raise ValueError(f"{source}: config key {quote(key)} names {quote(value)}, not one of opnet's {short(group)} "
                     f"components [{listed}]; a checkpoint's config is data and may only name these")
