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
