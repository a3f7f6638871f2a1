"""Fresh spins for the views of a settled pile (``scene.view_spin``, docs/data.md#fresh-spins-per-view).

With ``scene.views`` > 1 every view of a pile shows the same parts in the same poses, seen from a slightly other
camera: 24 piles of 75 drops hold 1800 spins about the parts' own axes whatever the number of views. A part whose
spin is what the network must read (a wheel's spokes, a flange's bolt circle) is then seen in few spins.

A part whose **convex hull is a body of revolution about its model z-axis** (a wheel, a rim, a gear, a flange: the
features that set its spin lie inside its envelope) touches its neighbours and the bin the same way whatever its
turn about that axis, so the pile stays a pile when every part is turned about its own axis. ``scene.view_spin``
does that for every view after the first (view 0 keeps the spins the physics made): each part of the pile gets a
spin of its own, drawn uniformly per view and held through the cycle's drops, so each view shows new spins of the
same settled pile. The generator refuses it for a part whose hull is not such a body
(:func:`hull_spin_gap` over ``scene.view_spin_tolerance`` × D). Off by default; ``scene.view_spin=auto`` (the dense
recipe's setting, :func:`resolve_view_spin`) turns it on for exactly the parts it fits: such a hull, spins that are
not free (no revolution symmetry) and more than one view per pile (docs/data.md#fresh-spins-per-view).

A part whose hull is also **symmetric about its mid-plane across z** (a wheel whose hub sits off the middle of its
rim inside the rim's envelope) touches its neighbours the same way turned end over end about a diameter through the
hull's middle. ``scene.view_flip`` turns half the parts of every view after the first so (each part's own draw,
from a stream apart from the spins': with ``view_spin`` the spins are those it makes alone), so that the views
show the part's faces both ways up in the same places; refused for a part whose hull is not so
(:func:`hull_flip`). Off unless set (docs/data.md#fresh-flips-per-view).
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np
import trimesh

from opnet.geometry.symmetry import cyclic_group
from opnet.synthesis.physics import CycleStates

if TYPE_CHECKING:
    from opnet.objects import ObjectModel
    from opnet.synthesis.config import SceneConfig

#: entropy tag of a view's spin stream (SeedSequence([seed, pile, view, SPIN_STREAM]))
SPIN_STREAM = 0x5917
#: entropy tag of a view's flip stream (SeedSequence([seed, pile, view, FLIP_STREAM]))
FLIP_STREAM = 0xF11B
#: turns about z at which the hull is tested (every 5 degrees)
HULL_TURNS = 72


def hull_spin_gap(mesh: trimesh.Trimesh, turns: int = HULL_TURNS) -> float:
    """How far (mesh units) the part's convex hull, turned about the model z-axis, reaches out of itself: the
    largest distance of a turned hull vertex beyond the hull's face planes over ``turns`` turns of the circle.
    0 for a body of revolution about z (up to its tessellation); a wheel's rim gives about its facets' sag."""
    hull = mesh.convex_hull
    vertices = np.asarray(hull.vertices, np.float64)
    return max((_beyond_hull(hull, vertices @ g.T) for g in cyclic_group(int(turns))[1:]), default=0.0)


def _beyond_hull(hull: trimesh.Trimesh, points: np.ndarray) -> float:
    """How far (mesh units) the farthest of ``points`` (N, 3) lies beyond the face planes of the convex ``hull``."""
    normals = np.asarray(hull.face_normals, np.float64)
    offsets = (normals * np.asarray(hull.triangles, np.float64)[:, 0]).sum(-1)
    return float((np.asarray(points, np.float64) @ normals.T - offsets).max())


def hull_flip(mesh: trimesh.Trimesh) -> tuple[float, float]:
    """``(centre, gap)``: the z (mesh units) of the convex hull's mid-plane across z, and how far the hull turned
    end over end about the x-axis through (0, 0, centre) reaches out of itself (0 for a hull symmetric about that
    plane, up to its tessellation)."""
    hull = mesh.convex_hull
    lo, hi = np.asarray(hull.bounds, np.float64)[:, 2]
    centre = 0.5 * (lo + hi)
    vertices = np.asarray(hull.vertices, np.float64) * np.array([1.0, -1.0, -1.0]) + np.array([0.0, 0.0, 2 * centre])
    return float(centre), _beyond_hull(hull, vertices)


def check_flippable(mesh: trimesh.Trimesh, diameter: float, tolerance: float, name: str) -> float:
    """The z of the hull's mid-plane (:func:`hull_flip`) where the hull turned end over end about it stays within
    ``tolerance`` × ``diameter`` of itself; ValueError, one line naming the part and the figures, otherwise."""
    centre, gap = hull_flip(mesh)
    if gap > tolerance * diameter:
        raise ValueError(
            f"scene.view_flip: {name}'s convex hull is not symmetric about its mid-plane across its z-axis: turned "
            f"end over end, the hull reaches {1e3 * gap:.2f} mm ({100 * gap / diameter:.2f} % of D) out of itself, "
            f"over scene.view_spin_tolerance={tolerance:g} of D, so a part turned in a settled pile would go "
            "through its neighbours (set scene.view_flip=false)"
        )
    return centre


def hull_spins_within(mesh: trimesh.Trimesh, diameter: float, tolerance: float) -> tuple[bool, float]:
    """Whether the part's hull is a body of revolution about z within ``tolerance`` × ``diameter`` (the rule of
    ``scene.view_spin``), and :func:`hull_spin_gap` behind it."""
    gap = hull_spin_gap(mesh)
    return gap <= tolerance * diameter, gap


def fresh_spins_fit(mesh: trimesh.Trimesh, diameter: float, tolerance: float, revolution: bool) -> tuple[bool, float]:
    """The part rule of ``scene.view_spin=auto`` (one rule for the generator and ``opnet-object``): the hull is a
    body of revolution about z within ``tolerance`` × ``diameter`` (:func:`hull_spins_within`) and the spins are not
    free (``revolution``: a revolution symmetry makes every spin the same pose); the hull's gap behind it (nan where
    the spins are free: not measured)."""
    if revolution:
        return False, float("nan")
    return hull_spins_within(mesh, diameter, tolerance)


def resolve_view_spin(scene: SceneConfig, obj: ObjectModel) -> SceneConfig:
    """``scene`` with ``view_spin=auto`` decided for ``obj`` (else as given): on where the part fits
    (:func:`fresh_spins_fit`) and a pile has more than one view; off otherwise."""
    if scene.view_spin != "auto":
        return scene
    on = (scene.views > 1 and obj.mesh is not None
          and fresh_spins_fit(obj.mesh, obj.diameter, scene.view_spin_tolerance, obj.symmetry.is_revolution)[0])
    return dataclasses.replace(scene, view_spin=bool(on))


def check_spinnable(mesh: trimesh.Trimesh, diameter: float, tolerance: float, name: str) -> None:
    """Refuse ``scene.view_spin`` for a part whose hull is not a body of revolution about z within
    ``tolerance`` × ``diameter`` (ValueError, one line naming the part and the figures)."""
    within, gap = hull_spins_within(mesh, diameter, tolerance)
    if not within:
        raise ValueError(
            f"scene.view_spin: {name}'s convex hull is not a body of revolution about its z-axis: turned about "
            f"it, the hull reaches {1e3 * gap:.2f} mm ({100 * gap / diameter:.2f} % of D) out of itself, over "
            f"scene.view_spin_tolerance={tolerance:g} of D, so a part turned in a settled pile would go through its "
            "neighbours (set scene.view_spin=false, or write the part with its axis of revolution as z)"
        )


def spin_rng(seed: int, pile: int, view: int) -> np.random.Generator:
    """The spin stream of view ``view`` of pile ``pile`` (independent of its camera's, :func:`view_rng`)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(pile), int(view), SPIN_STREAM]))


def spin_turns(rng: np.random.Generator, parts: int) -> np.ndarray:
    """(parts, 4, 4) turns about the model z-axis by angles drawn uniformly from [0, 2π)."""
    angle = rng.uniform(0.0, 2.0 * np.pi, int(parts))
    T = np.tile(np.eye(4), (int(parts), 1, 1))
    T[:, 0, 0], T[:, 0, 1] = np.cos(angle), -np.sin(angle)
    T[:, 1, 0], T[:, 1, 1] = np.sin(angle), np.cos(angle)
    return T


def flip_rng(seed: int, pile: int, view: int) -> np.random.Generator:
    """The flip stream of view ``view`` of pile ``pile`` (independent of its camera's and its spins')."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(pile), int(view), FLIP_STREAM]))


def flip_turns(rng: np.random.Generator, parts: int, centre: float) -> np.ndarray:
    """(parts, 4, 4): for each part drawn with probability 1/2, the turn end over end about the x-axis through
    (0, 0, ``centre``) (model frame, metres); the identity for the others."""
    flip = rng.random(int(parts)) < 0.5
    T = np.tile(np.eye(4), (int(parts), 1, 1))
    T[flip, 1, 1] = T[flip, 2, 2] = -1.0
    T[flip, 2, 3] = 2.0 * centre
    return T


def spun(states: CycleStates, turns: np.ndarray) -> CycleStates:
    """The cycle's piles with part i turned by ``turns[i]`` about its own model z-axis after every drop."""
    poses = [T @ turns[: len(T)] for T in states.T_world_obj]
    return dataclasses.replace(states, T_world_obj=poses)
