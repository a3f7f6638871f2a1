"""Near-symmetries about a part's axes: the spins a depth image hardly tells apart (``opnet-object``).

A gear with helical teeth, a wheel with thin spokes inside its rim, a flange with two small notches: no turn
about their axis maps them exactly onto themselves, yet every turn moves almost all of their surface by less
than the metric's threshold δ. The network is then asked for a spin the depth image barely shows, and the
metric, told the part has no such symmetry, counts every spin it misses as a wrong pose.

:func:`near_axis` looks at the spins about the part's main axis (its symmetry's axis, or the principal
axis of the surface that stands apart: a flat part's normal): the *spin profile*, the deviation (the 98th percentile of how far the surface moves, as
:mod:`opnet.objects.symmetry_finder` measures a symmetry) of the turns by every 2° up to a half turn. Where
every turn stays under δ the axis is a **near-revolution**; else, where every multiple of 360/k degrees does
(k from 72 down to one above the order the part has about that axis), it is **near-cyclic** of order k (the
highest such k).
:func:`declared` turns a report into the one that declares it (``opnet-object --declare-near``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from opnet.objects.symmetry_finder import (
    MAX_ORDER,
    Candidate,
    SymmetryReport,
    _axis_of,
    _axis_rotation,
    _flip_across,
    _frame,
    _principal,
    _same_axis,
    _Surface,
)

#: the spin profile's step (degrees)
PROFILE_STEP_DEG = 2.0


@dataclass(frozen=True)
class NearAxis:
    """A near-symmetry about one axis (module docstring).

    Attributes:
        axis: (3,) unit, the file's frame. order: None for a near-revolution, else k.
        deviation: metres, the largest deviation over the turns it takes (every turn, or every 360/k).
        delta: metres, the threshold it is under (δ = 0.1 D).
    """

    axis: np.ndarray
    order: int | None
    deviation: float
    delta: float

    @property
    def kind(self) -> str:
        return "revolution" if self.order is None else "cyclic"

    def spec(self, rotoreflection: bool = False) -> dict:
        """The ``symmetry`` entry that declares it."""
        if self.order is None:
            return {"kind": "revolution", "rotoreflection": rotoreflection}
        return {"kind": "cyclic", "order": self.order}

    def text(self, model_rotation: np.ndarray) -> str:
        """E.g. ``near-revolution about [+0.00, +0.00, +1.00] (model frame): every turn moves 98 % of the surface
        by at most 2.31 mm (delta 7.03 mm)``."""
        a = model_rotation @ self.axis
        a = -a if a[np.abs(a).argmax()] < 0 else a
        where = f"about [{', '.join(f'{v:+.2f}'.replace('-0.00', '+0.00') for v in a)}] (model frame)"
        turns = "every turn" if self.order is None else f"every {360.0 / self.order:.4g} deg turn"
        name = "near-revolution" if self.order is None else f"near-cyclic {self.order}"
        return (f"{name} {where}: {turns} moves 98 % of the surface by at most {self.deviation * 1000:.2f} mm "
                f"(delta {self.delta * 1000:.2f} mm)")  # fmt: skip


def spin_profile(surface: _Surface, axis: np.ndarray, step_deg: float = PROFILE_STEP_DEG) -> tuple[np.ndarray, np.ndarray]:
    """(angles in degrees, deviations in metres) of the turns about ``axis`` by every ``step_deg`` up to 180."""
    angles = np.arange(step_deg, 180.0 + 1e-9, step_deg)
    return angles, np.array([surface.deviation(_axis_rotation(axis, math.radians(a))) for a in angles])


def _axis_order(report: SymmetryReport, axis: np.ndarray) -> int | None:
    """The order the declared group has about ``axis`` (1: none; None: the revolution axis)."""
    if report.spec.get("kind") == "revolution":
        if _same_axis(report.model_rotation.T @ np.array([0.0, 0.0, 1.0]), axis):
            return None
        return 1
    order = 1
    for G in report.group[1:]:
        a, _ = _axis_of(G)
        if _same_axis(a, axis):
            order += 1
    return order


def main_axis(surface: _Surface, report: SymmetryReport) -> np.ndarray:
    """The part's main axis (file frame): its symmetry's (the model's z) where it has one, else the principal
    axis of the surface whose spread stands farthest (in ratio) from the other two (a flat part's normal)."""
    if report.spec.get("kind", "none") != "none":
        return report.model_rotation.T @ np.array([0.0, 0.0, 1.0])
    spreads, V = _principal(surface.covariance)
    s = np.log(np.maximum(spreads, 1e-12))
    apart = [min(abs(s[i] - s[j]) for j in range(3) if j != i) for i in range(3)]
    return V[:, int(np.argmax(apart))]


def near_axis(mesh, report: SymmetryReport, samples: int = 3000, seed: int = 0) -> NearAxis | None:
    """The part's near-symmetry of highest order about its main axis (:func:`main_axis`), under δ = 0.1 D
    (module docstring), or None (none, or the main axis is a revolution axis already)."""
    surface = _Surface(mesh, samples, seed)
    delta = 0.1 * report.diameter
    axis = main_axis(surface, report)
    exact = _axis_order(report, axis)
    if exact is None:
        return None  # a revolution axis already
    angles, devs = spin_profile(surface, axis)
    if devs.max() < delta:
        return NearAxis(axis, None, float(devs.max()), delta)
    for k in range(MAX_ORDER, exact, -1):
        if k % exact:
            continue  # a near-symmetry contains the exact one
        multiples = [360.0 * m / k for m in range(1, k // 2 + 1)]
        # the profile screens (its nearest turns), then the turns themselves are measured, the worst of the
        # profile first: a turn that fails ends the check
        if np.interp(multiples, angles, devs).max() > 1.5 * delta:
            continue
        worst = 0.0
        for a in sorted(multiples, key=lambda a: -float(np.interp(a, angles, devs))):
            worst = max(worst, surface.deviation(_axis_rotation(axis, math.radians(a))))
            if worst >= delta:
                break
        if worst < delta:
            return NearAxis(axis, k, float(worst), delta)
    return None


def declared(report: SymmetryReport, near: NearAxis, mesh, samples: int = 3000, seed: int = 0) -> SymmetryReport:
    """The report with ``near`` declared as the part's symmetry: its axis onto the model's z (the model frame kept
    where it is there already); a near-revolution keeps an exact half turn across it (rotoreflection) where the
    part has one."""
    surface = _Surface(mesh, samples, seed)
    found: list[Candidate] = list(report.found)
    # the model frame is kept where the axis is its z already (the part's poses, and data made of it, unchanged)
    keep = _same_axis(near.axis, report.model_rotation.T @ np.array([0.0, 0.0, 1.0]))
    if near.order is None:
        flip = _flip_across(surface, near.axis, report.tolerance, found, [])
        R = report.model_rotation if keep and flip is None else _frame(near.axis, flip)
        group = np.stack([np.eye(3), np.diag([1.0, -1.0, -1.0])]) if flip is not None else np.eye(3)[None]
        name = "D-inf" if flip is not None else "C-inf"
        spec = near.spec(flip is not None)
    else:
        R = report.model_rotation if keep else _frame(near.axis, None)
        group = np.stack([_axis_rotation(near.axis, 2 * math.pi * m / near.order) for m in range(near.order)])
        name, spec = f"C{near.order}", near.spec()
    rejected = [c for c in report.rejected if not _same_axis(c.axis, near.axis)]  # turns about the axis: declared
    return replace(report, spec=spec, name=name, model_rotation=R, group=group, found=found, rejected=rejected)


__all__ = ["NearAxis", "declared", "near_axis", "spin_profile"]
