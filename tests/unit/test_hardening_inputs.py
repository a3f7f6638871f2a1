"""Values checked where they are read, and one-line errors naming the file or key: BOP
ids and translations, duplicate camera YAML keys, millimetre depth in a
``.npy``, inside-out and oversized meshes, object config keys, generation arguments, full disks.
Each test failed before its fix."""

from __future__ import annotations

import errno
import json
import os
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import trimesh

from conftest import FullDisk
from opnet.datasets.bop import BOPDataset, symmetry_from_bop, write_bop_models
from opnet.datasets.camera_file import read_camera_file, read_camera_yaml
from opnet.datasets.depth_inputs import load_depth_image
from opnet.datasets.png import write_png
from opnet.fileio.atomic import DiskFullError, write_bytes_atomic
from opnet.objects import builtin_object, object_from_config
from opnet.objects import io as mesh_io

CAMERA = {"fx": 100.0, "fy": 100.0, "cx": 31.5, "cy": 23.5, "clip_start": 0.5, "clip_end": 1.5}


# ------------------------------------------------------------------------------------------- BOP


def _bop_split(root: Path, obj_id: Any = 1, t_mm: list[float] | None = None, entries: Any = None,
               info: Any = None) -> Path:
    """A one-image BOP split ``root/train`` (64 x 48 depth at 1 m) with one instance of ``obj_id``."""
    (root / "models").mkdir(parents=True)
    (root / "models" / "models_info.json").write_text(json.dumps({"1": info if info is not None else {"diameter": 50.0}}))
    scene = root / "train" / "000000"
    (scene / "depth").mkdir(parents=True)
    write_png(scene / "depth" / "000000.png", np.full((48, 64), 10000, np.uint16))  # 1 m at 0.1 mm
    K = [100.0, 0.0, 31.5, 0.0, 100.0, 23.5, 0.0, 0.0, 1.0]
    (scene / "scene_camera.json").write_text(json.dumps({"0": {"cam_K": K, "depth_scale": 0.1}}))
    gt = {"obj_id": obj_id, "cam_R_m2c": np.eye(3).reshape(-1).tolist(), "cam_t_m2c": t_mm or [0.0, 0.0, 950.0]}
    (scene / "scene_gt.json").write_text(json.dumps({"0": entries if entries is not None else [gt]}))
    (scene / "scene_gt_info.json").write_text(json.dumps({"0": [{"visib_fract": 0.8}]}))
    return root / "train"


def test_a_valid_bop_split_reads(tmp_path: Path) -> None:
    record = BOPDataset(_bop_split(tmp_path), 1)[0]
    assert np.allclose(record.t_cam_obj, [[0.0, 0.0, 0.95]])


def test_bop_translation_in_metres_is_refused(tmp_path: Path) -> None:
    split = _bop_split(tmp_path, t_mm=[0.0, 0.0, 0.95])  # metres where BOP has millimetres
    with pytest.raises(ValueError, match=r"scene_gt.json: image 0, instance 0: cam_t_m2c puts the part 0.00095 m in "
                                         r"front of the camera, far outside the image's depth range \[1, 1\] m"):
        BOPDataset(split, 1)[0]


@pytest.mark.parametrize("obj_id", [1.9, True, "1", 0])
def test_bop_obj_id_must_be_a_whole_positive_number(obj_id: Any, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"scene_gt.json: image 0, instance 0: obj_id=.* is not a BOP object id"):
        BOPDataset(_bop_split(tmp_path, obj_id=obj_id), 1)


@pytest.mark.parametrize(("change", "message"), [
    ({"entries": {"obj_id": 1}}, r"scene_gt.json: image 0: 'instances' must be a list, got \{'obj_id': 1\}"),
    ({"entries": [{"obj_id": "abc"}]}, r"scene_gt.json: image 0, instance 0: obj_id='abc'"),
    ({"info": {"diameter": 50.0, "symmetries_discrete": 5}}, r"models_info.json: obj_id 1: 'symmetries_discrete' must be a list"),
    ({"info": {"diameter": 50.0, "symmetries_continuous": {"axis": [0, 0, 1]}}}, r"'symmetries_continuous' must be a list"),
    ({"info": {"diameter": "big"}}, r"models_info.json: obj_id 1: 'diameter' must be a finite number, got 'big'"),
    ({"info": [1, 2]}, r"models_info.json: obj_id 1: expected an object of model info"),
])  # fmt: skip
def test_bop_entries_of_the_wrong_type_name_the_file(change: dict, message: str, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=message):
        BOPDataset(_bop_split(tmp_path, **change), 1)


def test_bop_visibility_errors_name_scene_gt_info(tmp_path: Path) -> None:
    split = _bop_split(tmp_path)
    (split / "000000" / "scene_gt_info.json").write_text(json.dumps({"0": [{"visib_fract": "a"}]}))
    with pytest.raises(ValueError, match=r"scene_gt_info.json: image 0, instance 0: 'visib_fract' must be a finite number"):
        BOPDataset(split, 1)[0]  # used to blame scene_gt.json


def test_bop_symmetry_of_a_continuous_entry_without_axis_names_it() -> None:
    with pytest.raises(ValueError, match=r"^m: symmetries_continuous\[0\]: missing key 'axis'"):
        symmetry_from_bop({"symmetries_continuous": [{"offset": [0, 0, 0]}]}, "m")


@pytest.mark.parametrize("obj_id", [-1, 0, 1.5, 10**6])
def test_bop_writer_refuses_an_obj_id_without_a_file_name(obj_id: Any, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"obj_id=.* is not a BOP object id"):
        write_bop_models(tmp_path / "models", builtin_object("zbracket"), obj_id)
    assert not list(tmp_path.rglob("*.ply"))  # before: obj_-00001.ply


# ---------------------------------------------------------------------------------- camera YAML


def test_duplicate_camera_yaml_keys_are_refused(tmp_path: Path) -> None:
    path = tmp_path / "cam.yaml"
    path.write_text("fx: 600\nfy: 600\ncx: 31.5\ncy: 23.5\nwidth: 64\nheight: 48\nclip_start: 0.5\nclip_end: 1.5\nfx: 6\n")
    with pytest.raises(ValueError, match=r"cam.yaml: key 'fx' is given twice \(line 9\)"):
        read_camera_yaml(path)
    with pytest.raises(ValueError, match=r"cam.yaml: key 'fx' is given twice"):
        read_camera_file(path)


def test_malformed_camera_yaml_is_one_line(tmp_path: Path) -> None:
    path = tmp_path / "cam.yaml"
    path.write_text("fx: [600\n")
    with pytest.raises(ValueError, match=r"cam.yaml: malformed camera YAML") as info:
        read_camera_yaml(path)
    assert "\n" not in str(info.value)


# ---------------------------------------------------------------------------------- depth inputs


def test_npy_depth_in_millimetres_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "mm.npy"
    np.save(path, np.full((48, 64), 1000.0, np.float32))  # 1 m written as 1000
    with pytest.raises(ValueError, match=r"mm.npy: 0 % of the valid depth lies between the clip planes .*millimetres"):
        load_depth_image(path, CAMERA)


def test_npy_depth_in_metres_reads(tmp_path: Path) -> None:
    path = tmp_path / "m.npy"
    np.save(path, np.full((48, 64), 1.0, np.float32))
    assert np.allclose(load_depth_image(path, CAMERA).depth, 1.0)


def test_png_depth_with_a_wrong_scale_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "raw.png"
    write_png(path, np.full((48, 64), 1000, np.uint16))
    with pytest.raises(ValueError, match=r"raw.png: 0 % of the valid depth .*millimetres"):
        load_depth_image(path, {**CAMERA, "depth_scale": 1.0})  # a millimetre PNG at 1 m per unit
    assert np.allclose(load_depth_image(path, {**CAMERA, "depth_scale": 0.001}).depth, 1.0)


# ----------------------------------------------------------------------------------------- meshes


def test_an_inside_out_mesh_is_repaired(tmp_path: Path) -> None:
    box = trimesh.creation.box((0.04, 0.03, 0.02))
    box.invert()
    box.export(tmp_path / "inside_out.ply")
    mesh = mesh_io.load_mesh(tmp_path / "inside_out.ply")
    assert mesh.volume == pytest.approx(0.04 * 0.03 * 0.02, rel=1e-6)


def test_a_mesh_with_too_many_faces_is_refused_from_its_header(tmp_path: Path) -> None:
    path = tmp_path / "scan.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                     b"property float z\nelement face 5000000\nproperty list uchar int vertex_indices\nend_header\n")
    with pytest.raises(ValueError, match=r"scan.ply: the mesh has 5,000,000 faces, more than 1,000,000; simplify"):
        mesh_io.load_mesh(path)


def test_a_mesh_with_too_many_faces_is_refused_after_loading(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    trimesh.creation.box((0.04, 0.03, 0.02)).export(tmp_path / "box.obj")
    monkeypatch.setattr(mesh_io, "MAX_MESH_FACES", 10)
    with pytest.raises(ValueError, match=r"box.obj: the mesh has 12 faces, more than 10"):
        mesh_io.load_mesh(tmp_path / "box.obj")


def test_a_mesh_with_a_nan_vertex_is_refused_not_trimmed(tmp_path: Path) -> None:
    path = tmp_path / "nan.obj"  # processing used to drop the vertex and its faces without a word
    path.write_text("v 0 0 0\nv nan 0 0\nv 0 0.05 0\nv 0 0 0.05\nf 1 2 3\nf 1 3 4\nf 1 2 4\nf 2 3 4\n")
    with pytest.raises(ValueError, match=r"nan.obj: mesh has non-finite \(NaN or inf\) vertex coordinates"):
        mesh_io.load_mesh(path)


def test_a_fifo_mesh_is_named_a_fifo(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "part.stl")
    with pytest.raises(ValueError, match=r"part.stl: not a regular file \(a FIFO\)"):
        mesh_io.load_mesh(tmp_path / "part.stl")


# ---------------------------------------------------------------------------------- object config


@pytest.mark.parametrize(("cfg", "message"), [
    ({"mesh_scale": "abc"}, r"object.mesh_scale='abc' of 'part': expected a positive number"),
    ({"mesh_scale": True}, r"object.mesh_scale=True of 'part'"),
    ({"symmetry": ["revolution"]}, r"object.symmetry of 'part': expected a name .* got a list"),
    ({"bop_models": "/nowhere", "bop_obj_id": 1.9}, r"object 'part': object.bop_obj_id=1.9 is not a BOP object id"),
])  # fmt: skip
def test_object_config_errors_name_the_key(cfg: dict, message: str, tmp_path: Path) -> None:
    trimesh.creation.box((0.04, 0.03, 0.02)).export(tmp_path / "box.obj")
    with pytest.raises(ValueError, match=message):
        object_from_config({"name": "part", "mesh": str(tmp_path / "box.obj"), **cfg})


# ------------------------------------------------------------------------------------- generation


def test_generation_refuses_a_negative_seed_and_a_file_as_out(tmp_path: Path) -> None:
    from opnet.synthesis import generate_dataset

    obj = builtin_object("zbracket")
    with pytest.raises(ValueError, match=r"^seed=-1: expected a whole number >= 0"):
        generate_dataset(obj, tmp_path / "data", cycles=0, drops=1, seed=-1, progress=False)
    (tmp_path / "file").write_text("x")
    with pytest.raises(ValueError, match=r"out=.*file: exists and is not a folder"):
        generate_dataset(obj, tmp_path / "file", cycles=0, drops=1, progress=False)


@pytest.mark.parametrize(("key", "value"), [("seed", "abc"), ("cycles", True), ("drops", 1.5)])
def test_generate_command_line_numbers_name_the_key(key: str, value: Any) -> None:
    from opnet.cli.generate import whole_number

    with pytest.raises(ValueError, match=rf"^{key}=.*: expected a whole number"):
        whole_number(value, key)


# -------------------------------------------------------------------------------------- full disk


def test_a_full_disk_is_one_line_naming_the_file_and_leaves_no_temporary(tmp_path: Path,
                                                                         monkeypatch: pytest.MonkeyPatch) -> None:
    import opnet.fileio.atomic as atomic

    monkeypatch.setattr(atomic.os, "fdopen", FullDisk)
    with pytest.raises(DiskFullError, match=rf"^{tmp_path / 'x.json'}: No space left on device \(disk full\)"):
        write_bytes_atomic(tmp_path / "x.json", b"{}")
    assert list(tmp_path.iterdir()) == []


def test_entry_points_report_a_full_disk_in_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    from opnet.cli.console import guarded

    def run(_: Any) -> None:
        raise DiskFullError(errno.ENOSPC, os.strerror(errno.ENOSPC), "/out/x.json")

    with pytest.raises(SystemExit) as exit_info:
        guarded(run, None)
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        "error: /out/x.json: No space left on device (disk full); free some space or choose another output folder"]


def test_export_on_a_full_disk_removes_its_temporary_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("onnx")
    import onnx
    from conftest import compose_cfg

    from opnet.cli.build import build_components
    from opnet.deploy.export import export_onnx

    def save(proto: Any, path: str) -> None:
        Path(path).write_bytes(b"half a model")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(onnx, "save", save)
    cfg = compose_cfg("train", ["model=tiny", "object=zbracket"])
    out = tmp_path / "model.onnx"
    with pytest.raises(DiskFullError, match=rf"^{out}: No space left on device"):
        export_onnx(build_components(cfg).system.eval(), cfg, Path("none.ckpt"), out)
    assert list(tmp_path.iterdir()) == []  # before: .model.onnx.tmp stayed


def test_a_fifo_onnx_model_is_named_a_fifo(tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    from opnet.deploy.runtime import OnnxPoseEstimator

    os.mkfifo(tmp_path / "model.onnx")  # used to be "ONNX model not found"
    with pytest.raises(ValueError, match=r"model.onnx: not a regular file \(a FIFO\)"):
        OnnxPoseEstimator(tmp_path / "model.onnx")


@pytest.mark.parametrize("out", ["file", "/dev/null"])
def test_eval_refuses_out_that_is_a_file_before_evaluating(out: str, tmp_path: Path) -> None:
    from conftest import compose_cfg

    from opnet.cli import eval as eval_cli

    target = tmp_path / "file" if out == "file" else Path(out)
    (tmp_path / "file").write_text("x")  # used to fail with a raw FileExistsError after the whole evaluation
    cfg = compose_cfg("eval", [f"ckpt={tmp_path / 'none.ckpt'}", f"out={target}"])
    with pytest.raises(ValueError, match=rf"^{target}: exists and is not a folder; choose another out="):
        eval_cli.run(cfg)


def test_a_folder_filled_by_another_run_meanwhile_is_not_replaced(tmp_path: Path) -> None:
    from opnet.datasets.outputs import folder_replaced

    target = tmp_path / "bop"
    with pytest.raises(ValueError, match=rf"^{target}: another run filled this folder while this one was writing"):
        with folder_replaced(target, overwrite=False) as tmp:
            (tmp / "mine.txt").write_text("this run")
            target.mkdir()  # a concurrent writer finished first (it passed the emptiness check too)
            (target / "theirs.txt").write_text("other run")
    assert [p.name for p in tmp_path.iterdir()] == ["bop"] and [p.name for p in target.iterdir()] == ["theirs.txt"]


def test_a_config_key_its_component_does_not_take_names_the_group() -> None:
    from conftest import compose_cfg

    from opnet.cli.build import build_components

    cfg = compose_cfg("train", ["model=tiny", "object=zbracket", "+parameterization.colour=red"])
    with pytest.raises(ValueError, match=r"^parameterization\.colour='red': not a setting of parameterization \(Vanilla"):
        build_components(cfg)  # used to be Hydra's InstantiationException: a traceback


def test_a_bop_split_without_images_is_named(tmp_path: Path) -> None:
    split = _bop_split(tmp_path)
    (split / "000000" / "scene_gt.json").write_text("{}")  # used to be an IndexError
    with pytest.raises(ValueError, match=rf"^{split}: no images: every scene_gt.json of its 1 scene folder"):
        BOPDataset(split, 1)


@pytest.mark.parametrize(("data", "message"), [
    ({"input_size": "abc"}, r"data.input_size='abc': expected a whole number of pixels in \[8, 4096\]"),
    ({"input_size": True}, r"data.input_size=True"),
    ({"input_size": 10**6}, r"data.input_size=1000000"),
    ({"input_size": 128, "fit": "stretch"}, r"data.fit='stretch': expected one of pad"),
])  # fmt: skip
def test_a_checkpoint_framing_is_checked_where_it_is_loaded(data: dict, message: str) -> None:
    from omegaconf import OmegaConf

    from opnet.cli.build import check_saved_settings

    with pytest.raises(ValueError, match=rf"^x.ckpt: the checkpoint's config {message}"):
        check_saved_settings(OmegaConf.create({"data": data}), "x.ckpt")  # predict.py used to fail on int('abc')
    check_saved_settings(OmegaConf.create({"data": {"input_size": 128, "fit": "pad"}}), "x.ckpt")


def test_a_full_disk_while_replacing_a_folder_names_the_target(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import opnet.fileio.atomic as atomic
    from opnet.datasets.outputs import folder_replaced

    monkeypatch.setattr(atomic.os, "fdopen", FullDisk)
    target = tmp_path / "bop"
    with pytest.raises(DiskFullError, match=rf"^{target / 'models' / 'x.json'}: No space left on device"):
        with folder_replaced(target, overwrite=False) as tmp:
            write_bytes_atomic(tmp / "models" / "x.json", b"{}")  # used to name the deleted temporary folder
    assert list(tmp_path.iterdir()) == []


def test_deploy_names_its_own_overwrite_option(tmp_path: Path) -> None:
    from opnet.datasets.depth_inputs import check_outputs

    image = tmp_path / "x.npy"
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "x.json").write_text("{}")
    with pytest.raises(ValueError, match=r"x.json: predictions exist already; pass --overwrite to replace them, or "
                                         r"choose another --out$"):  # was predict.py's overwrite=true
        check_outputs(tmp_path / "out", [(image, Path("x"))], False, option="--out")
