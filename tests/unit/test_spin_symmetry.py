"""Spinning parts in ``opnet-object``: cyclic orders above 12 (odd, prime, 60) found on generated gears of known
order, and the near-revolutions and near-cyclic orders about a part's main axis named (and declared on request)
on generated parts of known near-symmetry and on the two ITODD parts whose misses are spins."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import trimesh
import yaml

from opnet.cli.object import main as opnet_object
from opnet.objects import builtin_object, load_mesh
from opnet.objects.near_symmetry import main_axis, near_axis
from opnet.objects.symmetry_finder import _Surface, find_symmetry


def gear(teeth: int, radius: float = 0.05, depth: float = 0.005, height: float = 0.012, twist_deg: float = 0.0,
         layers: int = 1, hub: bool = True) -> trimesh.Trimesh:  # fmt: skip
    """A gear of ``teeth`` square teeth (outer radius, tooth depth, thickness in metres), its teeth twisted by
    ``twist_deg`` over its thickness (a helical gear), with a hub on one face (no flip: its group is cyclic)."""
    per_tooth = 8
    n = teeth * per_tooth
    radii = np.where((np.arange(n) % per_tooth) < per_tooth // 2, radius, radius - depth)
    angles = np.arange(n) * 2 * np.pi / n
    rings = [np.stack([radii * np.cos(angles + math.radians(twist_deg) * k / layers),
                       radii * np.sin(angles + math.radians(twist_deg) * k / layers),
                       np.full(n, height * k / layers - height / 2)], 1) for k in range(layers + 1)]  # fmt: skip
    vertices = np.vstack([*rings, [[0, 0, -height / 2], [0, 0, height / 2]]])
    faces = []
    for k in range(layers):
        for i in range(n):
            a, b = k * n + i, k * n + (i + 1) % n
            faces += [[a, b, b + n], [a, b + n, a + n]]
    bottom, top = len(vertices) - 2, len(vertices) - 1
    for i in range(n):
        faces += [[bottom, (i + 1) % n, i], [top, layers * n + i, layers * n + (i + 1) % n]]
    part = trimesh.Trimesh(vertices, np.array(faces))
    if hub:
        boss = trimesh.creation.cylinder(0.4 * radius, 0.6 * height, sections=64)
        boss.apply_translation([0, 0, 0.8 * height])
        part = trimesh.util.concatenate([part, boss])
    return part


def _report(mesh: trimesh.Trimesh):
    D = 2 * float(np.linalg.norm(mesh.vertices - mesh.centroid, axis=1).max())
    return find_symmetry(mesh, 0.01 * D)


@pytest.mark.parametrize("teeth", [13, 17, 31])
def test_cyclic_orders_above_twelve_are_found(teeth: int) -> None:
    """Odd and prime orders above the twelve tried before (a 17-tooth sprocket was named 'none')."""
    report = _report(gear(teeth))
    assert report.name == f"C{teeth}" and report.spec == {"kind": "cyclic", "order": teeth}


@pytest.mark.slow
def test_a_fine_order_finer_than_the_sample_is_found_on_a_denser_one() -> None:
    """60 teeth of 2.6 mm on a 100 mm ring pass the revolution test at 3000 points (the sampling floor sets the
    tolerance); the verdict is checked on a denser sample, which resolves the teeth: cyclic 60."""
    report = _report(gear(60, depth=0.008, height=0.004))
    assert report.spec == {"kind": "cyclic", "order": 60}


def test_a_near_revolution_is_named_with_what_to_declare_and_declared_on_request(tmp_path: Path, capsys) -> None:
    """A 17-tooth gear with 5 mm teeth is cyclic 17, and every turn about its axis moves 98 % of its surface by
    about 4.6 mm, under delta (10 mm): named a near-revolution; --declare-near writes revolution about z in the
    same model frame, and names the exact group it replaced."""
    src = tmp_path / "gear17.stl"
    gear(17).export(src)
    out = tmp_path / "gear17.yaml"
    assert opnet_object([str(src), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    line = next(line for line in printed.splitlines() if "near-revolution" in line)
    assert "about [+0.00, +0.00, +1.00] (model frame)" in line
    deviation = float(line.split("at most ")[1].split(" mm")[0])
    assert 3.0 < deviation < 7.0 and "--declare-near" in printed
    exact = yaml.safe_load(out.read_text())
    assert exact["symmetry"] == {"kind": "cyclic", "order": 17} and "near-revolution" in out.read_text()
    declared = tmp_path / "gear17_rev.yaml"
    assert opnet_object([str(src), "--out", str(declared), "--declare-near"]) == 0
    cfg = yaml.safe_load(declared.read_text())
    assert cfg["symmetry"] == {"kind": "revolution", "rotoreflection": False}
    assert "the exact symmetry is C17" in declared.read_text()
    np.testing.assert_allclose(cfg["model_rotation"], exact["model_rotation"], atol=1e-3)


def test_a_helical_gear_is_named_a_near_revolution() -> None:
    """Teeth twisted 20 degrees over the thickness: still cyclic 17, and a near-revolution."""
    mesh = gear(17, twist_deg=20.0, layers=10)
    report = _report(mesh)
    near = near_axis(mesh, report)
    assert report.spec == {"kind": "cyclic", "order": 17}
    assert near is not None and near.order is None and near.deviation < near.delta


def test_a_near_cyclic_order_is_named_and_exact_parts_are_left_alone() -> None:
    """A 60 x 56 x 8 mm plate: two-fold about its normal (and dihedral), and its quarter turn moves 98 % of the
    surface by about 2 mm, under delta: near-cyclic 4 about the normal. A cube's or a plain shaft's main axis has
    nothing near to name (exact symmetries), nor has a part with no near turn (the bracket)."""
    plate = trimesh.creation.box((0.060, 0.056, 0.008))
    report = _report(plate)
    near = near_axis(plate, report)
    assert near is not None and near.order == 4 and abs(abs(near.axis[2]) - 1) < 1e-6
    for mesh in (builtin_object("shaft").mesh, builtin_object("bracket").mesh):
        assert near_axis(mesh, _report(mesh)) is None


def test_the_main_axis_of_a_part_without_symmetry_is_its_flat_normal() -> None:
    plate = trimesh.creation.box((0.06, 0.03, 0.005))
    plate.apply_translation([0.004, 0, 0])
    boss = trimesh.creation.box((0.01, 0.01, 0.01))
    boss.apply_translation([0.02, 0.008, 0.007])  # breaks every symmetry
    mesh = trimesh.util.concatenate([plate, boss])
    report = _report(mesh)
    assert report.spec == {"kind": "none"}
    assert abs(abs(main_axis(_Surface(mesh, 2000, 0), report)[2]) - 1) < 0.05


@pytest.mark.parametrize(("part", "exact"), [("ITODD08.stl", "C5"), ("ITODD27.stl", "C1")])
def test_the_spinning_itodd_parts_are_near_revolutions(shared: Path, part: str, exact: str) -> None:
    """The two new parts missed on spins about their axis: a rim with five thin spokes and a flange with two
    notches; every turn about their axis moves 98 % of the surface by under half of delta."""
    mesh = load_mesh(shared / "data" / "meshes" / "new_parts" / part, 0.001)
    report = _report(mesh)
    near = near_axis(mesh, report)
    assert report.name == exact
    assert near is not None and near.order is None and near.deviation < 0.6 * near.delta


def cup(bumps: int = 5) -> trimesh.Trimesh:
    """A 80 mm cup (a base and a rim wall, 16 mm high) with ``bumps`` blocks on its floor below the wall: its
    group is cyclic ``bumps``, and what sets its spin lies inside its envelope (a rim's spokes, a flange's holes)."""
    base = trimesh.creation.cylinder(0.04, 0.004, sections=64)
    wall = trimesh.creation.annulus(0.036, 0.04, 0.012, sections=64)
    wall.apply_translation([0, 0, 0.008])
    parts = [base, wall]
    for k in range(bumps):
        block = trimesh.creation.box((0.008, 0.004, 0.006))
        a = 2 * math.pi * k / bumps
        block.apply_transform(trimesh.transformations.rotation_matrix(a, [0, 0, 1]))
        block.apply_translation([0.02 * math.cos(a), 0.02 * math.sin(a), 0.005])
        parts.append(block)
    return trimesh.util.concatenate(parts)


def test_a_part_whose_hull_spins_freely_is_told_of_fresh_spins_per_view(tmp_path: Path, capsys) -> None:
    """The cup lies with its axis along the file's x: in the model frame (the main axis on z) its hull is a body of
    revolution, so the report and the config name scene.view_spin=true with the hull's figure. A box's hull is
    not one, and a plain cylinder's spins are free (revolution): neither is told."""
    part = cup()
    part.apply_transform(trimesh.transformations.rotation_matrix(math.pi / 2, [0, 1, 0]))  # axis onto file x
    src = tmp_path / "cup.stl"
    part.export(src)
    out = tmp_path / "cup.yaml"
    assert opnet_object([str(src), "--out", str(out), "--units", "m"]) == 0
    line = next(line for line in capsys.readouterr().out.splitlines() if line.startswith("  spins:"))
    assert "experiment=dense" in line and "scene.view_spin=auto" in line and "scene.view_spin=true" in line
    assert float(line.split("% of D")[0].split(", ")[-1]) < 1.0  # within the generator's 1 % of D
    text = out.read_text()
    assert yaml.safe_load(text)["symmetry"] == {"kind": "cyclic", "order": 5} and "# spins:" in text
    for name, mesh in (("box", trimesh.creation.box((0.06, 0.04, 0.01))),
                       ("cylinder", trimesh.creation.cylinder(0.03, 0.01, sections=64))):
        src = tmp_path / f"{name}.stl"
        mesh.export(src)
        assert opnet_object([str(src), "--out", str(tmp_path / f"{name}.yaml"), "--units", "m"]) == 0
        assert "spins:" not in capsys.readouterr().out and "# spins:" not in (tmp_path / f"{name}.yaml").read_text()
