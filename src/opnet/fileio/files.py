"""File reads of the dataset readers, with errors that name the file."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path
from typing import Any


def require_regular_file(path: str | Path) -> Path:
    """``path`` if it is a regular file (or a link to one).

    A FIFO, socket or device named like a data file would block a reader forever or stream without
    end (``/dev/zero``); those are refused before anything is opened.

    Raises:
        FileNotFoundError: no such file ("<path>: file not found").
        ValueError: it exists but is a folder, FIFO, socket or device.
    """
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError as e:
        raise FileNotFoundError(f"{path}: file not found") from e
    except OSError as e:
        raise ValueError(f"{path}: cannot read file ({e})") from e
    if not stat.S_ISREG(mode):
        raise ValueError(f"{path}: not a regular file ({file_kind(mode)}); expected a data file")
    return path


def file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` is, for messages: a folder, a FIFO, a socket, a device."""
    return ("a folder" if stat.S_ISDIR(mode) else
            "a FIFO" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode) else
            "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "not a file")


def read_bytes(path: str | Path) -> bytes:
    """The content of ``path``.

    Raises:
        FileNotFoundError: no such file ("<path>: file not found").
        ValueError: the file exists but cannot be read, or is not a regular file (FIFO, device).
    """
    path = require_regular_file(path)
    try:
        return path.read_bytes()
    except FileNotFoundError as e:
        raise FileNotFoundError(f"{path}: file not found") from e
    except OSError as e:
        raise ValueError(f"{path}: cannot read file ({e})") from e


def read_text(path: str | Path) -> str:
    """The UTF-8 content of ``path``; errors as :func:`read_bytes`, ValueError for bad UTF-8."""
    data = read_bytes(path)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not UTF-8 text ({e})") from e


class _NonFinite(Exception):
    pass


def _reject_constant(name: str) -> float:
    raise _NonFinite(name)  # NaN, Infinity, -Infinity: Python's json accepts them, we do not


def read_json(path: str | Path, expected: str = "") -> Any:
    """The JSON content of ``path``, with errors naming it: regular files only, UTF-8, no NaN or
    Infinity, bounded nesting (``expected`` describes the content for the nesting message)."""
    text = read_text(path)
    try:
        return json.loads(text, parse_constant=_reject_constant)
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: malformed JSON ({e.msg} at line {e.lineno}, column {e.colno})") from None
    except RecursionError:
        raise ValueError(f"{path}: JSON nested too deeply" + (f" (expected {expected})" if expected else "")) from None
    except _NonFinite as e:
        raise ValueError(f"{path}: {e} is not a finite number") from None
