"""Physics drops: resting contact, staying in the bin, determinism, collision shapes and their cache."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from opnet.objects import builtin_object
from opnet.synthesis.collision import build_collision_model, choose_mode, vhacd_cached
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.cycle import cycle_rngs
from opnet.synthesis.layout import inverse_pose, make_rig, sample_layout
from opnet.synthesis.physics import BinSimulator


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("vhacd_cache")


def _simulate(name: str, drops: int, cycle: int, cfg: SceneConfig, sim: BinSimulator | None = None):
    obj = builtin_object(name)
    rig = make_rig(obj, drops, 1, cfg)
    own = sim is None
    sim = sim or BinSimulator(rig, build_collision_model(obj.mesh, cfg), cfg)
    layout_rng, drop_rng = cycle_rngs(0, cycle)
    layout = sample_layout(rig, cfg, layout_rng)
    states = sim.simulate(layout, drops, drop_rng)
    if own:
        sim.close()
    return obj, rig, layout, states


def _vertices_in_bin(obj, layout, T_world_obj: np.ndarray) -> np.ndarray:
    T = inverse_pose(layout.T_world_bin) @ T_world_obj
    return obj.mesh.vertices @ T[:3, :3].T + T[:3, 3]


@pytest.mark.parametrize(("name", "mode"), [("pin", "convex_hull"), ("bracket", "vhacd")])
def test_a_dropped_part_rests_on_the_bin_floor(name: str, mode: str, cache_dir: Path) -> None:
    # the recorded pose is the model frame (not pybullet's inertial frame): its lowest vertex
    # touches the floor top, up to the collision margin / the decomposition's voxel inflation
    cfg = SceneConfig(collision=mode, cache_dir=str(cache_dir))
    obj, rig, layout, states = _simulate(name, 1, 0, cfg)
    assert states.stats.unsettled == 0
    v = _vertices_in_bin(obj, layout, states.T_world_obj[1][0])
    assert -0.0015 < v[:, 2].min() < 0.0025
    assert np.abs(v[:, :2]).max() < rig.bin.inner / 2 + 1e-3


def test_every_recorded_pile_is_in_the_bin_with_one_more_part_each_drop() -> None:
    cfg = SceneConfig(collision="convex_hull")
    obj, rig, layout, states = _simulate("shaft", 6, 3, cfg)
    assert [len(p) for p in states.T_world_obj] == list(range(7))
    for pile in states.T_world_obj[1:]:
        com = np.array([_vertices_in_bin(obj, layout, T).mean(0) for T in pile])
        assert rig.bin.inside(com).all()
        np.testing.assert_allclose(pile[:, :3, :3] @ pile[:, :3, :3].transpose(0, 2, 1), np.broadcast_to(np.eye(3), (len(pile), 3, 3)), atol=1e-6)


def test_a_cycle_does_not_depend_on_what_the_client_simulated_before() -> None:
    cfg = SceneConfig(collision="convex_hull")
    obj = builtin_object("zbracket")
    rig = make_rig(obj, 4, 1, cfg)
    with BinSimulator(rig, build_collision_model(obj.mesh, cfg), cfg) as sim:
        _simulate("zbracket", 4, 0, cfg, sim)
        after_other = _simulate("zbracket", 4, 1, cfg, sim)[3]
    fresh = _simulate("zbracket", 4, 1, cfg)[3]
    for a, b in zip(after_other.T_world_obj, fresh.T_world_obj):
        np.testing.assert_array_equal(a, b)
    other_seed = _simulate("zbracket", 4, 2, cfg)[3]
    assert not np.allclose(other_seed.T_world_obj[-1], fresh.T_world_obj[-1])


def test_parts_that_cannot_stay_in_the_bin_end_in_a_clear_error() -> None:
    # a 4 mm pedestal instead of a bin, hit from 30 cm: every drop falls off
    cfg = SceneConfig(collision="convex_hull", bin_inner=0.002, bin_wall_height=0.001, bin_wall_thickness=0.001, camera_height=0.5,
                      drop_gap=0.3, max_redrops=2, max_cycle_restarts=1, settle_time_cap=1.0)
    with pytest.raises(RuntimeError, match="bin_inner"):
        _simulate("pin", 1, 0, cfg)


def test_auto_collision_mode_decomposes_concave_parts_only() -> None:
    cfg = SceneConfig(collision="auto")
    assert choose_mode(builtin_object("bracket").mesh, cfg) == "vhacd"
    assert choose_mode(builtin_object("zbracket").mesh, cfg) == "vhacd"
    assert choose_mode(builtin_object("pin").mesh, cfg) == "convex_hull"
    assert choose_mode(builtin_object("pin").mesh, SceneConfig(collision="vhacd")) == "vhacd"


def test_vhacd_decomposition_is_cached_and_deterministic(tmp_path: Path, cache_dir: Path) -> None:
    mesh = builtin_object("bracket").mesh
    first = vhacd_cached(mesh, 1_000_000, cache_dir)
    stamp = first.stat().st_mtime_ns
    assert vhacd_cached(mesh, 1_000_000, cache_dir) == first and first.stat().st_mtime_ns == stamp  # a hit
    elsewhere = vhacd_cached(mesh, 1_000_000, tmp_path)
    assert elsewhere.name == first.name and elsewhere.read_bytes() == first.read_bytes()
    assert first.read_text().count("\no ") + first.read_text().startswith("o ") >= 2  # L-shape: 2+ convex parts
    assert vhacd_cached(mesh, 500_000, tmp_path).name != first.name  # settings are part of the key
