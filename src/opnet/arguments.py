"""The console tools' command lines: one validation path (docs/reliability.md#the-console-tools).

:class:`ArgumentParser` is argparse whose refusal is one line on stderr, ``error: --option: <what is
wrong>``, and exit status 2 (argparse prints its usage first: two lines). The option types check a value
where it is parsed, before any work: :func:`whole` (a whole number in bounds), :func:`folder` (an existing
folder), :func:`file` (an existing regular file). :func:`variant_settings` reads the ``KEY=VALUE,...``
settings of a variant string (``opnet-oracle --variant``, ``bench_refine.py --variant``) against the keys
a tool documents: a plain value each (text, a number, true / false, null), never an interpolation.

Standard library only: the torch-free ONNX runtime's command line uses it.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, NoReturn


class ArgumentParser(argparse.ArgumentParser):
    """An ``argparse.ArgumentParser`` whose refusal of the command line is one line naming the option."""

    def error(self, message: str) -> NoReturn:
        text = " ".join(message.split()).removeprefix("argument ")
        self.exit(2, f"error: {text}\n")


def _type(name: str, parse: Callable[[str], Any]) -> Callable[[str], Any]:
    parse.__name__ = name  # argparse names a type by it
    return parse


def whole(low: int, high: int | None = None) -> Callable[[str], int]:
    """An option type: a whole number in ``[low, high]`` (``high`` None: no upper bound)."""
    bound = f"in [{low}, {high}]" if high is not None else f">= {low}"

    def parse(text: str) -> int:
        try:
            value = int(text.strip(), 10)
        except ValueError:
            value = None
        if value is None or value < low or (high is not None and value > high):
            raise argparse.ArgumentTypeError(f"{text!r}: expected a whole number {bound}")
        return value

    return _type("whole number", parse)


def _existing(kind: str, ok: Callable[[Path], bool]) -> Callable[[str], Path]:
    def parse(text: str) -> Path:
        path = Path(text)
        if not path.exists():
            raise argparse.ArgumentTypeError(f"{path}: no such {kind}")
        if not ok(path):
            raise argparse.ArgumentTypeError(f"{path}: not a {kind}")
        return path

    return _type(kind, parse)


#: an option type: an existing folder
folder = _existing("folder", Path.is_dir)
#: an option type: an existing regular file
file = _existing("file", Path.is_file)

#: what a setting's value may be: text, a number, true / false, null (parsed as YAML scalars)
PLAIN = (str, int, float, bool, type(None))


def plain_value(text: str, where: str) -> Any:
    """``text`` as the YAML scalar it spells; ValueError naming ``where`` for a list, a mapping, unreadable
    YAML or an interpolation (``${...}``), which a variant never takes."""
    import yaml

    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        value = ...
    if not isinstance(value, PLAIN) or (isinstance(value, str) and "${" in value):
        raise ValueError(f"{where}: expected a plain value (text, a number, true / false, null)")
    return value


def variant_settings(text: str, settings: str, known: Iterable[str], option: str) -> dict[str, Any]:
    """The ``KEY=VALUE,...`` ``settings`` of the variant ``text`` (as given to ``option``), each key one of
    ``known`` and each value plain (:func:`plain_value`).

    Raises:
        ValueError: ``<option> <text>: <item>: ...``, one line naming the setting.
    """
    known = list(known)
    out: dict[str, Any] = {}
    for item in filter(None, settings.split(",")):
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq:
            raise ValueError(f"{option} {text}: {item!r} is no KEY=VALUE setting")
        if key not in known:
            raise ValueError(f"{option} {text}: {key!r} is not one of its settings; expected one of {', '.join(known)}")
        if key in out:
            raise ValueError(f"{option} {text}: {key!r} is given twice; give each setting once")
        out[key] = plain_value(value, f"{option} {text}: {key}={value}")
    return out


def fail(message: str) -> int:
    """Print ``error: <message>`` (one line) on stderr; the exit status of a refusal, 2."""
    print(f"error: {' '.join(message.split())}", file=sys.stderr)
    return 2


__all__ = ["PLAIN", "ArgumentParser", "fail", "file", "folder", "plain_value", "variant_settings", "whole"]
