"""Plausibility checks of ground-truth values, done once where they are read (the readers).

Tolerances (documented in docs/reliability.md):
- a rotation must be orthonormal to ``ORTHONORMAL_TOL`` (max |RᵀR − I|; the official data is
  orthonormal to ~1e-6, values written with six decimals to ~1e-6) with det(R) = +1: a scaled
  matrix or a reflection is not a pose;
- a translation must be finite and within ``MAX_TRANSLATION_M`` of the camera or world origin (a
  value of 1e300 or millimetres read as metres is not a part in a bin);
- IPA visibility scores must lie in [0, ``MAX_IPA_VISIBILITY``] (the perspective score can exceed
  1 a little, the data format documents it; −5 or 50 are not visibilities); Siléane occlusion
  rates in [0, 1].
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

ORTHONORMAL_TOL = 1e-4
MAX_TRANSLATION_M = 100.0
MAX_IPA_VISIBILITY = 2.0


def check_poses(R: np.ndarray, t: np.ndarray, where: Callable[[int], str]) -> None:
    """Rotations (N, 3, 3) proper and orthonormal, translations (N, 3) finite and plausible.

    Args:
        where: entry index -> a prefix naming the file and the entry (line) for the message.
    Raises:
        ValueError: for the first bad entry, with the count of bad entries.
    """
    if len(R) == 0:
        return
    if not (np.isfinite(R).all() and np.isfinite(t).all()):
        i = int(np.flatnonzero(~(np.isfinite(R).reshape(len(R), -1).all(1) & np.isfinite(t).all(1)))[0])
        raise ValueError(f"{where(i)}: the pose holds NaN or inf")
    bad = not_rotations(R)
    if bad:
        i, what = bad[0]
        raise ValueError(f"{where(i)}: the rotation is not a rotation matrix ({what}; {len(bad)} such entries)")
    far = np.flatnonzero(np.linalg.norm(t, axis=1) > MAX_TRANSLATION_M)
    if len(far):
        i = int(far[0])
        raise ValueError(f"{where(i)}: translation {np.array2string(t[i], precision=4)} m is implausible "
                         f"(more than {MAX_TRANSLATION_M:g} m away; millimetres instead of metres?)")


def not_rotations(R: np.ndarray) -> list[tuple[int, str]]:
    """The matrices of ``R`` (N, 3, 3) that are no rotation, as (index, why) pairs: NaN or inf, not
    orthonormal to ``ORTHONORMAL_TOL``, or a reflection (det(R) = -1)."""
    R = np.asarray(R, np.float64).reshape(-1, 3, 3)
    finite = np.isfinite(R).reshape(len(R), -1).all(1)
    safe = np.where(finite[:, None, None], R, np.eye(3))
    err = np.abs(np.swapaxes(safe, 1, 2) @ safe - np.eye(3)).reshape(len(R), -1).max(1)
    det = np.linalg.det(safe)
    bad = []
    for i in np.flatnonzero(~finite | (err > ORTHONORMAL_TOL) | (det < 0)):
        why = ("holds NaN or inf" if not finite[i] else
               f"|R^T R - I| = {err[i]:.3g} > {ORTHONORMAL_TOL:g}, not orthonormal" if err[i] > ORTHONORMAL_TOL
               else "det(R) = -1, a reflection")
        bad.append((int(i), why))
    return bad


def check_range(values: np.ndarray, low: float, high: float, name: str, where: Callable[[int], str]) -> None:
    """Every value finite and in [low, high]; ValueError naming the first bad entry otherwise."""
    values = np.asarray(values, np.float64)
    bad = np.flatnonzero(~np.isfinite(values) | (values < low) | (values > high))
    if len(bad):
        i = int(bad[0])
        raise ValueError(f"{where(i)}: {name} = {values[i]:g} is outside [{low:g}, {high:g}] "
                         f"({len(bad)} such entries)")
