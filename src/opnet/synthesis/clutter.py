"""Foreign parts on the bin floor (``scene.clutter``): what real cells hold besides the part.

Real bins rarely hold one kind of part only: the IPD basket holds round and gear-like parts under
and around the plates, and a network trained on clean piles meets them first on the real frames.
``scene.clutter`` lays that many foreign pieces on the floor of every pile before the parts fall:

- shapes: discs (flat cylinders, as washers, flanges, gears are at a few millimetres a pixel) and
  flat boxes (brackets, bars), half of each on average; sizes drawn relative to the part's radius
  ``r`` (a disc's radius 0.3-0.7 r, a box's sides 0.4-1.4 r by 0.2-0.8 r, heights 0.1-0.4 r,
  always below ``r`` so that a part spawned over one still clears it);
- poses: lying on the floor, any yaw, anywhere the piece fits inside the walls; pieces may touch or
  overlap one another (a heap of foreign parts);
- physics: static bodies of the bin (MuJoCo primitives), so the parts land on and against them;
- rendering: drawn with the bin (segmentation 0: not parts), occluding the parts behind them;
  the ground truth and the visibility of the parts are otherwise unchanged.

Random numbers come from a stream of their own (``cycle_rngs``'s third child), so a dataset without
clutter is byte-identical to one made before clutter existed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from opnet.synthesis.layout import homogeneous

#: the shapes a clutter piece can take
SHAPES = ("disc", "box")
_DISC_RADIUS = (0.3, 0.7)  # x the part's radius
_BOX_HALF_X = (0.2, 0.7)
_BOX_HALF_Y = (0.1, 0.4)
_HALF_HEIGHT = (0.05, 0.2)
_DISC_SECTIONS = 24


@dataclass(frozen=True)
class ClutterPiece:
    """One foreign piece: ``shape`` in :data:`SHAPES`, ``half`` its half extents (3,) in its own frame
    (a disc: radius, radius, half height), ``T_bin_piece`` (4, 4) its pose in the bin frame (metres;
    its centre, lying on the floor)."""

    shape: str
    half: tuple[float, float, float]
    T_bin_piece: np.ndarray


def sample_clutter(count: int, sides: tuple[float, float], radius: float,
                   rng: np.random.Generator) -> tuple[ClutterPiece, ...]:  # fmt: skip
    """``count`` pieces lying on a floor of inner ``sides`` (x, y metres), sized relative to the
    part's ``radius`` (metres)."""
    pieces = []
    for _ in range(int(count)):
        hz = radius * rng.uniform(*_HALF_HEIGHT)
        if rng.random() < 0.5:
            rr = radius * rng.uniform(*_DISC_RADIUS)
            shape, half, reach_r = "disc", (rr, rr, hz), rr
        else:
            hx, hy = radius * rng.uniform(*_BOX_HALF_X), radius * rng.uniform(*_BOX_HALF_Y)
            shape, half, reach_r = "box", (hx, hy, hz), math.hypot(hx, hy)
        yaw = rng.uniform(-math.pi, math.pi)
        reach = np.maximum(np.asarray(sides) / 2.0 - reach_r, 0.0)
        x, y = rng.uniform(-reach, reach)
        c, s = math.cos(yaw), math.sin(yaw)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        pieces.append(ClutterPiece(shape, (float(half[0]), float(half[1]), float(hz)),
                                   homogeneous(R, np.array([x, y, hz]))))  # fmt: skip
    return tuple(pieces)


def clutter_mesh(pieces: tuple[ClutterPiece, ...]) -> trimesh.Trimesh | None:
    """The pieces as one triangle mesh in the bin frame (for rendering); None without pieces."""
    if not pieces:
        return None
    meshes = []
    for p in pieces:
        if p.shape == "disc":
            m = trimesh.creation.cylinder(radius=p.half[0], height=2.0 * p.half[2], sections=_DISC_SECTIONS)
        else:
            m = trimesh.creation.box(extents=2.0 * np.asarray(p.half))
        m.apply_transform(p.T_bin_piece)
        meshes.append(m)
    return trimesh.util.concatenate(meshes)
