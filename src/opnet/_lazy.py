"""Packages whose names are imported on first use (PEP 562), so that a light submodule (the
camera, the records, the averaging) loads without the heavy ones (PyTorch) its package also holds."""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any


def lazy_exports(package: str, where: Mapping[str, str]) -> tuple[Callable[[str], Any], Callable[[], list[str]], list[str]]:
    """``(__getattr__, __dir__, __all__)`` for ``package`` whose name ``n`` lives in submodule
    ``where[n]``; a name is imported at its first use and then kept in the package."""

    def getattr_(name: str) -> Any:
        if name in where:
            value = getattr(importlib.import_module(f"{package}.{where[name]}"), name)
            setattr(sys.modules[package], name, value)
            return value
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    names = sorted(where)
    return getattr_, lambda: names, names
