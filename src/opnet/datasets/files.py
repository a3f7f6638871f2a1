"""File reads of the dataset readers, with errors that name the file."""

from __future__ import annotations

from pathlib import Path


def read_bytes(path: str | Path) -> bytes:
    """The content of ``path``.

    Raises:
        FileNotFoundError: no such file ("<path>: file not found").
        ValueError: the file exists but cannot be read.
    """
    path = Path(path)
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
