"""DataModule pieces: cycle-grouped splits, samples, batches."""

from __future__ import annotations

import numpy as np
import pytest

from opnet.data.scene_data import split_groups
from opnet.data.sample import collate, make_sample
from opnet.datasets.record import SceneRecord
from opnet.geometry import Camera


def test_split_keeps_cycles_together_and_is_deterministic() -> None:
    keys = [c for c in range(20) for _ in range(5)]  # 20 cycles of 5 scenes
    tr, va, te = split_groups(keys, 0.1, 0.2, seed=3)
    assert sorted(tr + va + te) == list(range(100))
    cyc = lambda idx: {keys[i] for i in idx}  # noqa: E731
    assert not (cyc(tr) & cyc(va) or cyc(tr) & cyc(te) or cyc(va) & cyc(te))
    assert len(cyc(va)) == 2 and len(cyc(te)) == 4
    assert (tr, va, te) == split_groups(keys, 0.1, 0.2, seed=3)
    assert (tr, va, te) != split_groups(keys, 0.1, 0.2, seed=4)


def test_split_with_few_groups_keeps_everything_for_training() -> None:
    tr, va, te = split_groups([0, 0, 1], 0.1, 0.1, seed=0)
    assert tr == [0, 1, 2] and va == [] and te == []


def _record(n: int = 3) -> SceneRecord:
    cam = Camera(300.0, 300.0, 159.5, 119.5, 320, 240, 0.5, 1.5)
    depth = np.full((240, 320), 1.2, np.float32)
    depth[::9, ::7] = np.nan
    rng = np.random.default_rng(0)
    R = np.stack([np.eye(3)] * n)
    t = np.c_[rng.uniform(-0.1, 0.1, (n, 2)), np.full(n, 1.1)]
    seg = np.zeros((240, 320), np.int32)
    seg[100:140, 150:200] = 2
    return SceneRecord("s", depth, cam, seg, R, t, np.array([0.9, 1.3, 0.0])[:n], np.arange(1, n + 1))


def test_sample_is_normalized_and_keeps_ground_truth() -> None:
    rec = _record()
    s = make_sample(rec, size=128)
    assert s.image.shape == (1, 128, 128) and s.image.dtype == np.float32
    assert np.isfinite(s.image).all() and 0 <= s.image.min() and s.image.max() <= 1
    assert (s.camera.width, s.camera.height) == (128, 128)
    np.testing.assert_allclose(s.t_cam_obj, rec.t_cam_obj, atol=1e-6)
    assert s.visibility.max() <= 1.0  # IPA visibilities above 1 are clipped
    assert s.segmentation is not None and set(np.unique(s.segmentation)) == {0, 2}
    # the segmented patch lands where the network camera projects its centre
    centre = rec.camera.backproject(174.5, 119.5, 1.2)
    u, v = s.camera.project(centre)
    assert s.segmentation[int(round(v)), int(round(u))] == 2


def test_collate_builds_flat_ground_truth() -> None:
    batch = collate([make_sample(_record(3)), make_sample(_record(2))])
    assert batch.images.shape == (2, 1, 128, 128)
    assert batch.gt.batch_index.tolist() == [0, 0, 0, 1, 1]
    assert [len(g) for g in batch.gt_sets] == [3, 2]
    np.testing.assert_allclose(batch.gt_sets[0].occlusion_rate, [0.1, 0.0, 1.0], atol=1e-6)
    assert batch.names == ["s", "s"]


@pytest.mark.parametrize("bad", ["int", "3d"])
def test_sample_rejects_bad_depth(bad: str) -> None:
    rec = _record()
    rec.depth = rec.depth.astype(np.int32) if bad == "int" else np.stack([rec.depth] * 2, -1)
    with pytest.raises(ValueError):
        make_sample(rec)


def test_a_checkpoint_that_would_run_code_is_refused(tmp_path) -> None:
    """Model files are exchanged between users: loading one must never execute code."""
    import os as _os

    import torch

    from opnet.cli.build import load_checkpoint

    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self):
            return (_os.system, (f"touch {marker}",))

    torch.save({"hyper_parameters": {"config": {"object": {}}}, "payload": Evil()}, tmp_path / "evil.ckpt")
    with pytest.raises(ValueError, match="refused"):
        load_checkpoint(tmp_path / "evil.ckpt")
    assert not marker.exists()
