"""Values checked where they are read: symmetry specs typed, repeats folded,
reflections refused, group closure bounded; each case was accepted wrongly (or hung) before."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from opnet.datasets.bop import symmetry_from_bop
from opnet.geometry.rotations import axis_angle_rotation
from opnet.geometry.symmetry import MAX_GROUP_SIZE, Symmetry, dihedral_group, symmetry_from_rotations
from opnet.objects.io import load_mesh
from opnet.objects.model import ObjectModel

RZ180 = np.diag([-1.0, -1.0, 1.0])


def _bop_matrix(R: np.ndarray) -> list[float]:
    T = np.eye(4)
    T[:3, :3] = R
    return T.ravel().tolist()


@pytest.mark.parametrize("value", ["false", "true", 1, 0, None])
def test_rotoreflection_must_be_a_boolean(value: object) -> None:
    # 'false' (a string) used to become True through bool()
    with pytest.raises(ValueError, match="symmetry.rotoreflection must be true or false"):
        Symmetry.from_spec({"kind": "revolution", "rotoreflection": value})
    assert Symmetry.from_spec({"kind": "revolution", "rotoreflection": False}).rotoreflection is False


def test_poseutils_rotoreflection_must_be_a_boolean(tmp_path: Path) -> None:
    path = tmp_path / "poseutils.json"
    path.write_text(json.dumps({"type": "RevolutionPoseUtils", "lambda": 0.01, "distance_threshold": 0.01,
                                "rotoreflection_symmetry": "false"}))
    with pytest.raises(ValueError, match=r"poseutils.json: 'rotoreflection_symmetry' must be true or false"):
        ObjectModel.from_poseutils(path)


def test_repeated_group_elements_are_one_element() -> None:
    assert symmetry_from_rotations([np.eye(3), np.eye(3)]).kind == "none"
    sym = symmetry_from_rotations([np.eye(3), RZ180, RZ180])
    assert (sym.kind, sym.order) == ("cyclic", 2)
    D4 = dihedral_group(4)
    assert len(Symmetry("finite", rotations=np.concatenate((D4, D4[::-1]))).group()) == 8


def test_bop_repeated_discrete_symmetry_is_one_element() -> None:
    # symmetries_discrete [Rz180, Rz180] used to become a "group" of 3 elements
    sym, align = symmetry_from_bop({"diameter": 100.0, "symmetries_discrete": [_bop_matrix(RZ180)] * 2}, "obj 1")
    assert (sym.kind, sym.order) == ("cyclic", 2)
    np.testing.assert_allclose(np.abs(align @ np.array([0, 0, 1.0])), [0, 0, 1], atol=1e-9)


def test_group_size_is_capped_and_closure_is_fast() -> None:
    start = time.perf_counter()
    assert len(symmetry_from_rotations(dihedral_group(360)).group()) == MAX_GROUP_SIZE  # the largest accepted
    turns = axis_angle_rotation("Z", 2 * np.pi * np.arange(800) / 800)
    with pytest.raises(ValueError, match="800 distinct elements, more than 720"):
        symmetry_from_rotations(turns)
    with pytest.raises(ValueError, match="more than 5760"):
        symmetry_from_rotations(np.repeat(np.eye(3)[None], 6000, 0))
    # O(K^3) closure took 4.7 s for 400 rotations and never ended for 3,000
    rng = np.random.default_rng(0)
    q = rng.normal(size=(3000, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    R = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                  2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                  2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], 1).reshape(-1, 3, 3)
    R[0] = np.eye(3)
    with pytest.raises(ValueError, match="more than 720"):
        symmetry_from_rotations(R)
    with pytest.raises(ValueError, match="not closed"):
        symmetry_from_rotations(R[:500])
    assert time.perf_counter() - start < 30.0


def test_model_rotation_reflection_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "box.stl"
    trimesh.creation.box((0.02, 0.03, 0.04)).export(path)
    with pytest.raises(ValueError, match=r"box.stl: model_rotation has det -1, a reflection"):
        load_mesh(path, model_rotation=np.diag([1.0, 1.0, -1.0]))
    assert load_mesh(path, model_rotation=RZ180).extents == pytest.approx([0.02, 0.03, 0.04])


CAMERA_YAML = "fx: {fx}\nfy: 500\ncx: 100\ncy: 100\nwidth: 200\nheight: 200\nclip_start: 0.5\nclip_end: 2.0\n"


@pytest.mark.parametrize("fx", ["true", "1e-9", "0.0035", "1e12"])
def test_camera_yaml_focal_length_must_be_a_plausible_number(tmp_path: Path, fx: str) -> None:
    from opnet.datasets.camera_file import read_camera_file

    path = tmp_path / "camera.yaml"
    path.write_text(CAMERA_YAML.format(fx=fx))
    # `true` used to read as fx = 1 px; 1e-9 px put the parts 1e10 m away; 1e12 px hung the overlay
    with pytest.raises(ValueError, match=r"camera.yaml: (camera.fx=True is a boolean|focal length fx = .* field of view)"):
        read_camera_file(path)
    path.write_text(CAMERA_YAML.format(fx=500))
    assert read_camera_file(path).fx == 500.0


def test_camera_bool_is_not_a_number_anywhere() -> None:
    from opnet.datasets.depth_inputs import given_camera
    from opnet.geometry.camera import Camera

    with pytest.raises(ValueError, match="command line: camera.fx=True is a boolean"):
        given_camera({"fx": True})
    with pytest.raises(ValueError, match="camera width must be a number, got the boolean True"):
        Camera(500.0, 500.0, 100.0, 100.0, True, 200, 0.5, 2.0)


def test_alias_bomb_message_is_bounded(tmp_path: Path) -> None:
    from opnet.datasets.camera_file import read_camera_yaml

    items = ["&a [x, x, x, x, x, x, x, x, x]"]
    for prev, name in zip("abcdefg", "bcdefgh", strict=True):
        items.append(f"&{name} [" + ", ".join([f"*{prev}"] * 9) + "]")
    path = tmp_path / "camera.yaml"
    path.write_text("fx: [" + ", ".join(items) + "]\n")  # 9^8 leaves from a few hundred bytes
    with pytest.raises(ValueError) as err:  # the repr of 9^7 leaves used to be the message (39 MB)
        read_camera_yaml(path)
    assert str(path) in str(err.value) and len(str(err.value)) < 400


def _npy_header(shape: tuple[int, int], dtype: str = "<f4") -> bytes:
    header = repr({"descr": dtype, "fortran_order": False, "shape": shape}).encode()
    pad = 64 - (10 + len(header) + 1) % 64
    return b"\x93NUMPY\x01\x00" + (len(header) + pad + 1).to_bytes(2, "little") + header + b" " * pad + b"\n"


def test_npy_header_is_checked_before_allocation(tmp_path: Path) -> None:
    from opnet.datasets.depth_inputs import read_npy_image

    huge = tmp_path / "huge.npy"  # the header claims 160 GB; used to be read (or allocated) whole
    huge.write_bytes(_npy_header((200000, 200000)) + b"\x00" * 64)
    with pytest.raises(ValueError, match=r"huge\.npy: cannot read \.npy \(the header says 200000x200000 pixels"):
        read_npy_image(huge)
    short = tmp_path / "short.npy"
    short.write_bytes(_npy_header((100, 100)) + b"\x00" * 400)
    with pytest.raises(ValueError, match=r"short\.npy: .*holds \d+ bytes, its header describes \d+"):
        read_npy_image(short)
    sparse = tmp_path / "sparse.npy"
    with sparse.open("wb") as fh:  # a sparse file far larger than its header says: refused from its size
        fh.write(_npy_header((10, 10)))
        fh.truncate(30 * 2**30)
    with pytest.raises(ValueError, match=r"sparse\.npy: .*holds 32212254720 bytes"):
        read_npy_image(sparse)
    objects = tmp_path / "objects.npy"
    objects.write_bytes(_npy_header((2, 2), "|O") + b"\x00" * 32)
    with pytest.raises(ValueError, match=r"objects\.npy: cannot read \.npy"):
        read_npy_image(objects)
    good = tmp_path / "good.npy"
    depth = np.arange(12, dtype=np.float32).reshape(3, 4)
    np.save(good, depth)
    np.testing.assert_array_equal(read_npy_image(good), depth)
    np.save(good, np.asfortranarray(depth.astype(np.float64)))
    np.testing.assert_array_equal(read_npy_image(good), depth)


def test_png_header_is_checked_before_decoding(tmp_path: Path) -> None:
    import zlib

    from opnet.datasets.png import read_png

    def chunk(kind: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")

    ihdr = (50000).to_bytes(4, "big") * 2 + bytes([16, 0, 0, 0, 0])
    path = tmp_path / "bomb.png"  # a small file whose header says 50000 x 50000 16-bit pixels
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 100_000))
                     + chunk(b"IEND", b""))
    with pytest.raises(ValueError, match=r"bomb\.png: the PNG header says 50000x50000 pixels"):
        read_png(path, np.uint16)


def test_thread_and_worker_counts_are_capped(tmp_path: Path) -> None:
    from opnet.inference import InferenceSettings
    from opnet.objects import builtin_object
    from opnet.synthesis import generate_dataset

    with pytest.raises(ValueError, match=r"^workers=20000: expected a whole number in 1\.\.\d+ \(4 per core"):
        generate_dataset(builtin_object("shaft"), tmp_path / "gen", 1, 1, workers=20000)
    assert not (tmp_path / "gen").exists()
    with pytest.raises(ValueError, match=r"^inference\.workers=20000: expected a whole number"):
        InferenceSettings.from_config({"workers": 20000})
    with pytest.raises(ValueError, match=r"^inference\.workers=True"):
        InferenceSettings.from_config({"workers": True})
    with pytest.raises(ValueError, match=r"^inference\.compile='false', expected true or false"):
        InferenceSettings.from_config({"compile": "false"})
    assert InferenceSettings.from_config({"workers": 2}).workers == 2
