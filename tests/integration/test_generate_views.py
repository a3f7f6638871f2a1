"""Several views per settled pile (``scene.views``): one simulation, several cycles on disk."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from opnet.datasets.bop import BOPDataset, convert_ipa_to_bop
from opnet.datasets.ipa import IPADataset, read_ipa_csv, scene_paths
from opnet.objects import builtin_object
from opnet.synthesis import SceneConfig, generate_dataset
from opnet.synthesis.layout import inverse_pose, make_rig

SCENE = SceneConfig(resolution=128, collision="convex_hull", camera_jitter_m=0.02, camera_jitter_deg=3.0)
DROPS = 3


def _files(root: Path, cycle: int) -> dict[str, str]:
    folder = f"cycle_{cycle:04d}"
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and folder in p.parts}


def _bin_frame_poses(record, R_cam_bin: np.ndarray, t_cam_bin: np.ndarray) -> np.ndarray:
    T_cam_bin = np.eye(4)
    T_cam_bin[:3, :3], T_cam_bin[:3, 3] = R_cam_bin, t_cam_bin
    T = np.tile(np.eye(4), (record.num_objects, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = record.R_cam_obj, record.t_cam_obj
    return inverse_pose(T_cam_bin) @ T


@pytest.fixture(scope="module")
def two_views(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("views") / "v2"
    scene = SceneConfig.from_dict({**SCENE.to_dict(), "views": 2})
    report = generate_dataset(builtin_object("bracket"), out, cycles=6, drops=DROPS, seed=3, scene=scene,
                              progress=False, previews=0)
    assert (report.cycles_generated, report.piles_simulated, report.scenes_written) == (6, 3, 6 * (DROPS + 1))
    return out


def test_views_share_the_pile_and_differ_in_camera(two_views: Path) -> None:
    ds = IPADataset(two_views)
    assert len(ds) == 6 * (DROPS + 1)

    for pile in (0, 1):
        a, b = ds.read(2 * pile, DROPS), ds.read(2 * pile + 1, DROPS)
        gt_a = read_ipa_csv(scene_paths(two_views, 2 * pile, DROPS)["csv"])
        gt_b = read_ipa_csv(scene_paths(two_views, 2 * pile + 1, DROPS)["csv"])
        # the same parts in the same places relative to the bin ...
        np.testing.assert_allclose(_bin_frame_poses(a, gt_a.R_cam_bin, gt_a.t_cam_bin),
                                   _bin_frame_poses(b, gt_b.R_cam_bin, gt_b.t_cam_bin), atol=2e-6)
        # ... seen from another camera
        assert np.linalg.norm(gt_a.t_cam_bin - gt_b.t_cam_bin) > 1e-3
        assert not np.array_equal(a.depth, b.depth)
    # different piles are different
    assert not np.allclose(ds.read(0, DROPS).t_cam_obj, ds.read(2, DROPS).t_cam_obj, atol=1e-3)


def test_view_zero_is_the_cycle_of_a_dataset_without_views(two_views: Path, tmp_path: Path) -> None:
    one = tmp_path / "v1"
    generate_dataset(builtin_object("bracket"), one, cycles=2, drops=DROPS, seed=3, scene=SCENE, progress=False,
                     previews=0)
    # pile p of views=2 is cycle p of views=1: view 0 of pile 1 (cycle 2) equals cycle 1
    assert _files(two_views, 0) == _files(one, 0)
    renamed = {k.replace("cycle_0002", "cycle_0001"): v for k, v in _files(two_views, 2).items()}
    assert renamed == _files(one, 1)


def test_views_resume_to_the_same_bytes(two_views: Path, tmp_path: Path) -> None:
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(two_views, copy)
    (copy / "gt" / "cycle_0003" / f"{DROPS:03d}.csv").unlink()  # view 1 of pile 1 incomplete
    scene = SceneConfig.from_dict({**SCENE.to_dict(), "views": 2})
    report = generate_dataset(builtin_object("bracket"), copy, cycles=6, drops=DROPS, seed=3, scene=scene,
                              progress=False, previews=0)
    assert (report.cycles_generated, report.cycles_skipped, report.piles_simulated) == (1, 5, 1)
    for c in range(6):
        assert _files(copy, c) == _files(two_views, c)


def test_views_read_back_through_bop(two_views: Path, tmp_path: Path) -> None:
    bop = convert_ipa_to_bop(two_views, tmp_path / "bop", split="train_synt", obj_id=1)
    ds, ipa = BOPDataset(bop, obj_id=1), IPADataset(two_views)
    assert len(ds) == len(ipa)
    t_bop = sorted(np.round(ds[i].t_cam_obj, 4).tobytes() for i in range(len(ds)))
    t_ipa = sorted(np.round(ipa[i].t_cam_obj, 4).tobytes() for i in range(len(ipa)))
    assert t_bop == t_ipa


def test_views_read_back_as_sileane_ground_truth(two_views: Path, tmp_path: Path) -> None:
    from opnet.datasets.convert import convert_dataset
    from opnet.datasets.sileane_json import read_gt_json

    files = convert_dataset(two_views, tmp_path / "gt")
    ipa = IPADataset(two_views)
    assert len(files) == len(ipa)
    for c in (0, 1):  # the two views of pile 0: one scene each, its own camera-frame poses
        record = ipa.read(c, DROPS)
        gt = read_gt_json(tmp_path / "gt" / f"{record.name}.json")
        np.testing.assert_allclose(np.sort(gt.t[:, 2]), np.sort(record.t_cam_obj[:, 2]), atol=1e-6)


@pytest.mark.parametrize("key, value", [("views", 0), ("views", -2), ("views", True), ("views", 1.5),
                                        ("camera_jitter_deg", 60.0)])
def test_bad_views_and_jitter_name_the_key(key: str, value: object) -> None:
    with pytest.raises(ValueError, match=f"{key}="):
        SceneConfig.from_dict({**SCENE.to_dict(), key: value})


@pytest.mark.parametrize("key, value", [("camera_jitter_m", 5.0), ("camera_jitter_deg", 30.0)])
def test_impossible_camera_jitter_names_the_key(key: str, value: float) -> None:
    scene = SceneConfig.from_dict({**SCENE.to_dict(), key: value})
    with pytest.raises(ValueError, match=f"{key}="):
        make_rig(builtin_object("bracket"), DROPS, 1, scene)


def test_splits_keep_the_views_of_a_pile_together(two_views: Path) -> None:
    from opnet.data.scene_data import SceneData

    dm = SceneData(builtin_object("bracket"), two_views, val_fraction=0.5, test_fraction=0.0, cache=False,
                         check="off", test_root=two_views, test_min_objects=DROPS)
    dm.setup()
    piles = {split: {int(dm.splits[split].record(i).name.split("_")[1]) // 2 for i in range(len(dm.splits[split]))} for split in ("train", "val")}
    assert piles["train"] and piles["val"] and not piles["train"] & piles["val"]
    # the test split: only the full piles of test_root
    assert sorted(dm.splits["test"].record(i).name for i in range(len(dm.splits["test"]))) == [f"cycle_{c:04d}_{DROPS:03d}" for c in range(6)]
    with pytest.raises(ValueError, match="test_min_objects"):
        SceneData(builtin_object("bracket"), two_views, test_min_objects=-1)


def test_a_validation_dataset_of_its_own_replaces_the_held_out_share(two_views: Path) -> None:
    from opnet.data.scene_data import SceneData

    dm = SceneData(builtin_object("bracket"), two_views, val_fraction=0.5, test_fraction=0.0, cache=False,
                   check="off", val_root=two_views, test_min_objects=DROPS)
    dm.setup()
    names = {split: [dm.splits[split].record(i).name for i in range(len(dm.splits[split]))] for split in dm.splits}
    # the validation split: only the full piles of val_root, every one of them
    assert sorted(names["val"]) == [f"cycle_{c:04d}_{DROPS:03d}" for c in range(6)]
    # and the share val_fraction would have held out is trained on: every pile of root, every scene
    assert {int(n.split("_")[1]) // 2 for n in names["train"]} == {0, 1, 2}
    assert len(names["train"]) == 6 * DROPS  # the empty bins (0 parts) are left out as ever


def test_rotation_refused_for_data_without_segmentation(two_views: Path, tmp_path: Path) -> None:
    import shutil

    from opnet.data.augment import DepthAugmenter
    from opnet.data.scene_data import SceneData

    bare = tmp_path / "bare"
    shutil.copytree(two_views, bare)
    shutil.rmtree(bare / "p_segmentation")
    make = lambda deg: SceneData(builtin_object("bracket"), bare, cache=False, check="off",  # noqa: E731
                                       augmenter=DepthAugmenter(p_rotate=0.5, rotate_deg=deg))
    with pytest.raises(ValueError, match=r"bare: augmentation.p_rotate=0.5 .* no segmentation"):
        make((-30.0, 30.0)).setup()
    make((180.0, 180.0)).setup()  # the exact half turn needs none


def test_train_groups_keeps_the_first_piles_of_the_training_split(two_views: Path) -> None:
    from opnet.data.scene_data import SceneData

    def piles(dm: SceneData, split: str) -> set[int]:
        return {int(dm.splits[split].record(i).name.split("_")[1]) // 2 for i in range(len(dm.splits[split]))}

    make = lambda n: SceneData(builtin_object("bracket"), two_views, val_fraction=0.34, test_fraction=0.0,  # noqa: E731
                                     cache=False, check="off", train_groups=n)
    full, one = make(None), make(1)
    full.setup()
    one.setup()
    assert len(piles(full, "train")) == 2 and piles(one, "train") == {min(piles(full, "train"))}
    assert len(one.splits["train"]) == len(full.splits["train"]) // 2  # both views of that pile
    assert piles(one, "val") == piles(full, "val")  # the held-out data does not move
    with pytest.raises(ValueError, match="data.train_groups=0, expected null or an integer >= 1"):
        make(0)
