"""opnet-object writes only where it should, and says what is wrong with a part in its own terms: an --out
onto the input mesh (or any file that is not an object config) is refused before the work and the mesh is
left as it was; a --name that is not a plain name (a path) is refused, nothing written anywhere, no folder
made; a part whose vertices coincide is named as such (not a "math domain error"); a --tolerance-mm above
delta is refused naming the option and the bound (a box was called "a sphere-like part"). Each failed
before its fix."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import trimesh

from opnet.cli.object import main as opnet_object


def _box(path: Path, size: tuple[float, float, float] = (0.05, 0.03, 0.02)) -> Path:
    trimesh.creation.box(size).export(path)
    return path


def _one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err, err
    return err


@pytest.mark.parametrize("how", ["same path", "relative path", "hard link", "symbolic link"])
def test_an_out_onto_the_input_mesh_is_refused_and_the_mesh_kept(tmp_path: Path, capsys, monkeypatch,
                                                                how: str) -> None:  # fmt: skip
    mesh = _box(tmp_path / "m.stl")
    before = mesh.read_bytes()
    out = {"same path": mesh, "relative path": Path("m.stl"), "hard link": tmp_path / "link.yaml",
           "symbolic link": tmp_path / "sym.yaml"}[how]
    if how == "hard link":
        os.link(mesh, out)
    elif how == "symbolic link":
        out.symlink_to(mesh)
    monkeypatch.chdir(tmp_path)
    listing = sorted(p.name for p in tmp_path.iterdir())
    assert opnet_object([str(mesh), "--out", str(out), "--force"]) == 2
    err = _one_line(capsys)
    assert str(out) in err and "--out" in err and "mesh" in err
    assert mesh.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == listing  # no preview, no temporary file


def test_an_out_that_is_no_object_config_name_is_refused_before_the_work(tmp_path: Path, capsys) -> None:
    """``--out other.stl --force`` replaced another mesh with YAML (and wrote other.png beside it)."""
    mesh, other = _box(tmp_path / "m.stl"), _box(tmp_path / "other.stl", (0.04, 0.03, 0.02))
    before = other.read_bytes()
    assert opnet_object([str(mesh), "--out", str(other), "--force"]) == 2
    err = _one_line(capsys)
    assert f"--out {other}" in err and ".yaml" in err
    assert other.read_bytes() == before and not (tmp_path / "other.png").exists()


@pytest.mark.parametrize("name", ["../../elsewhere/x", "a/b", "..", ".hidden", "x y", "", "-x"])
def test_a_name_that_is_no_plain_name_is_refused_and_nothing_written(tmp_path: Path, capsys, monkeypatch,
                                                                      name: str) -> None:  # fmt: skip
    """The default --out is conf/object/<name>.yaml: ``--name ../../elsewhere/x`` wrote outside it, making folders."""
    import opnet.paths

    conf = tmp_path / "repo" / "conf"
    (conf / "object").mkdir(parents=True)
    monkeypatch.setattr(opnet.paths, "config_dir", lambda: conf)
    mesh = _box(tmp_path / "m.stl")
    listing = sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*"))
    assert opnet_object([str(mesh), f"--name={name}"]) == 2
    err = _one_line(capsys)
    assert f"--name {name!r}" in err
    assert sorted(p.relative_to(tmp_path) for p in tmp_path.rglob("*")) == listing


def test_the_default_name_of_a_mesh_with_spaces_is_a_plain_name(tmp_path: Path, capsys) -> None:
    mesh = _box(tmp_path / "Part V2.1.stl")
    out = tmp_path / "x.yaml"
    assert opnet_object([str(mesh), "--out", str(out)]) == 0
    import yaml

    assert yaml.safe_load(out.read_text())["name"] == "part_v2_1"


def test_a_part_whose_vertices_coincide_is_named_so(tmp_path: Path, capsys) -> None:
    """A box of a few nanometres: its STL vertices merge into one point; the message was "math domain error"."""
    mesh = _box(tmp_path / "nano.stl", (3e-9, 2e-9, 1e-9))
    out = tmp_path / "out" / "nano.yaml"
    assert opnet_object([str(mesh), "--out", str(out)]) == 2
    err = _one_line(capsys)
    assert str(mesh) in err and "math domain" not in err and "no extent" in err
    assert not out.parent.exists()


@pytest.mark.parametrize("tolerance", ["1e9", "10"])
def test_a_tolerance_above_delta_is_refused_naming_the_bound(tmp_path: Path, capsys, tolerance: str) -> None:
    """A 50 x 30 x 20 mm box (D 61.6 mm, delta 6.16 mm) at 1e9 mm was "a sphere-like part"."""
    mesh = _box(tmp_path / "box.stl")
    out = tmp_path / "box.yaml"
    assert opnet_object([str(mesh), "--out", str(out), "--tolerance-mm", tolerance]) == 2
    err = _one_line(capsys)
    assert f"--tolerance-mm {float(tolerance):g}" in err and "sphere" not in err and "6.16 mm" in err, err
    assert not out.exists()
