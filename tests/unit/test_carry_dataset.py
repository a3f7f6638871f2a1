"""scripts/dev/carry_dataset.py: a dataset packed and unpacked keeps every depth pixel and every other
file's bytes, and an archive cannot write outside the target folder."""

from __future__ import annotations

import importlib.util
import io
import tarfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from opnet.paths import REPO_ROOT

spec = importlib.util.spec_from_file_location("carry_dataset", REPO_ROOT / "scripts" / "dev" / "carry_dataset.py")
carry = importlib.util.module_from_spec(spec)
spec.loader.exec_module(carry)


def test_a_packed_dataset_unpacks_to_the_same_pixels_and_bytes(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    src = tmp_path / "ds"
    (src / "p_depth" / "cycle_0000").mkdir(parents=True)
    (src / "gt" / "cycle_0000").mkdir(parents=True)
    ramp = (np.arange(64 * 80).reshape(64, 80) * 17 % 65536).astype(np.uint16)  # differences that wrap
    depths = [ramp, rng.integers(0, 65536, (64, 80), dtype=np.uint16), np.full((64, 80), 65535, np.uint16)]
    for k, depth in enumerate(depths):
        cv2.imwrite(str(src / "p_depth" / "cycle_0000" / f"00{k}_depth_uint16.png"), depth)
    (src / "gt" / "cycle_0000" / "000.csv").write_text("id,x\n1,0.5\n")
    cv2.imwrite(str(src / "segmentation.png"), rng.integers(0, 5, (64, 80), dtype=np.uint8))
    archive = tmp_path / "ds.tar.xz"
    assert carry.pack(src, archive) == {"depth_images": 3, "files": 5}
    out = tmp_path / "out"
    assert carry.unpack(archive, out)["files"] == 5
    for k, depth in enumerate(depths):
        back = cv2.imread(str(out / "p_depth" / "cycle_0000" / f"00{k}_depth_uint16.png"), cv2.IMREAD_UNCHANGED)
        assert back.dtype == np.uint16 and np.array_equal(back, depth)
    for name in ("gt/cycle_0000/000.csv", "segmentation.png"):
        assert (out / name).read_bytes() == (src / name).read_bytes()


def test_an_archive_reaching_outside_the_folder_is_refused(tmp_path: Path) -> None:
    archive = tmp_path / "bad.tar.xz"
    with tarfile.open(archive, "w:xz") as tar:
        info = tarfile.TarInfo("../escape.txt")
        info.size = 2
        tar.addfile(info, io.BytesIO(b"hi"))
    with pytest.raises(ValueError, match="outside"):
        carry.unpack(archive, tmp_path / "out")
    assert not (tmp_path / "escape.txt").exists()


def test_a_cache_carried_alone_opens_as_it_is_where_the_images_are_stand_ins(builtin_dataset, tmp_path: Path) -> None:
    """pack-cache: the cache's depth pixels and the dataset's other files come back to the byte, the images as
    empty stand-ins of their size and modification time, so that the cache's fingerprint is the source's and
    the cache is opened, not rebuilt (a rebuild would read the stand-ins); another cache stays behind."""
    import shutil

    from opnet.data.cache import build_scene_cache, scene_keys, source_fingerprint
    from opnet.datasets import open_dataset

    src = tmp_path / "ds"
    shutil.copytree(builtin_dataset("pin", 2, 3, 1), src)  # copy2: modification times kept
    cache = build_scene_cache(open_dataset(src), src / "cache_s64", size=64, shard_scenes=4)
    (src / "cache_s32").mkdir()
    (src / "cache_s32" / "cache.json").write_text("{}")
    archive = tmp_path / "ds.tar.xz"
    counts = carry.pack_cache(src, "cache_s64", archive)
    pngs = sorted(p for p in src.rglob("*.png") if not str(p.relative_to(src)).startswith("cache_"))
    firsts = {}  # the first image of each top-level folder is carried as it is (the loader's checks read it)
    for png in pngs:
        firsts.setdefault(png.relative_to(src).parts[0], png)
    assert counts["stand_ins"] == len(pngs) - len(firsts) > 0
    assert len(firsts) >= 2  # depth and segmentation
    out = tmp_path / "out" / "ds"  # the dataset's own name (a reader may name the part by its folder)
    carry.unpack(archive, out)
    assert not (out / "cache_s32").exists()
    for png in firsts.values():
        assert (out / png.relative_to(src)).read_bytes() == png.read_bytes()
        assert open_dataset(out)[0].segmentation is not None  # what the loader checks before training
    for png in (p for p in pngs if p not in firsts.values()):
        stand_in = out / png.relative_to(src)
        assert stand_in.stat().st_size == png.stat().st_size and stand_in.stat().st_mtime_ns == png.stat().st_mtime_ns
        assert not stand_in.read_bytes().strip(b"\0")  # no image in it
    for f in (p for p in src.rglob("*") if p.is_file() and p.suffix != ".png" and p.parent.name != "cache_s32"):
        assert (out / f.relative_to(src)).read_bytes() == f.read_bytes(), f
    theirs, ours = open_dataset(out), open_dataset(src)
    assert source_fingerprint(theirs, scene_keys(theirs)) == source_fingerprint(ours, scene_keys(ours))
    shards = {p.name: p.stat().st_mtime_ns for p in (out / "cache_s64").glob("shard_*")}
    reopened = build_scene_cache(theirs, out / "cache_s64", size=64, shard_scenes=4)
    assert {p.name: p.stat().st_mtime_ns for p in (out / "cache_s64").glob("shard_*")} == shards  # nothing rewritten
    for i in range(len(cache)):
        np.testing.assert_array_equal(reopened[i].R_cam_obj, cache[i].R_cam_obj)
        np.testing.assert_array_equal(reopened[i].depth, cache[i].depth)


def test_pack_cache_names_a_folder_without_a_cache(tmp_path: Path) -> None:
    (tmp_path / "ds" / "cache_s64").mkdir(parents=True)
    assert carry.main(["pack-cache", str(tmp_path / "ds"), str(tmp_path / "a.tar.xz"), "--cache", "cache_s64"]) == 2
