"""Bounded reprs for error messages that quote an input value."""

from __future__ import annotations

import reprlib
from typing import Any

_SHORT = reprlib.Repr()  # attributes, not keywords: Python 3.11's Repr takes none
_SHORT.maxlevel, _SHORT.maxlist, _SHORT.maxdict, _SHORT.maxtuple, _SHORT.maxset = 2, 4, 4, 4, 4
_SHORT.maxstring, _SHORT.maxother, _SHORT.maxlong = 40, 40, 40
MAX_REPR_CHARS = 80


def short_repr(value: Any) -> str:
    """``repr(value)`` cut to at most :data:`MAX_REPR_CHARS` characters, for error messages that quote
    an input value: a YAML alias bomb of 301 bytes has a 39 MB repr, and ``reprlib`` never walks it."""
    text = _SHORT.repr(value)
    return text if len(text) <= MAX_REPR_CHARS else text[: MAX_REPR_CHARS - 3] + "..."
