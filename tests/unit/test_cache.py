"""The scene cache: same samples as the dataset files, resumable, rebuilt when stale, bounded."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from opnet.data.cache import SceneCache, build_scene_cache, decode_depth, default_cache_dir, encode_depth
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
