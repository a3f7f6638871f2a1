"""opnet-object: a part's proper symmetry group found from its mesh (groups known by construction or from the
paper), the same group for the mesh turned and moved anywhere, the config it writes loads with that symmetry
about the model's z axis, and bad input is one line naming the file with nothing written."""

from __future__ import annotations

import math
import os
import stat
from pathlib import Path

import numpy as np
import pytest
import trimesh

from opnet.cli.object import main as opnet_object
from opnet.objects import builtin_object, load_mesh
from opnet.objects.symmetry_finder import find_symmetry


def _group(mesh: trimesh.Trimesh) -> tuple[str, dict]:
    D = 2 * float(np.linalg.norm(mesh.vertices - mesh.centroid, axis=1).max())
    r = find_symmetry(mesh, 0.01 * D)
    return r.name, r.spec


def _moved(mesh: trimesh.Trimesh, seed: int) -> trimesh.Trimesh:
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=seed).as_matrix()
    T[:3, 3] = [0.1, -0.2, 0.05]
    return mesh.copy().apply_transform(T)


HEX_NUT = trimesh.creation.cylinder(0.02, 0.01, sections=6)


@pytest.mark.parametrize(("mesh", "name"), [
    (builtin_object("bracket").mesh, "C1"),
    (builtin_object("zbracket").mesh, "C2"),
    (builtin_object("shaft").mesh, "C-inf"),
    (builtin_object("pin").mesh, "D-inf"),
    (HEX_NUT, "D6"),
    pytest.param(trimesh.creation.box((0.05, 0.05, 0.05)), "O", marks=pytest.mark.slow),  # the longest case
])  # fmt: skip
def test_known_groups_are_found(mesh: trimesh.Trimesh, name: str) -> None:
    found, spec = _group(mesh)
    assert found == name
    sizes = {"D6": 12, "O": 24}
    if name in sizes:
        assert spec["kind"] == "finite" and len(spec["rotations"]) == sizes[name]


@pytest.mark.parametrize(("mesh", "name"), [(builtin_object("zbracket").mesh, "C2"), (HEX_NUT, "D6"),
                                            (builtin_object("pin").mesh, "D-inf")])
def test_a_turned_and_moved_mesh_gives_the_same_group(mesh: trimesh.Trimesh, name: str) -> None:
    assert _group(_moved(mesh, 7))[0] == name


def test_a_sphere_like_part_is_refused() -> None:
    with pytest.raises(ValueError, match="several axes of revolution"):
        _group(trimesh.creation.icosphere(3, 0.03))


@pytest.mark.parametrize(("path", "scale", "name"), [
    ("meshes/SileaneBunny.obj", 1.0, "C1"),
    ("meshes/IPARingScrew.stl", 1.0, "C2"),
    ("meshes/IPAGearShaft.stl", 1.0, "C-inf"),
    ("ipd_real_obj18/models/obj_000018.ply", 0.001, "C2"),  # the official 180 degrees about the stem axis
    ("meshes/new_parts/SileanePepper.stl", 0.001, "C-inf"),  # the paper's Table I: revolution
    ("meshes/new_parts/TLess20.stl", 0.001, "C2"),  # the paper's Table I: cyclic, k = 2
])  # fmt: skip
def test_the_reference_parts_groups(shared: Path, path: str, scale: float, name: str) -> None:
    assert _group(load_mesh(shared / "data" / path, scale))[0] == name


def test_the_written_config_loads_with_the_symmetry_about_model_z(tmp_path: Path) -> None:
    from opnet.objects.config import object_from_config
    from opnet.objects.symmetry_finder import _Surface, _axis_rotation

    src = tmp_path / "nut.stl"
    _moved(trimesh.creation.cylinder(0.02, 0.012, sections=5), 3).export(src)  # a pentagonal prism: D5
    out = tmp_path / "conf" / "nut.yaml"
    assert opnet_object([str(src), "--out", str(out)]) == 0
    assert out.with_suffix(".png").stat().st_size > 10_000
    import yaml

    cfg = yaml.safe_load(out.read_text())
    assert cfg["symmetry"]["kind"] == "finite" and len(cfg["symmetry"]["rotations"]) == 10
    obj = object_from_config(cfg)
    assert obj.symmetry.group().shape == (10, 3, 3)
    surface = _Surface(obj.mesh, 2000, 0)
    assert np.linalg.norm(surface.centroid) < 1e-6  # the symmetry centre is the model origin
    for angle in (72.0, 144.0):  # the five-fold axis is the model's z
        assert surface.deviation(_axis_rotation(np.array([0.0, 0.0, 1.0]), math.radians(angle))) < 0.001
    assert opnet_object([str(src), "--out", str(out)]) == 2  # no overwriting without --force


def test_a_near_symmetry_is_named_with_its_deviation_and_not_declared(tmp_path: Path, capsys) -> None:
    """A 50 x 40 x 20 mm block with a 12 x 12 x 4 mm boss off its centre: no symmetry, but turned half about z
    about its thin axis it moves 98 % of its surface by about 3 mm, under delta (7 mm): said, with its axis, in
    the output and the YAML; the block without the boss has that half turn as a symmetry, so nothing near is said of it."""
    import yaml

    boss = trimesh.creation.box((0.012, 0.012, 0.004))
    boss.apply_translation([0.015, 0.01, 0.012])
    src = tmp_path / "block.stl"
    _moved(trimesh.util.concatenate([trimesh.creation.box((0.05, 0.04, 0.02)), boss]), 5).export(src)
    out = tmp_path / "block.yaml"
    assert opnet_object([str(src), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    near = [line for line in printed.splitlines() if "near-symmetry:" in line]
    assert len(near) == 1 and "180.0 deg about [" in near[0]
    axis = np.array([float(v) for v in near[0].split("about [")[1].split("]")[0].split(",")])
    deviation = float(near[0].split("(model frame), ")[1].split(" mm")[0])
    from scipy.spatial.transform import Rotation

    thin = Rotation.random(random_state=5).as_matrix()[:, 2]  # the block's thin axis, turned as _moved turns it
    assert abs(axis @ thin) > 0.99 and 1.5 < deviation < 5.0  # (no symmetry: the model frame is the file's)
    text = out.read_text()
    assert yaml.safe_load(text)["symmetry"] == {"kind": "none"} and "# near-symmetry (under delta" in text
    plain = tmp_path / "plain.stl"
    _moved(trimesh.creation.box((0.05, 0.04, 0.02)), 5).export(plain)
    assert opnet_object([str(plain), "--out", str(tmp_path / "plain.yaml")]) == 0
    assert "near-symmetry" not in capsys.readouterr().out


def _bad(tmp_path: Path, name: str, mesh: trimesh.Trimesh | None = None, text: str | None = None) -> Path:
    path = tmp_path / name
    if mesh is not None:
        mesh.export(path)
    else:
        path.write_text(text or "")
    return path


@pytest.mark.parametrize(("case", "args", "message"), [
    ("metres_as_mm", ["--units", "mm"], "the part would be 50 mm across"),
    ("mm_as_metres", ["--units", "m"], "the part would be 50000 mm across"),
    ("two_shells", [], "2 shells, one"),
    ("sheet", [], "a flat sheet"),
    ("not_a_mesh", [], "not a mesh"),
    ("zero_tolerance", ["--tolerance-mm", "0"], "--tolerance-mm 0: expected a positive number"),
])  # fmt: skip
def test_bad_input_is_one_line_naming_the_file_and_nothing_is_written(tmp_path: Path, capsys, case: str,
                                                                       args: list[str], message: str) -> None:  # fmt: skip
    box = trimesh.creation.box((0.05, 0.03, 0.02))
    if case == "metres_as_mm":
        path, message = _bad(tmp_path, "p.stl", box), "the part would be 0.05 mm across"
    elif case == "mm_as_metres":
        path = _bad(tmp_path, "p.stl", box.copy().apply_scale(1000.0))
    elif case == "two_shells":
        path = _bad(tmp_path, "p.stl", trimesh.util.concatenate([box, box.copy().apply_translation((0.5, 0, 0))]))
    elif case == "sheet":
        sheet = trimesh.Trimesh(vertices=[[0, 0, 0], [0.05, 0, 0], [0.05, 0.05, 0], [0, 0.05, 0]], faces=[[0, 1, 2], [0, 2, 3]])
        path = _bad(tmp_path, "p.stl", sheet)
    elif case == "not_a_mesh":
        path = _bad(tmp_path, "p.stl", text="these are not triangles\n")
    else:
        path = _bad(tmp_path, "p.stl", box)
    out = tmp_path / "out" / "p.yaml"
    assert opnet_object([str(path), "--out", str(out), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and str(path) in err and message in err, err
    assert not out.parent.exists()


@pytest.mark.parametrize("target", ["folder", "fifo", "png_folder"])
def test_an_out_that_is_no_file_is_refused_before_the_work_and_left_as_it_was(tmp_path: Path, capsys,
                                                                              target: str) -> None:  # fmt: skip
    """--out a folder was a traceback after the whole measurement; a FIFO or a device (--out /dev/null as
    root) was replaced by the written YAML, and its preview written beside it."""
    src = tmp_path / "box.stl"
    trimesh.creation.box((0.05, 0.03, 0.02)).export(src)
    out = tmp_path / "out.yaml"
    if target == "folder":
        out.mkdir()
    elif target == "fifo":
        os.mkfifo(out)
    else:
        out.with_suffix(".png").mkdir()
    before = sorted(p.name for p in tmp_path.iterdir())
    assert opnet_object([str(src), "--out", str(out), "--force"]) == 2
    err = capsys.readouterr().err.strip()
    blocked = out if target != "png_folder" else out.with_suffix(".png")
    assert err == f"error: {blocked}: exists and is not a regular file; --out takes the name of a file to write"
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert target != "fifo" or stat.S_ISFIFO(os.stat(out).st_mode)


def test_a_missing_mesh_is_named_as_missing(tmp_path: Path, capsys) -> None:
    assert opnet_object([str(tmp_path / "gone.stl"), "--out", str(tmp_path / "x.yaml")]) == 2
    assert capsys.readouterr().err.strip() == f"error: {tmp_path / 'gone.stl'}: file not found"
