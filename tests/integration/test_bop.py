"""BOP interoperability: symmetry mapping (hand-checked), IPA -> BOP -> reader round trip, training
and evaluation on a BOP split, the BOP results CSV, and clear errors on bad BOP files."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from opnet.cli import eval as eval_cli
from opnet.cli import train as train_cli
from opnet.datasets.bop import BOPDataset, bop_symmetry_entries, convert_ipa_to_bop, symmetry_from_bop
from opnet.datasets.ipa import IPADataset
from opnet.geometry.symmetry import Symmetry
from conftest import compose_cfg


def _rot(axis: str, deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return {"x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]), "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def _m16(R: np.ndarray, t: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> list[float]:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T.reshape(-1).tolist()


@pytest.mark.parametrize(("info", "kind", "order", "flip", "axis"), [
    ({}, "none", 1, False, None),
    ({"symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]}, "revolution", 1, False, [0, 0, 1]),
    ({"symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}], "symmetries_discrete": [_m16(_rot("x", 180))]},
     "revolution", 1, True, [0, 0, 1]),
    ({"symmetries_continuous": [{"axis": [0, 1, 0], "offset": [0, 5, 0]}]}, "revolution", 1, False, [0, 1, 0]),
    ({"symmetries_discrete": [_m16(_rot("z", 180))]}, "cyclic", 2, False, [0, 0, 1]),
    ({"symmetries_discrete": [_m16(_rot("z", a)) for a in (90, 180, 270)]}, "cyclic", 4, False, [0, 0, 1]),
    ({"symmetries_discrete": [_m16(_rot("x", 180))]}, "cyclic", 2, False, [1, 0, 0]),
])  # fmt: skip
def test_bop_symmetries_map_to_opnet(info: dict, kind: str, order: int, flip: bool, axis: list | None) -> None:
    info = {"diameter": 100.0, **info}
    sym, A = symmetry_from_bop(info, "models_info.json")
    assert (sym.kind, sym.order, sym.rotoreflection) == (kind, order, flip)
    assert np.allclose(A @ A.T, np.eye(3)) and np.linalg.det(A) > 0
    if axis is not None:
        a = np.array(axis, float)
        assert np.allclose(A @ (a / np.linalg.norm(a)), [0, 0, 1])  # the symmetry axis becomes z
    # and back: the entries we write read back as the same symmetry
    again, A2 = symmetry_from_bop({"diameter": 100.0, **bop_symmetry_entries(sym)}, "x")
    assert (again.kind, again.order, again.rotoreflection) == (kind, order, flip) and np.allclose(A2, np.eye(3))


def test_dihedral_bop_symmetry_is_a_finite_group() -> None:
    sym, A = symmetry_from_bop({"diameter": 50.0, "symmetries_discrete": [
        _m16(_rot("z", 180)), _m16(_rot("x", 180)), _m16(_rot("y", 180))]}, "m")
    assert sym.kind == "finite" and len(sym.group()) == 4 and np.allclose(A, np.eye(3))


@pytest.mark.parametrize(("info", "message"), [
    ({"symmetries_continuous": [{"axis": [0, 0, 1]}, {"axis": [0, 1, 0]}]}, "2 continuous symmetry axes"),
    ({"symmetries_continuous": [{"axis": [0, 0, 1], "offset": [20, 0, 0]}]}, "misses the model origin by 20 mm"),
    ({"symmetries_discrete": [_m16(_rot("z", 180), (10.0, 0.0, 0.0))]}, "moves the origin by 10 mm"),
    ({"symmetries_discrete": [_m16(np.diag([1.0, 1.0, -1.0]))]}, "not a rotation"),
    ({"symmetries_discrete": [_m16(_rot("z", 90))]}, "not closed"),
])  # fmt: skip
def test_unmappable_bop_symmetries_are_clear_errors(info: dict, message: str) -> None:
    with pytest.raises(ValueError, match=rf"models_info.json: obj_id 7: .*{message}"):
        symmetry_from_bop({"diameter": 100.0, **info}, "models_info.json: obj_id 7")


@pytest.fixture(scope="module")
def bop_split(tiny_dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return convert_ipa_to_bop(tiny_dataset, tmp_path_factory.mktemp("bop") / "zbracket_bop", split="train_synt", obj_id=3)


def test_ipa_to_bop_round_trip_gives_the_same_records(tiny_dataset: Path, bop_split: Path) -> None:
    ipa = IPADataset(tiny_dataset)
    bop = BOPDataset(bop_split, 3, clip=(ipa.camera.clip_start, ipa.camera.clip_end))
    assert [s[:2] for s in bop.scenes()] == ipa.scenes() and len(bop) == len(ipa)
    assert (bop.symmetry.kind, bop.symmetry.order) == ("cyclic", 2) and np.allclose(bop.R_align, np.eye(3))
    for (c, n), (sid, im, count) in zip(ipa.scenes(), bop.scenes()):
        a, b = ipa.read(c, n), bop.read(sid, im)
        assert count == a.num_objects == b.num_objects
        np.testing.assert_allclose(b.R_cam_obj, a.R_cam_obj, atol=1e-12)
        np.testing.assert_allclose(b.t_cam_obj, a.t_cam_obj, atol=1e-9)
        np.testing.assert_allclose(b.visibility, np.clip(a.visibility, 0, 1), atol=1e-12)
        np.testing.assert_array_equal(b.instance_id, a.instance_id)
        assert b.camera.fx == pytest.approx(a.camera.fx) and b.camera.cx == pytest.approx(a.camera.cx)
        both = np.isfinite(a.depth) & np.isfinite(b.depth)
        assert (np.isfinite(a.depth) == np.isfinite(b.depth)).mean() > 0.999
        assert np.abs(a.depth[both] - b.depth[both]).max() <= 0.5e-4 + 1e-7  # BOP's 0.1 mm step
        np.testing.assert_array_equal(np.where(a.segmentation > 0, a.segmentation, 0), b.segmentation)


def test_train_and_evaluate_on_a_bop_split(bop_split: Path, tmp_path: Path) -> None:
    overrides = ["data=bop", "object=bop", f"data.root={bop_split}", "data.object_id=3", "model=tiny",
                 "data.batch_size=4", "data.val_fraction=0.25", "data.test_fraction=0.25", "data.num_workers=0",
                 "trainer.max_epochs=1", "+trainer.limit_train_batches=2", "+trainer.limit_val_batches=1",
                 "trainer.enable_progress_bar=false", "example_predictions=0"]
    cfg = compose_cfg("train", overrides)
    from omegaconf import OmegaConf

    OmegaConf.update(cfg, "paths.output_dir", str(tmp_path / "run"), force_add=True)
    result = train_cli.run(cfg)
    assert result["scenes"] > 0 and result["object"] == "bop_obj_3"
    ev = eval_cli.run(compose_cfg("eval", [f"ckpt={tmp_path / 'run' / 'checkpoints' / 'last.ckpt'}",
                                           f"out={tmp_path / 'eval'}", "examples=0"]))
    assert ev["scenes"] == result["scenes"]
    rows = (tmp_path / "eval" / "bop_results.csv").read_text().splitlines()
    assert rows[0] == "scene_id,im_id,obj_id,score,R,t,time"
    if len(rows) > 1:
        sid, im, obj, score, R, t, _ = rows[1].split(",")
        assert obj == "3" and len(R.split()) == 9 and len(t.split()) == 3


def _break(split: Path, tmp: Path, change: str) -> Path:
    root = tmp / "broken"
    shutil.copytree(split.parent, root)
    scene = root / split.name / "000000"
    cam = json.loads((scene / "scene_camera.json").read_text())
    if change == "missing_cam_K":
        del cam["1"]["cam_K"]
    elif change == "depth_scale_0":
        cam["1"]["depth_scale"] = 0
    (scene / "scene_camera.json").write_text(json.dumps(cam))
    if change == "mask_size":
        mask = next((scene / "mask_visib").glob("000001_*.png"))
        import cv2

        cv2.imwrite(str(mask), np.zeros((10, 12), np.uint8))
    return root / split.name


@pytest.mark.parametrize(("change", "message"), [
    ("missing_cam_K", r"scene_camera.json: image 1: missing key 'cam_K'"),
    ("depth_scale_0", r"scene_camera.json: image 1: 'depth_scale' = 0, expected > 0"),
    ("mask_size", r"000001_000000.png: mask is 12x10, the depth image 000001.png is 128x128"),
])  # fmt: skip
def test_bad_bop_files_name_the_file(change: str, message: str, bop_split: Path, tmp_path: Path) -> None:
    split = _break(bop_split, tmp_path, change)
    with pytest.raises(ValueError, match=message):
        BOPDataset(split, 3, clip=(0.5, 1.5)).read(0, 1)


def test_unknown_obj_id_names_models_info(bop_split: Path) -> None:
    with pytest.raises(ValueError, match=r"models_info.json: obj_id 9 is not in this dataset's models \(ids: 3\)"):
        BOPDataset(bop_split, 9)


def test_converter_command(tiny_dataset: Path, tmp_path: Path) -> None:
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-m", "opnet.datasets.bop", str(tiny_dataset), str(tmp_path / "bop"),
                           "--obj-id", "5"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "data=bop object=bop" in proc.stdout
    info = json.loads((tmp_path / "bop" / "models" / "models_info.json").read_text())
    assert set(info) == {"5"} and info["5"]["diameter"] > 0 and len(info["5"]["symmetries_discrete"]) == 1
    assert (tmp_path / "bop" / "models" / "obj_000005.ply").is_file()
    bad = subprocess.run([sys.executable, "-m", "opnet.datasets.bop", str(tmp_path / "nope"), str(tmp_path / "b2")],
                         capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "nope" in bad.stderr and "Traceback" not in bad.stderr


def test_bop_split_without_object_id_is_a_clear_error(bop_split: Path) -> None:
    from opnet.datasets import open_dataset

    with pytest.raises(ValueError, match="data.object_id"):
        open_dataset(bop_split)
    assert Symmetry("none").kind == "none"
