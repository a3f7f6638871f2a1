"""Let torch-first geometry functions accept numpy arrays too."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import numpy as np
import torch


def numpy_compatible(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Wrap a torch function so numpy inputs give numpy outputs (float64 stays float64).

    Positional array arguments are converted to tensors; if any was a numpy array, every tensor
    in the result (a tensor or a tuple of tensors) is converted back.
    """

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        was_numpy = any(isinstance(a, np.ndarray) for a in args)
        targs = [torch.from_numpy(np.asarray(a)) if isinstance(a, np.ndarray) else a for a in args]
        out = fn(*targs, **kwargs)
        if not was_numpy:
            return out
        if isinstance(out, tuple):
            return tuple(o.numpy() if isinstance(o, torch.Tensor) else o for o in out)
        return out.numpy() if isinstance(out, torch.Tensor) else out

    return wrapper


def as_float_tensor(x: Any, like: torch.Tensor | None = None) -> torch.Tensor:
    """Tensor of a floating dtype (float64 for python/numpy scalars unless `like` says otherwise)."""
    if isinstance(x, torch.Tensor):
        return x if x.is_floating_point() else x.double()
    t = torch.as_tensor(np.asarray(x, dtype=np.float64))
    if like is not None:
        t = t.to(dtype=like.dtype, device=like.device)
    return t
