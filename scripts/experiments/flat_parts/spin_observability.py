"""Does the depth show a part's spin about its main axis? An isolated part, rendered at the network's pixels.

A part is rendered alone (the project's renderer, no bin) with its main axis tilted by each ``--tilts`` angle
from the line of sight, and again turned about that axis by each ``--spins`` angle; each render is brought to
the network input as the recipes frame a part (D across ``--pixels`` pixels of it, rendered at four times that
and each input pixel the median of its 4 x 4, as the generated 512-pixel images reach the 128-pixel input). The
table counts the input pixels whose depth a spin changes by more than ``--change`` x D (or that it covers or
uncovers): what a network could read the spin from, before any neighbour hides part of it. A column near 0 is a spin the depth
does not hold; a depth that changes under every spin holds it, whether or not a network learns to read it.

    python scripts/experiments/flat_parts/spin_observability.py --object itodd08 --pixels 45 90

Prints a table (``--out``: also writes it, with the command, as a Markdown page).
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402

from opnet.geometry.camera import Camera  # noqa: E402
from opnet.geometry.pose_numpy import rodrigues  # noqa: E402
from opnet.metrics.breakdown import main_axis  # noqa: E402
from opnet.objects import object_from_config  # noqa: E402
from opnet.studies import compose_train, write_table_page  # noqa: E402
from opnet.synthesis.rendering import SceneRenderer  # noqa: E402

#: the render's side over the input's (the generated images are 512 pixels, the recipes' input 128)
SUPERSAMPLE = 4


def frame(axis: np.ndarray, tilt_deg: float) -> np.ndarray:
    """(3, 3) part-to-camera rotation putting the part's main ``axis`` at ``tilt_deg`` from the line of sight
    (the camera's +z, tipped towards the camera's x)."""
    a = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(a[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(a, helper)
    u /= np.linalg.norm(u)
    base = np.stack([np.cross(u, a), u, a])  # rows: the part's frame with its axis onto the camera's z
    return rodrigues(np.array([0.0, 1.0, 0.0]), math.radians(tilt_deg)) @ base


def input_depth(renderer: SceneRenderer, R: np.ndarray, distance: float, size: int, far: float) -> np.ndarray:
    """The part at rotation ``R`` and ``distance`` on the optical axis, rendered and brought down to ``size``."""
    T = np.eye(4)
    T[:3, :3], T[2, 3] = R, distance
    depth = renderer.render(T[None]).depth
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, far).astype(np.float32)
    k = depth.shape[0] // size
    # each input pixel the median of its k x k rendered ones: a pixel on the outline takes the depth most of it
    # sees, so a turn that moves the outline by a sliver (a body of revolution's facets) changes no pixel
    return np.median(depth.reshape(size, k, size, k), axis=(1, 3))


def observability(obj, tilts: list[float], spins: list[float], pixels: float, change: float,
                  size: int = 128) -> list[tuple[float, int, list[int]]]:  # fmt: skip
    """Per tilt: (tilt, the part's input pixels, the pixels each spin changes by more than ``change`` x D)."""
    D = float(obj.diameter)
    axis = main_axis(obj.pose_space)
    big = size * SUPERSAMPLE
    f = big * 0.5 / math.tan(math.radians(25.0))  # a 50° camera
    distance = f * D / (pixels * SUPERSAMPLE)
    far = distance + 4 * D
    camera = Camera(f, f, (big - 1) / 2, (big - 1) / 2, big, big, max(distance - D, 0.1 * distance), far)
    renderer = SceneRenderer(obj.mesh, camera)
    rows = []
    try:
        for tilt in tilts:
            R0 = frame(axis, tilt)
            d0 = input_depth(renderer, R0, distance, size, far)
            part = d0 < far - 1e-6
            changed = []
            for spin in spins:
                d = input_depth(renderer, R0 @ rodrigues(axis, math.radians(spin)), distance, size, far)
                changed.append(int((np.abs(d - d0) > change * D).sum()))
            rows.append((tilt, int(part.sum()), changed))
    finally:
        renderer.close()
    return rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--object", required=True, help="a conf/object name")
    ap.add_argument("--tilts", type=float, nargs="+", default=[0, 20, 40, 45, 50, 55, 60, 75, 90])
    ap.add_argument("--spins", type=float, nargs="+", default=[6, 12, 18, 24, 30, 36])
    ap.add_argument("--pixels", type=float, nargs="+", default=[45.0],
                    help="D across this many input pixels (the recipes: ~45); several: a table each")
    ap.add_argument("--change", type=float, default=0.015, help="a depth change counts above this share of D")
    ap.add_argument("--out", type=Path, help="also write the tables here (Markdown)")
    args = ap.parse_args(argv)
    obj = object_from_config(compose_train([f"object={args.object}"]).object)
    lines: list[str] = []
    for pixels in args.pixels:
        rows = observability(obj, args.tilts, args.spins, pixels, args.change)
        lines += [f"{args.object}: D {1000 * obj.diameter:.1f} mm across {pixels:g} input pixels; input pixels whose "
                  f"depth a spin about the main axis changes by more than {args.change:g} D "
                  f"({1000 * args.change * obj.diameter:.1f} mm)", "",
                  "| axis from the line of sight | part pixels | " + " | ".join(f"spin {s:g}°" for s in args.spins)
                  + " |", "|---" * (len(args.spins) + 2) + "|"]  # fmt: skip
        lines += [f"| {tilt:g}° | {part} | " + " | ".join(str(c) for c in changed) + " |"
                  for tilt, part, changed in rows]
        lines.append("")
    print("\n".join(lines))
    if args.out:
        write_table_page(args.out, "What the depth shows of a spin about the main axis", lines)


if __name__ == "__main__":
    main()
