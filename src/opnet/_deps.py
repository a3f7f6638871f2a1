"""Optional heavy dependencies, asked for where they are needed with a message that says what to do.

The generator needs a physics engine (MuJoCo by default, pybullet on request: its wheels stop at
CPython 3.11) and pyrender (rendering); training on data generated elsewhere, evaluation,
prediction and export need neither.
"""

from __future__ import annotations

import importlib.util


class MissingDependencyError(ImportError):
    """An optional package a command needs is not installed (a user's environment, not a bug)."""


def require(module: str, purpose: str, hint: str = "") -> None:
    """Raise :class:`MissingDependencyError` naming ``purpose`` when ``module`` cannot be imported."""
    if importlib.util.find_spec(module) is None:
        raise MissingDependencyError(f"{purpose} needs the package '{module}', which is not installed"
                                     f"{'; ' + hint if hint else ''}")


__all__ = ["MissingDependencyError", "require"]
