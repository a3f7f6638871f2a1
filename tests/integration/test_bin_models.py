"""Several bin models within one generated dataset (``scene.bin_models``): each pile's bin drawn from
them by its share, recorded with the pile, built as drawn (physics and rendering), the same for any
worker count; without models, the datasets of before, byte for byte."""

from __future__ import annotations

import csv
import hashlib
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from opnet.datasets.ipa import IPADataset
from opnet.objects import builtin_object
from opnet.synthesis import SceneConfig, generate_dataset
from opnet.synthesis.cycle import draw_bin_model
from opnet.synthesis.layout import make_rig
from opnet.synthesis.writer import read_bin_model

# a fixed camera looking straight down on a level bin that does not move: a bin's size and clearance
# show at known pixels and depths
HEIGHT = 0.5
FIXED = {"resolution": 128, "camera_height": HEIGHT, "clip": [None, 1.0], "camera_jitter_m": 0.0, "camera_jitter_deg": 0.0,
         "bin_jitter_m": 0.0, "bin_jitter_deg": 0.0, "collision": "convex_hull", "bin_wall_height": 0.03}
MODELS = [
    {"bin_inner": 0.10},
    {"bin_inner": 0.16, "weight": 2.0},
    {"bin_inner": 0.10, "bin_hole_size": 0.01, "bin_hole_pitch": 0.02, "bin_clearance": 0.04},
]


def _tree(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*")) if p.is_file()}


def _floor(depth: np.ndarray) -> tuple[int, float]:
    """(pixels, deepest depth): the centre row's run of pixels at or below the floor top about the
    image centre (the inner faces of the walls, nearer than the floor, end it); the deepest pixel
    of the 11 x 11 pixels (4 cm of floor) about the centre."""
    c = depth.shape[0] // 2
    row = depth[c]
    deep = np.nan_to_num(row, nan=np.inf) >= HEIGHT - 1e-3
    lo, hi = c, c
    while lo > 0 and deep[lo - 1]:
        lo -= 1
    while hi < len(row) - 1 and deep[hi + 1]:
        hi += 1
    return hi - lo + 1, float(np.nanmax(depth[c - 5:c + 6, c - 5:c + 6]))


def test_each_pile_draws_its_model_by_weight_and_the_same_for_a_seed() -> None:
    scene = SceneConfig(bin_models=MODELS)
    draws = np.array([draw_bin_model(scene, 3, pile) for pile in range(3000)])
    shares = np.bincount(draws, minlength=3) / len(draws)
    assert np.allclose(shares, [0.25, 0.5, 0.25], atol=0.03), shares
    assert [draw_bin_model(scene, 3, p) for p in range(30)] == draws[:30].tolist()  # per (seed, pile)
    assert [draw_bin_model(scene, 4, p) for p in range(30)] != draws[:30].tolist()
    assert np.bincount(draws[:30], minlength=3).min() >= 3  # 30 piles: every model has its piles
    assert draw_bin_model(SceneConfig(), 3, 0) == 0


def test_each_pile_is_rendered_with_the_bin_it_records_and_any_worker_count_gives_its_bytes(tmp_path: Path) -> None:
    scene = SceneConfig(**FIXED, bin_models=MODELS)
    obj = builtin_object("bracket")
    kwargs = {"cycles": 9, "drops": 0, "seed": 2, "scene": scene, "previews": 0, "progress": False}
    generate_dataset(obj, tmp_path / "one", workers=1, **kwargs)
    generate_dataset(obj, tmp_path / "two", workers=2, **kwargs)
    assert _tree(tmp_path / "one") == _tree(tmp_path / "two")

    ds = IPADataset(tmp_path / "one")
    fx = ds.params.camera().fx
    drawn = []
    for cycle in range(9):
        record = read_bin_model(tmp_path / "one", cycle)
        model = record["bin_model"]
        drawn.append(model)
        assert model == draw_bin_model(scene, 2, cycle) and record["pile"] == cycle
        assert record["settings"] == MODELS[model] and record["bin"]["inner"] == MODELS[model]["bin_inner"]
        pixels, deepest = _floor(ds.read(cycle, 0).depth)
        # the floor spans the model's inner side; holes show the ground its clearance below the floor
        assert abs(pixels - MODELS[model]["bin_inner"] * fx / HEIGHT) <= 3, (cycle, model, pixels)
        expected = HEIGHT + (0.01 + 0.04 if model == 2 else 0.0)
        assert deepest == pytest.approx(expected, abs=2e-3), (cycle, model, deepest)
    assert len(set(drawn)) == 3
    assert json.loads((tmp_path / "one" / "generation.json").read_text())["scene"]["bin_models"] == MODELS


@pytest.mark.parametrize("tilt", [0.0, 20.0])
def test_the_camera_is_sized_for_the_largest_model(tilt: float) -> None:
    """The camera as high as the widest bin needs, its near plane above the tallest walls."""
    obj = builtin_object("bracket")
    wide, tall = {"bin_inner": 0.20, "bin_wall_height": 0.02}, {"bin_inner": 0.10, "bin_wall_height": 0.08}
    both = make_rig(obj, 5, 1, SceneConfig(resolution=128, camera_tilt_deg=tilt, bin_models=[tall, wide]))
    alone = make_rig(obj, 5, 1, SceneConfig(resolution=128, camera_tilt_deg=tilt, **wide))
    assert both.params.location == alone.params.location and both.camera.clip_end == alone.camera.clip_end
    tall_there = make_rig(obj, 5, 1, SceneConfig(resolution=128, camera_tilt_deg=tilt,
                                                 camera_height=both.params.location[2], **tall))
    assert both.camera.clip_start == tall_there.camera.clip_start < alone.camera.clip_start
    assert [b.inner for b in both.bins] == [0.10, 0.20] and both.with_bin(1).bin.inner == 0.20 == both.with_bin(1).bins[1].inner


# the pre-change generator's files of this dataset: its root JSON files and ground-truth CSVs (its PNGs are
# checked below against a dataset whose one model is the default bin). Physics and rendering are deterministic on
# one machine but not bit for bit across CPUs (another instruction set rounds the last bits differently, and a
# pile amplifies that: a 1e-12 m change of the drop height moves the settled poses by about 1e-7), so the poses are
# compared within POSE_TOL and the visibilities within VIS_TOL (a pixel of a 64-pixel image); a changed draw or
# pile moves them by centimetres.
_GOLDEN = Path(__file__).with_name("golden") / "bin_models_null.json"
POSE_TOL, VIS_TOL = 1e-4, 0.02


def _same_numbers(a: Any, b: Any, where: str) -> None:
    """``a`` and ``b`` the same JSON data, numbers equal to 1e-9 (relative)."""
    if isinstance(b, dict):
        assert isinstance(a, dict) and set(a) == set(b), where
        for k in b:
            _same_numbers(a[k], b[k], f"{where}.{k}")
    elif isinstance(b, list):
        assert isinstance(a, list) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _same_numbers(x, y, f"{where}[{i}]")
    elif isinstance(b, float) and not isinstance(a, bool):
        assert a == pytest.approx(b, rel=1e-9, abs=1e-12), where
    else:
        assert a == b, where


def _assert_golden(root: Path) -> None:
    golden = json.loads(_GOLDEN.read_text())
    assert sorted(p.name for p in root.glob("*.json")) == sorted(golden["json"])
    for name, data in golden["json"].items():
        _same_numbers(json.loads((root / name).read_text()), data, name)
    assert sorted(str(p.relative_to(root / "gt")) for p in (root / "gt").rglob("*.csv")) == sorted(golden["gt"])
    for name, want in golden["gt"].items():
        with (root / "gt" / name).open() as f:
            rows = list(csv.reader(f))
        assert rows[0] == want["header"], name
        got, ref = np.array(rows[1:], float).reshape(-1, len(want["header"])), np.array(want["rows"]).reshape(-1, len(want["header"]))
        assert got.shape == ref.shape and (got[:, :2] == ref[:, :2]).all(), name  # the same parts, ids and classes
        np.testing.assert_allclose(got[:, 2:14], ref[:, 2:14], rtol=0, atol=POSE_TOL, err_msg=name)  # x y z, R
        np.testing.assert_allclose(got[:, 14:], ref[:, 14:], rtol=0, atol=VIS_TOL, err_msg=name)


def test_without_models_the_datasets_keep_their_bytes(tmp_path: Path) -> None:
    obj = builtin_object("bracket")
    kwargs = {"cycles": 2, "drops": 3, "seed": 5, "previews": 0, "progress": False}
    generate_dataset(obj, tmp_path / "null", scene=SceneConfig(resolution=64, collision="convex_hull"), **kwargs)
    generate_dataset(obj, tmp_path / "one", scene=SceneConfig(resolution=64, collision="convex_hull", bin_models=[{}]),
                     **kwargs)
    null, one = _tree(tmp_path / "null"), _tree(tmp_path / "one")
    _assert_golden(tmp_path / "null")
    assert "bin_models" not in json.loads((tmp_path / "null" / "generation.json").read_text())["scene"]
    assert not list((tmp_path / "null").rglob("bin_model.json"))
    # one model that is the default bin: the same piles, the same pixels, plus what says so
    assert {k: v for k, v in one.items() if k.endswith((".png", ".csv"))} == {k: v for k, v in null.items()
                                                                            if k.endswith((".png", ".csv"))}
    assert read_bin_model(tmp_path / "one", 1)["settings"] == {}


def test_a_dataset_with_models_completes_to_the_bytes_of_one_run(tmp_path: Path) -> None:
    """More cycles later (a resumed or extended run): the first cycles stay, the new ones are those of
    one run; every view of a pile shows the pile's bin."""
    scene = SceneConfig(**FIXED, views=2, bin_models=MODELS)
    kwargs = {"drops": 0, "seed": 7, "scene": scene, "previews": 0, "progress": False}
    obj = builtin_object("bracket")
    generate_dataset(obj, tmp_path / "grown", cycles=4, **kwargs)
    generate_dataset(obj, tmp_path / "grown", cycles=8, **kwargs)
    generate_dataset(obj, tmp_path / "once", cycles=8, **kwargs)
    assert _tree(tmp_path / "grown") == _tree(tmp_path / "once")
    for cycle in range(8):
        assert read_bin_model(tmp_path / "once", cycle)["bin_model"] == draw_bin_model(scene, 7, cycle // 2)


@pytest.mark.parametrize(("models", "match"), [
    ([], r"bin_models=\[\], expected null or a non-empty list"),
    ({"bin_inner": 0.1}, r"bin_models=.*expected null or a non-empty list"),
    ([{"bin_inner": 0.1}, {"bin_colour": "red"}], r"bin_models\[1\]: unknown keys \['bin_colour'\]"),
    ([{"bin_hole_size": 0.0001, "bin_hole_pitch": 0.01}], r"bin_models\[0\]\.bin_hole_size=0\.0001, expected 0 \(solid\)"),
    ([{}, {"bin_hole_size": 0.02}], r"bin_models\[1\]\.bin_hole_pitch=0\.0, expected metres > bin_hole_size"),
    ([{"bin_clearance": -0.1}], r"bin_models\[0\]\.bin_clearance=-0\.1, expected a number >= 0"),
    ([{"bin_inner": 40.0}], r"bin_models\[0\]\.bin_inner=40\.0, expected at most 20 metres"),
    ([{"weight": 0}], r"bin_models\[0\]\.weight=0, expected a number > 0"),
    (["solid"], r"bin_models\[0\]='solid', expected a mapping"),
])  # fmt: skip
def test_bad_models_are_one_line_errors_naming_the_model_and_key(models: object, match: str) -> None:
    with pytest.raises(ValueError, match=match) as info:
        SceneConfig(bin_models=models)
    assert "\n" not in str(info.value)


def test_a_model_that_leaves_the_working_areas_view_is_refused() -> None:
    obj = builtin_object("bracket")
    cfg = {"resolution": 128, "camera_height": 0.6, "bin_area": (-0.05, -0.05, 0.05, 0.05)}
    half_view = 0.6 * math.tan(math.radians(25.0))  # 0.28 m: a 0.2 m floor fits anywhere in the area, 0.4 m does not
    assert half_view > 0.05 + math.hypot(0.1, 0.1)
    make_rig(obj, 5, 1, SceneConfig(**cfg, bin_models=[{"bin_inner": 0.2}]))
    with pytest.raises(ValueError, match=r"bin_models\[1\]: its floor \(0\.4 x 0\.4 m\) standing at the bin_area corner "
                                         r"\(-0\.05, -0\.05\) m leaves the camera's view") as info:
        make_rig(obj, 5, 1, SceneConfig(**cfg, bin_models=[{"bin_inner": 0.2}, {"bin_inner": 0.4}]))
    assert "\n" not in str(info.value)
    # perforations alone leave the configured bin's floor where it was: checked as the configured bin is
    holes = [{"bin_hole_size": 0.01, "bin_hole_pitch": 0.02}, {"bin_hole_size": 0.02, "bin_hole_pitch": 0.03}]
    make_rig(obj, 5, 1, SceneConfig(**cfg, bin_inner=0.4, bin_models=holes))
    make_rig(obj, 5, 1, SceneConfig(**cfg, bin_inner=0.4))
    with pytest.raises(ValueError, match=r"bin_models\[1\]: its floor"):
        make_rig(obj, 5, 1, SceneConfig(**cfg, bin_inner=0.4, bin_models=[holes[0], {"bin_clearance": 0.1}]))


def test_train_pys_scene_node_gives_the_models_of_the_command_line() -> None:
    """``python train.py experiment=cell "scene.bin_models=[{...}, {...}]"``: the composed node (a Hydra
    ListConfig of DictConfigs, as the data module hands it on) reads as the same models as plain lists."""
    from conftest import compose_cfg

    cfg = compose_cfg("train", ["scene.bin_models=[{bin_hole_size:0.012,bin_hole_pitch:0.018},{bin_inner:0.3}]"])
    plain = [{"bin_hole_size": 0.012, "bin_hole_pitch": 0.018}, {"bin_inner": 0.3}]
    assert SceneConfig.from_dict(dict(cfg.scene)).bin_models == SceneConfig(bin_models=plain).bin_models
