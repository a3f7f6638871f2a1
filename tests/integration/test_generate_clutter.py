"""Foreign pieces on the bin floor (scene.clutter): real MuJoCo physics and real rendering. They
show in the depth as non-parts (segmentation 0 above the floor), the parts rest on or beside them
without sinking into them, a pile is deterministic for a seed, and no clutter is what it was."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from conftest import compose_cfg
from opnet.cli.generate import run
from opnet.datasets.ipa import IPADataset
from opnet.synthesis.clutter import clutter_mesh, sample_clutter


def _generate(tmp_path: Path, name: str, *extra: str) -> IPADataset:
    out = tmp_path / name
    run(compose_cfg("generate", ["object=pin", "scene.collision=convex_hull", "cycles=2", "drops=5", f"out={out}",
                                 "progress=false", "previews=0", *extra]))
    return IPADataset(out)


def _floor_depth(record) -> float:  # noqa: ANN001
    # the bin floor: the most common depth of the background pixels (segmentation 0)
    z = record.depth[(record.segmentation == 0) & np.isfinite(record.depth)]
    values, counts = np.unique(np.round(z, 3), return_counts=True)
    return float(values[np.argmax(counts)])


def test_clutter_lies_on_the_floor_under_the_parts_and_is_deterministic(tmp_path: Path) -> None:
    plain = _generate(tmp_path, "plain")
    clutter = _generate(tmp_path, "clutter", "scene.clutter=8")
    again = _generate(tmp_path, "again", "scene.clutter=8")
    assert json.loads((tmp_path / "clutter" / "generation.json").read_text())["scene"]["clutter"] == 8
    assert "clutter" not in json.loads((tmp_path / "plain" / "generation.json").read_text())["scene"]
    raised = []
    for k in range(len(plain)):
        a, b = plain[k], clutter[k]
        floor = _floor_depth(a)
        background = (b.segmentation == 0) & np.isfinite(b.depth)
        # background pixels well above the floor (nearer the camera): the foreign pieces
        raised.append(np.mean(b.depth[background] < floor - 0.004))
        assert np.array_equal(b.depth, again[k].depth, equal_nan=True)
        assert np.array_equal(b.t_cam_obj, again[k].t_cam_obj)
    plain_raised = [np.mean(r.depth[(r.segmentation == 0) & np.isfinite(r.depth)] < _floor_depth(r) - 0.004)
                    for r in (plain[k] for k in range(len(plain)))]
    # the walls are background above the floor too: the pieces add to them
    assert np.mean(raised) > np.mean(plain_raised) + 0.02
    # the parts rest on or beside the pieces: no part's centre below the floor, none inside a piece
    last = clutter[len(clutter) - 1]
    assert len(last.t_cam_obj) == 5 and (last.t_cam_obj[:, 2] < _floor_depth(last) + 1e-3).all()


def test_clutter_pieces_fit_the_floor_and_stay_below_the_part_radius() -> None:
    rng = np.random.default_rng(0)
    pieces = sample_clutter(200, (0.3, 0.5), 0.05, rng)
    assert {p.shape for p in pieces} == {"disc", "box"}
    mesh = clutter_mesh(pieces)
    lo, hi = mesh.bounds
    assert lo[2] > -1e-9 and hi[2] < 0.05  # on the floor, lower than the part's radius
    assert (np.abs(lo[:2]) <= np.array([0.15, 0.25]) + 1e-9).all() and (hi[:2] <= np.array([0.15, 0.25]) + 1e-9).all()
    assert clutter_mesh(()) is None


@pytest.mark.parametrize(("values", "match"), [
    (["scene.clutter=-1"], "clutter"),
    (["scene.clutter=3", "scene.physics=pybullet"], "clutter.*pybullet"),
])  # fmt: skip
def test_bad_clutter_settings_name_the_key(tmp_path: Path, values: list[str], match: str) -> None:
    with pytest.raises(ValueError, match=match):
        run(compose_cfg("generate", ["object=pin", f"out={tmp_path / 'bad'}", "progress=false", *values]))
    assert not (tmp_path / "bad").exists()
