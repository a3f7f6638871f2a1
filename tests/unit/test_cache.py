"""The scene cache: same samples as the dataset files, resumable, rebuilt when stale, bounded."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from opnet.data.cache import (
    SceneCache,
    build_scene_cache,
    decode_depth,
    default_cache_dir,
    encode_depth,
)
from opnet.data.sample import make_sample
from opnet.datasets import open_dataset
from opnet.geometry import Camera


@pytest.fixture(scope="module")
def dataset(builtin_dataset) -> Path:
    return builtin_dataset("pin", 3, 3, 1)


def test_depth_code_round_trip_and_missing_pixels():
    cam = Camera.from_fov(50.0, 4, 1, 0.5, 1.5)
    depth = np.array([[0.5, 1.0, np.nan, 1.5]], np.float32)
    back = decode_depth(encode_depth(depth, cam), cam)
    assert np.isnan(back[0, 2])
    np.testing.assert_allclose(back[0, [0, 1, 3]], depth[0, [0, 1, 3]], atol=1.0 / 65534)


def test_cached_records_give_the_samples_of_the_files(dataset: Path, tmp_path: Path):
    source = open_dataset(dataset)
    cache = build_scene_cache(source, tmp_path / "c", size=128, shard_scenes=5)
    assert len(cache) == len(source) and cache.scenes() == source.scenes()
    assert cache.info.num_shards == -(-len(source) // 5)
    for i in range(len(source)):
        rec, cached = source[i], cache[i]
        assert cached.name == rec.name == cache.scene_name(i)
        np.testing.assert_array_equal(cached.R_cam_obj, rec.R_cam_obj)
        np.testing.assert_array_equal(cached.visibility, rec.visibility)
        a = make_sample(rec, 64, cv2.INTER_AREA)
        b = make_sample(cached, 64, cv2.INTER_AREA)
        assert a.camera == b.camera
        assert np.abs(a.image - b.image).max() < 1e-4  # the 16-bit depth code
        np.testing.assert_array_equal(a.segmentation, b.segmentation)


def test_build_resumes_and_rebuilds_a_stale_cache(dataset: Path, tmp_path: Path):
    source = open_dataset(dataset)
    path = tmp_path / "c"
    build_scene_cache(source, path, size=64, shard_scenes=4)
    shard1 = path / "shard_00001.npz"
    stamp = shard1.stat().st_mtime_ns
    (path / "shard_00002.npz").unlink()  # a crash before this shard was complete
    with pytest.raises(FileNotFoundError, match="incomplete"):
        SceneCache(path)
    cache = build_scene_cache(source, path, size=64, shard_scenes=4)
    assert shard1.stat().st_mtime_ns == stamp  # complete shards are kept
    assert cache[9].name == source[9].name
    cache = build_scene_cache(source, path, size=32, shard_scenes=4)  # other settings: rebuilt
    assert cache[0].depth.shape == (32, 32)


def test_truncated_shard_is_reported(dataset: Path, tmp_path: Path):
    cache = build_scene_cache(open_dataset(dataset), tmp_path / "c", size=64, shard_scenes=50)
    depth = tmp_path / "c" / "shard_00000.depth"
    depth.write_bytes(depth.read_bytes()[:1000])
    with pytest.raises(ValueError, match="truncated"):
        SceneCache(tmp_path / "c")[3]
    assert default_cache_dir(dataset, 64) == dataset / "cache_s64"
    assert len(cache) == 12


def _move_poses(csv: Path, dz: float) -> None:
    """Rewrite an IPA CSV with every pose moved ``dz`` metres along z (same scene list)."""
    from dataclasses import replace

    from opnet.datasets.ipa_csv import read_ipa_csv, write_ipa_csv

    gt = read_ipa_csv(csv)
    write_ipa_csv(csv, replace(gt, t_cam_obj=gt.t_cam_obj + np.array([0.0, 0.0, dz])))


def test_cache_follows_changed_ground_truth_and_images(dataset: Path, tmp_path: Path):
    """The cache was keyed by the scene list only: moved poses still gave the old ground truth."""
    import shutil

    from opnet.datasets.ipa import scene_paths

    data = tmp_path / "d"
    shutil.copytree(dataset, data)
    path = tmp_path / "c"
    old = build_scene_cache(open_dataset(data), path, size=32, shard_scenes=4)
    t_before = old[5].t_cam_obj.copy()
    stamps = {p.name: p.stat().st_mtime_ns for p in path.iterdir()}
    assert build_scene_cache(open_dataset(data), path, size=32, shard_scenes=4)[5].name == old[5].name
    assert {p.name: p.stat().st_mtime_ns for p in path.iterdir()} == stamps  # unchanged: nothing rewritten
    source = open_dataset(data)
    for cycle, n in source.scenes():
        _move_poses(scene_paths(data, cycle, n)["csv"], 0.05)
    cache = build_scene_cache(open_dataset(data), path, size=32, shard_scenes=4)
    np.testing.assert_allclose(cache[5].t_cam_obj, t_before + [0.0, 0.0, 0.05])
    # a depth image rewritten in place (same size): its scene is read again
    depth = scene_paths(data, *source.scenes()[5])["depth"]
    raw = np.full((128, 128), 30000, np.uint16)
    from opnet.datasets.png import write_png

    write_png(depth, raw)
    cache = build_scene_cache(open_dataset(data), path, size=32, shard_scenes=4)
    assert np.nanstd(cache[5].depth) < 1e-6
    assert not list(path.glob(".*.tmp")) and (path / "cache.json").is_file()


def test_shards_without_their_cache_json_are_not_reused(dataset: Path, tmp_path: Path):
    source = open_dataset(dataset)
    path = tmp_path / "c"
    build_scene_cache(source, path, size=32, shard_scenes=4)
    (path / "cache.json").unlink()  # e.g. killed while a stale cache was being replaced
    (path / "shard_00000.npz").write_bytes(b"stale")
    cache = build_scene_cache(source, path, size=32, shard_scenes=4)
    assert cache[0].name == source[0].name


def test_every_reader_lists_the_files_it_reads(dataset: Path, tmp_path: Path):
    """IPA, BOP and Siléane sources: their listed files exist, and touching one (the first, the
    last) changes the fingerprint."""
    import os

    from test_sileane_reader import make_folder

    from opnet.data.cache import scene_keys, source_fingerprint
    from opnet.datasets import SileaneDataset
    from opnet.datasets.bop import BOPDataset, convert_ipa_to_bop

    bop = BOPDataset(convert_ipa_to_bop(dataset, tmp_path / "bop", obj_id=2), 2)
    sileane = SileaneDataset(make_folder(tmp_path / "sileane"))
    for source in (open_dataset(dataset), bop, sileane):
        files = [Path(source.root, name) for name in source.source_files()]
        present = [f for f in files if f.is_file()]
        expected = len(files) if source is not sileane else 4  # Siléane: .PNG or .png
        assert len(present) == expected, [f for f in files if not f.is_file()][:3]
        for f in (present[0], present[-1]):
            before = source_fingerprint(source, scene_keys(source))
            st = f.stat()
            os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 1000))
            assert source_fingerprint(source, scene_keys(source)) != before, f


def test_a_killed_build_leaves_no_orphan_temporary_file(dataset: Path, tmp_path: Path):
    # SIGKILL while a shard was written left a 10 MB ".shard_*.tmp" behind for good
    import os
    import time

    source = open_dataset(dataset)
    path = tmp_path / "c"
    build_scene_cache(source, path, size=64, shard_scenes=4)
    orphan, fresh = path / ".shard_00001.depth.k1ll3d.tmp", path / ".shard_00002.depth.w0rk1ng.tmp"
    orphan.write_bytes(b"x" * 1000)
    fresh.write_bytes(b"y" * 1000)  # another process's write in progress
    old = time.time() - 3600
    os.utime(orphan, (old, old))
    build_scene_cache(source, path, size=64, shard_scenes=4)
    assert not orphan.exists() and fresh.exists()
