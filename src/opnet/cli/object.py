"""``opnet-object``: inspect a part's CAD mesh and write its object config.

    opnet-object <mesh> [--name N] [--out conf/object/N.yaml] [--units auto|m|cm|mm|in] [--tolerance-mm T]
                 [--declare-near]

Reads the mesh (any shells, watertight or not), states its units (``auto``: a largest extent up to 3 in file
units is metres, above it millimetres; say so otherwise), measures it (extent, diameter D as the metric
defines it, δ = 0.1 D, Λ), finds its proper symmetry group (:mod:`opnet.objects.symmetry_finder`; tolerance
1 % of D unless ``--tolerance-mm``, printed with every candidate's deviation), turns the main symmetry axis
onto z (``model_rotation``) about the symmetry centre (``model_origin``), and writes the YAML and a preview
PNG beside it (the part from three sides with its axes). It names the part's near-symmetries: a turn it
rejects that still moves 98 % of the surface by less than δ, and about the main axis a near-revolution (every
turn under δ) or a near-cyclic order (every 360/k turn under δ; :mod:`opnet.objects.near_symmetry`), which a
depth image hardly tells apart and the metric counts as wrong poses; ``--declare-near`` declares the latter.
Bad input is one line naming the file, exit 2, nothing written.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
from pathlib import Path
from typing import Any

import numpy as np

from opnet.arguments import ArgumentParser, fail

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}
#: a bin-picking part is this big (metres, largest extent) or the units are wrong
PART_SIZE = (0.003, 3.0)
#: an object's name: its config is conf/object/<name>.yaml, a Hydra option (``object=<name>``)
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]{0,63}")
#: the names an object config takes
CONFIG_SUFFIXES = (".yaml", ".yml")


def read_part(path: Path, units: str) -> tuple[Any, float, str]:
    """(mesh in metres, the scale applied, what was assumed); ValueError naming the file."""
    import trimesh

    from opnet.objects.io import load_mesh

    try:
        raw = load_mesh(path)
    except FileNotFoundError as e:  # no such file is no file trimesh cannot read
        raise ValueError(str(e)) from None
    except ValueError as e:
        raise ValueError(str(e) if str(path) in str(e) else f"{path}: {e}") from None
    except Exception as e:  # noqa: BLE001  (a file trimesh cannot parse)
        raise ValueError(f"{path}: not a mesh trimesh can read ({type(e).__name__}: {e})") from None
    if not isinstance(raw, trimesh.Trimesh) or len(raw.faces) == 0:
        raise ValueError(f"{path}: not a mesh: no triangles in the file")
    largest = float(raw.extents.max())
    if not (math.isfinite(largest) and largest > 0):
        raise ValueError(f"{path}: the mesh has no extent (its vertices lie in one point, {largest:g} file units "
                         "across, as read): not a part")
    if units == "auto":
        units = "m" if largest <= PART_SIZE[1] else "mm"
        assumed = f"units: {units} (assumed from its largest extent, {largest:g} file units; give --units otherwise)"
    else:
        assumed = f"units: {units} (given)"
    scale = UNITS[units]
    size = largest * scale
    if not PART_SIZE[0] <= size <= PART_SIZE[1]:
        likely = min(UNITS, key=lambda u: abs(math.log(largest * UNITS[u] / 0.1)))
        raise ValueError(f"{path}: in {units} the part would be {size * 1000:g} mm across, not a part to pick "
                         f"({PART_SIZE[0] * 1000:g} mm to {PART_SIZE[1]:g} m); the file is probably in {likely}: "
                         f"--units {likely}")  # fmt: skip
    raw.apply_scale(scale)
    _check_shape(raw, path)
    return raw, scale, assumed


def _check_shape(mesh: Any, path: Path) -> None:
    """Refuse two far-apart shells and a flat sheet; ValueError naming the file."""
    shells = mesh.split(only_watertight=False)
    if len(shells) > 1:
        boxes = [s.bounds for s in shells]
        size = float(mesh.extents.max())
        big = max(range(len(shells)), key=lambda i: shells[i].area)
        for i, b in enumerate(boxes):
            gap = np.maximum(np.maximum(boxes[big][0] - b[1], b[0] - boxes[big][1]), 0.0)
            if i != big and float(np.linalg.norm(gap)) > 0.25 * size:
                raise ValueError(f"{path}: {len(shells)} shells, one {float(np.linalg.norm(gap)) * 1000:.0f} mm away from the "
                                 "largest: several parts in one file? give one part per mesh")  # fmt: skip
    thin = float(np.sort(mesh.extents)[0])
    if thin < 1e-3 * float(mesh.extents.max()) or thin < 1e-5:
        raise ValueError(f"{path}: a flat sheet ({thin * 1000:.3g} mm thick across {mesh.extents.max() * 1000:.0f} mm): "
                         "a part needs a thickness a depth camera can see")


def inspect_part(path: Path, units: str = "auto", tolerance_mm: float | None = None) -> tuple[Any, float, str, Any]:
    """The part's mesh in metres, its scale, what was assumed of its units, and its symmetry report at
    ``tolerance_mm`` (default 1 % of the diameter about the centroid). Raises ValueError on bad input."""
    from opnet.objects.symmetry_finder import find_symmetry

    mesh, scale, assumed = read_part(path, units)
    centroid_d = 2.0 * float(np.linalg.norm(mesh.vertices - mesh.centroid, axis=1).max())
    delta_mm = 100.0 * centroid_d  # 0.1 D, in millimetres
    if tolerance_mm is not None and tolerance_mm > delta_mm:
        raise ValueError(f"{path}: --tolerance-mm {tolerance_mm:g}: above delta ({delta_mm:.2f} mm, a tenth of the "
                         "part's diameter), where the metric counts a pose as wrong: no turn that far off is a "
                         f"symmetry; expected at most {delta_mm:.2f}")  # fmt: skip
    tol = tolerance_mm / 1000 if tolerance_mm is not None else 0.01 * centroid_d
    return mesh, scale, assumed, find_symmetry(mesh, tol)


def describe(mesh: Any, report: Any, path: Path, assumed: str, near_spin: Any = None, declared: bool = False,
             spins: str = "") -> list[str]:
    """The report printed: units, measures, the symmetry found and rejected, the near-symmetries, and ``spins``
    (:func:`spin_hint`)."""
    from opnet.objects.surface import sqrtm_psd, surface_moments

    m = surface_moments(mesh.vertices, mesh.faces)
    _, sqrt_w, _ = sqrtm_psd(m.covariance)
    shells = len(mesh.split(only_watertight=False))
    lines = [f"{path}", f"  {assumed}",
             f"  extent {' x '.join(f'{e * 1000:.1f}' for e in mesh.extents)} mm; {shells} shell(s); "
             f"{'watertight' if mesh.is_watertight else 'not watertight (open edges: read as a surface)'}",
             f"  diameter D {report.diameter * 1000:.2f} mm (2 x the farthest vertex from the surface centroid); "
             f"delta {report.diameter * 100:.2f} mm; Lambda (principal sqrt) "
             f"{', '.join(f'{w * 1000:.2f}' for w in np.sort(sqrt_w))} mm",
             f"  tolerance {report.tolerance * 1000:.2f} mm: a turn is a symmetry when 98 % of the surface lands within it",
             f"  symmetry: {report.name} -> {_spec_text(report.spec)}"]  # fmt: skip
    for c in report.found:
        lines.append(f"    holds:  {c.angle_deg:6.1f} deg about [{', '.join(f'{v:+.3f}' for v in c.axis)}]: "
                     f"deviation {c.deviation * 1000:.2f} mm")
    for c in sorted(report.rejected, key=lambda c: c.deviation)[:4]:
        lines.append(f"    fails:  {c.angle_deg:6.1f} deg about [{', '.join(f'{v:+.3f}' for v in c.axis)}]: "
                     f"deviation {c.deviation * 1000:.2f} mm")
    near = near_symmetries(report)
    if near:
        lines += [f"  near-symmetry: {near}.",
                  "    A depth image may hardly tell the part from itself turned so, and the metric counts such a pose as",
                  "    wrong (expect orientation misses there); where both poses serve the same grasp, a --tolerance-mm",
                  "    above the deviation declares the turn a symmetry."]
    if near_spin is not None:
        what = "revolution" if near_spin.order is None else f"cyclic {near_spin.order}"
        lines += [f"  {near_spin.text(report.model_rotation)}.",
                  "    A depth image hardly tells the part's spins about this axis apart, and the metric counts each as a",
                  "    wrong pose: a network is asked to learn what it cannot see (expect orientation misses, spins about",
                  f"    the axis). {'Declared' if declared else 'To declare it'}: symmetry {what} about the main axis"
                  f"{'' if declared else ' (--declare-near)'}, where the part's spin does not matter to the grasp."]
    if spins:
        lines += [f"  spins: {spins}.",
                  "    It helps most where the depth shows the spin (a flange's face), less where the part hides it",
                  "    (spokes inside a rim). What a spin changes in the depth, measured:",
                  "    python scripts/experiments/flat_parts/spin_observability.py --object <name>"]
    return lines


def spin_hint(mesh: Any, report: Any) -> str:
    """What a part's training piles may do with its spins: when its convex hull, in the model frame (the main axis
    on z), is a body of revolution within the generator's ``scene.view_spin_tolerance`` × D and its spins are not
    free (no revolution symmetry), a line saying that ``experiment=dense`` turns its views (``scene.view_spin=auto``
    decides as this does) and naming ``scene.view_spin=true`` for other recipes, with the hull's figure; else empty."""
    from opnet.synthesis.config import SceneConfig
    from opnet.synthesis.spin import fresh_spins_fit

    model = mesh.copy()
    model.vertices = (np.asarray(mesh.vertices) - np.asarray(report.origin)) @ np.asarray(report.model_rotation).T
    within, gap = fresh_spins_fit(model, report.diameter, SceneConfig().view_spin_tolerance,
                                  report.spec["kind"] == "revolution")
    if not within:
        return ""
    return (f"its convex hull is a body of revolution about the main axis (turned about it, the hull reaches "
            f"{gap * 1000:.2f} mm, {100 * gap / report.diameter:.2f} % of D, out of itself): experiment=dense gives "
            "every view of a training pile fresh spins of its parts (its scene.view_spin=auto decides so for this "
            "part; in another recipe, scene.view_spin=true: docs/data.md#fresh-spins-per-view)")


def near_symmetries(report: Any) -> str:
    """The rejected turn nearest to a symmetry where it moves 98 % of the surface by less than δ (0.1 D), its
    axis in the model frame (``x_model = R x_file``; a half turn's axis with its largest component positive),
    e.g. ``180.0 deg about [+0.00, +0.00, +1.00] (model frame), 2.99 mm``, and how many more are under δ;
    empty if none."""
    near = sorted((c for c in report.rejected if c.deviation < 0.1 * report.diameter), key=lambda c: c.deviation)
    if not near:
        return ""
    c = near[0]
    axis = report.model_rotation @ c.axis
    axis = -axis if c.angle_deg > 179.5 and axis[np.abs(axis).argmax()] < 0 else axis
    more = f" ({len(near) - 1} more turn{'s' * (len(near) > 2)} under delta)" if len(near) > 1 else ""
    return (f"{c.angle_deg:.1f} deg about [{', '.join(f'{v:+.2f}'.replace('-0.00', '+0.00') for v in axis)}] (model frame), "
            f"{c.deviation * 1000:.2f} mm{more}")


def _spec_text(spec: dict) -> str:
    if spec["kind"] == "finite":
        return f"finite, {len(spec['rotations'])} rotations"
    return ", ".join(f"{k} {v}" for k, v in spec.items())


def write_config(out: Path, name: str, mesh_path: Path, scale: float, report: Any, assumed: str,
                 near_spin: Any = None, exact: Any = None, spins: str = "") -> str:  # fmt: skip
    """The object config's text. ``near_spin``: the near-symmetry about the main axis, named (``exact`` None)
    or declared (``exact``: the report of the exact symmetry it replaced); ``spins``: :func:`spin_hint`'s line."""
    import yaml

    spec = dict(report.spec)
    lines = [f"# {name}: written by opnet-object from {mesh_path} ({assumed}; symmetry {report.name}, tolerance "
             f"{report.tolerance * 1000:.2f} mm).", "# model_origin: the symmetry centre (the surface centroid) in the "
             "file's frame, metres; model_rotation: x_model = R (x_file - origin), the main axis onto z."]  # fmt: skip
    if near_symmetries(report):
        lines.append(f"# near-symmetry (under delta, not declared): {near_symmetries(report)}.")
    if spins:
        lines.append(f"# spins: {spins}.")
    if near_spin is not None and exact is None:
        lines.append(f"# {near_spin.text(report.model_rotation)} (not declared; --declare-near declares it).")
    elif near_spin is not None:
        lines.append(f"# declared with --declare-near: {near_spin.text(report.model_rotation)}; the exact symmetry "
                     f"is {exact.name} ({_spec_text(exact.spec)}).")
    body = {"name": name, "mesh": str(mesh_path), "mesh_scale": scale,
            "model_origin": [round(float(v), 9) for v in report.origin],
            "model_rotation": [[round(float(v), 9) for v in row] for row in report.model_rotation], "symmetry": spec}
    text = "\n".join(lines) + "\n" + yaml.safe_dump(body, sort_keys=False, default_flow_style=None, width=120)
    return text


def preview(mesh: Any, report: Any, out: Path) -> None:
    """The part in its model frame from three sides (xy, xz, yz), its axes, the main axis (z) marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import trimesh

    pts, _ = trimesh.sample.sample_surface(mesh, 6000, seed=0)
    p = (np.asarray(pts) - report.origin) @ report.model_rotation.T
    r = float(np.abs(p).max()) * 1000 * 1.15
    fig, axes = plt.subplots(1, 3, figsize=(12, 4.2))
    for ax, (i, j, title) in zip(axes, ((0, 1, "from +z (down the main axis)"), (0, 2, "from -y"), (1, 2, "from +x")), strict=True):
        ax.scatter(p[:, i] * 1000, p[:, j] * 1000, s=0.5, c=p[:, 3 - i - j] * 1000, cmap="viridis")
        for k, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
            e = np.eye(3)[k]
            if e[i] or e[j]:
                ax.annotate("", xy=(e[i] * r * 0.8, e[j] * r * 0.8), xytext=(0, 0),
                            arrowprops={"arrowstyle": "->", "color": colour, "lw": 2 if k == 2 else 1})
                ax.text(e[i] * r * 0.85, e[j] * r * 0.85, "xyz"[k], color=colour)
        ax.set_xlim(-r, r)
        ax.set_ylim(-r, r)
        ax.set_aspect("equal")
        ax.set_title(title, fontsize=9)
        ax.set_xlabel(f"{'xyz'[i]} mm")
        ax.set_ylabel(f"{'xyz'[j]} mm")
    fig.suptitle(f"{out.stem}: symmetry {report.name} ({_spec_text(report.spec)}); D {report.diameter * 1000:.1f} mm")
    fig.tight_layout()
    fig.savefig(out, dpi=90)
    plt.close(fig)


def object_name(given: str | None, mesh: Path) -> str:
    """The object's name: ``given`` (``--name``) if a plain name (:data:`NAME`), else the mesh's stem made one.

    Raises:
        ValueError: ``given`` is no plain name (a path, a hidden or empty name): naming ``--name``.
    """
    if given is None:
        return re.sub(r"[^a-z0-9_-]+", "_", mesh.stem.lower()).strip("_-") or "part"
    if not NAME.fullmatch(given):
        raise ValueError(f"--name {given!r}: expected a plain name (letters, digits, _ and -, starting with a letter "
                         "or digit, at most 64): the object's config is conf/object/<name>.yaml")
    return given


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.resolve() == b.resolve() or (a.exists() and b.exists() and os.path.samefile(a, b))
    except OSError:
        return False


def output_paths(mesh: Path, out: Path, force: bool) -> tuple[Path, Path]:
    """The object config ``out`` and its preview beside it, checked before the work: an object config's name
    (``.yaml``), neither of them the input mesh, not an existing file without ``force``, both writable.

    Raises:
        ValueError: one line naming the path and the option.
    """
    from opnet.cli.tools import require_writable

    png = out.with_suffix(".png")
    for target in (out, png):
        if _same_file(target, mesh):
            raise ValueError(f"--out {out}: {'its preview ' + str(png) if target == png else 'it'} is the input mesh "
                             f"{mesh}; choose another --out (the mesh is left as it is)")
    if out.suffix.lower() not in CONFIG_SUFFIXES:
        raise ValueError(f"--out {out}: expected the name of a .yaml file (the object config; its preview is "
                         "written beside it as .png)")
    if out.exists() and not force:
        raise ValueError(f"{out}: exists; give --force to overwrite it or another --out")
    for target in (out, png):  # a folder, a device, a read-only folder
        require_writable(target, "--out")
    return out, png


def main(argv: list[str] | None = None) -> int:
    ap = ArgumentParser(prog="opnet-object", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mesh", type=Path)
    ap.add_argument("--name", default=None, help="the object's name (default: the file's stem, lower case)")
    ap.add_argument("--out", type=Path, default=None, help="the YAML to write (default conf/object/<name>.yaml)")
    ap.add_argument("--units", choices=("auto", *UNITS), default="auto")
    ap.add_argument("--tolerance-mm", type=float, default=None, help="default: 1 %% of the part's diameter")
    ap.add_argument("--force", action="store_true", help="overwrite an existing --out")
    ap.add_argument("--declare-near", action="store_true",
                    help="declare the near-revolution or near-cyclic order about the main axis it names (every turn, "
                         "or every 360/k turn, moves 98 %% of the surface by less than delta) as the part's symmetry")
    args = ap.parse_args(argv)
    if args.tolerance_mm is not None and not (math.isfinite(args.tolerance_mm) and args.tolerance_mm > 0):
        return fail(f"{args.mesh}: --tolerance-mm {args.tolerance_mm:g}: expected a positive number of millimetres")
    from opnet import paths
    from opnet.fileio.atomic import write_text_atomic

    try:  # where it writes: before the measuring, not after it
        name = object_name(args.name, args.mesh)
        out, png = output_paths(args.mesh, args.out or paths.config_dir() / "object" / f"{name}.yaml", args.force)
    except ValueError as e:
        return fail(str(e))
    try:
        mesh, scale, assumed, report = inspect_part(args.mesh, args.units, args.tolerance_mm)
    except ValueError as e:
        msg = str(e)
        return fail(msg if msg.startswith(str(args.mesh)) else f"{args.mesh}: {msg}")
    from opnet.objects.near_symmetry import declared, near_axis

    near_spin, exact = near_axis(mesh, report), None
    if args.declare_near and near_spin is not None:
        exact, report = report, declared(report, near_spin, mesh)
    elif args.declare_near:
        print(f"{args.mesh}: --declare-near: no near-revolution or near-cyclic order about the main axis to declare; "
              "the exact symmetry is written")  # fmt: skip
    spins = spin_hint(mesh, report)
    print("\n".join(describe(mesh, report, args.mesh, assumed, near_spin, declared=exact is not None, spins=spins)))
    text = write_config(out, name, args.mesh.resolve(), scale, report, assumed, near_spin, exact, spins)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, text)
    preview(mesh, report, png)
    print(f"wrote {out} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
