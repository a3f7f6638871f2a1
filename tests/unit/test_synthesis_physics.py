"""Physics drops: resting contact, staying in the bin, determinism, collision shapes and their cache,
for both engines (MuJoCo, the default, and pybullet where it is installed)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from opnet._deps import MissingDependencyError
from opnet.objects import builtin_object
from opnet.synthesis.collision import (
    build_collision_model,
    choose_mode,
    coacd_cached,
    convex_parts,
    merge_convex_parts,
    merged_cached,
    vhacd_cached,
)
from opnet.synthesis.config import SceneConfig
from opnet.synthesis.cycle import cycle_rngs
from opnet.synthesis.layout import inverse_pose, make_rig, sample_layout
from opnet.synthesis.physics import BinSimulator, make_simulator

HAS_PYBULLET = importlib.util.find_spec("pybullet") is not None
ENGINES = ["mujoco", pytest.param("pybullet", marks=pytest.mark.skipif(not HAS_PYBULLET, reason="pybullet not installed (CPython 3.11 only)"))]


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("vhacd_cache")


def _simulate(name: str, drops: int, cycle: int, cfg: SceneConfig, sim: BinSimulator | None = None):
    obj = builtin_object(name)
    rig = make_rig(obj, drops, 1, cfg)
    own = sim is None
    sim = sim or make_simulator(rig, build_collision_model(obj.mesh, cfg), cfg)
    layout_rng, drop_rng = cycle_rngs(0, cycle)
    layout = sample_layout(rig, cfg, layout_rng)
    states = sim.simulate(layout, drops, drop_rng)
    if own:
        sim.close()
    return obj, rig, layout, states


def _vertices_in_bin(obj, layout, T_world_obj: np.ndarray) -> np.ndarray:
    T = inverse_pose(layout.T_world_bin) @ T_world_obj
    return obj.mesh.vertices @ T[:3, :3].T + T[:3, 3]


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize(("name", "mode"), [("pin", "convex_hull"), ("bracket", "vhacd")])
def test_a_dropped_part_rests_on_the_bin_floor(name: str, mode: str, engine: str, cache_dir: Path) -> None:
    # the recorded pose is the model frame (not the engine's inertial frame): its lowest vertex
    # touches the floor top, up to the collision margin / the decomposition's voxel inflation
    cfg = SceneConfig(collision=mode, cache_dir=str(cache_dir), physics=engine)
    obj, rig, layout, states = _simulate(name, 1, 0, cfg)
    assert states.stats.unsettled == 0
    v = _vertices_in_bin(obj, layout, states.T_world_obj[1][0])
    assert -0.0015 < v[:, 2].min() < 0.0025
    assert np.abs(v[:, :2]).max() < rig.bin.inner / 2 + 1e-3


@pytest.mark.parametrize("engine", ENGINES)
def test_every_recorded_pile_is_in_the_bin_with_one_more_part_each_drop(engine: str) -> None:
    cfg = SceneConfig(collision="convex_hull", physics=engine)
    obj, rig, layout, states = _simulate("shaft", 6, 3, cfg)
    assert [len(p) for p in states.T_world_obj] == list(range(7))
    for pile in states.T_world_obj[1:]:
        com = np.array([_vertices_in_bin(obj, layout, T).mean(0) for T in pile])
        assert rig.bin.inside(com).all()
        np.testing.assert_allclose(pile[:, :3, :3] @ pile[:, :3, :3].transpose(0, 2, 1), np.broadcast_to(np.eye(3), (len(pile), 3, 3)), atol=1e-6)


@pytest.mark.parametrize("engine", ENGINES)
def test_a_cycle_does_not_depend_on_what_the_client_simulated_before(engine: str) -> None:
    cfg = SceneConfig(collision="convex_hull", physics=engine)
    obj = builtin_object("zbracket")
    rig = make_rig(obj, 4, 1, cfg)
    with make_simulator(rig, build_collision_model(obj.mesh, cfg), cfg) as sim:
        _simulate("zbracket", 4, 0, cfg, sim)
        after_other = _simulate("zbracket", 4, 1, cfg, sim)[3]
    fresh = _simulate("zbracket", 4, 1, cfg)[3]
    for a, b in zip(after_other.T_world_obj, fresh.T_world_obj):
        np.testing.assert_array_equal(a, b)
    other_seed = _simulate("zbracket", 4, 2, cfg)[3]
    assert not np.allclose(other_seed.T_world_obj[-1], fresh.T_world_obj[-1])


@pytest.mark.parametrize("engine", ENGINES)
def test_parts_that_cannot_stay_in_the_bin_end_in_a_clear_error(engine: str) -> None:
    # a 4 mm pedestal instead of a bin, hit from 30 cm: every drop falls off (redrops restore the world)
    cfg = SceneConfig(physics=engine, collision="convex_hull", bin_inner=0.002, bin_wall_height=0.001, bin_wall_thickness=0.001, camera_height=0.5,
                      drop_gap=0.3, max_redrops=2, max_cycle_restarts=1, settle_time_cap=1.0)
    with pytest.raises(RuntimeError, match="bin_inner"):
        _simulate("pin", 1, 0, cfg)


def test_auto_collision_mode_decomposes_concave_parts_only() -> None:
    cfg = SceneConfig(collision="auto")
    assert choose_mode(builtin_object("bracket").mesh, cfg) == "vhacd"
    assert choose_mode(builtin_object("zbracket").mesh, cfg) == "vhacd"
    assert choose_mode(builtin_object("pin").mesh, cfg) == "convex_hull"
    assert choose_mode(builtin_object("pin").mesh, SceneConfig(collision="vhacd")) == "vhacd"


@pytest.mark.parametrize(("engine", "setting", "other"), [("mujoco", 0.1, 0.05), ("pybullet", 1_000_000, 500_000)])
def test_the_decomposition_is_cached_deterministic_and_covers_the_part(engine: str, setting: float, other: float,
                                                                      tmp_path: Path, cache_dir: Path) -> None:
    if engine == "pybullet" and not HAS_PYBULLET:
        pytest.skip("pybullet not installed (its V-HACD makes the decomposition)")
    decompose = coacd_cached if engine == "mujoco" else vhacd_cached
    mesh = builtin_object("bracket").mesh
    first = decompose(mesh, setting, cache_dir)
    stamp = first.stat().st_mtime_ns
    assert decompose(mesh, setting, cache_dir) == first and first.stat().st_mtime_ns == stamp  # a hit
    elsewhere = decompose(mesh, setting, tmp_path)
    assert elsewhere.name == first.name and elsewhere.read_bytes() == first.read_bytes()
    parts = convex_parts(first)
    assert len(parts) >= 2  # an L-shape: two or more convex parts
    hull = np.concatenate(parts)  # the parts span the part's extent, within the decomposition's inflation
    np.testing.assert_allclose(hull.min(0), mesh.bounds[0], atol=2e-3)
    np.testing.assert_allclose(hull.max(0), mesh.bounds[1], atol=2e-3)
    assert decompose(mesh, other, tmp_path).name != first.name  # settings are part of the key


def test_the_engine_follows_the_config_and_an_unknown_engine_is_named() -> None:
    with pytest.raises(ValueError, match=r"physics='bullet'.*mujoco"):
        SceneConfig(physics="bullet")
    cfg = SceneConfig(collision="convex_hull")
    assert cfg.physics == "mujoco"
    obj = builtin_object("pin")
    with make_simulator(make_rig(obj, 2, 1, cfg), build_collision_model(obj.mesh, cfg), cfg) as sim:
        assert type(sim).__name__ == "MujocoSimulator" and isinstance(sim, BinSimulator)


def test_a_missing_engine_is_a_one_line_error(monkeypatch: pytest.MonkeyPatch) -> None:
    import opnet._deps as deps

    real = importlib.util.find_spec
    monkeypatch.setattr(deps.importlib.util, "find_spec", lambda name, *a: None if name == "pybullet" else real(name, *a))
    cfg = SceneConfig(collision="convex_hull", physics="pybullet")
    obj = builtin_object("pin")
    with pytest.raises(MissingDependencyError, match=r"scene.physics=pybullet needs the package 'pybullet'.*mujoco"):
        make_simulator(make_rig(obj, 2, 1, cfg), build_collision_model(obj.mesh, cfg), cfg)


def _box(lo: tuple, hi: tuple) -> np.ndarray:
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], dtype=float)


def test_merging_convex_pieces_joins_the_pair_that_adds_the_least_volume_first() -> None:
    # two unit cubes face to face make a box (nothing added); the third, far away, stays alone
    a, b, far = _box((0, 0, 0), (1, 1, 1)), _box((1, 0, 0), (2, 1, 1)), _box((5, 5, 5), (6, 6, 6))
    merged = merge_convex_parts([far, a, b], 2)
    assert len(merged) == 2
    np.testing.assert_allclose(np.sort(merged[0][0], axis=0), np.sort(far, axis=0))
    np.testing.assert_allclose(merged[1][0].min(0), [0, 0, 0])
    np.testing.assert_allclose(merged[1][0].max(0), [2, 1, 1])
    assert len(merged[1][0]) == 8  # the hull's corners only
    # one piece: the hull of all; a far cube then adds what lies between (the bound: the cubes' box)
    (whole,) = merge_convex_parts([far, a, b], 1)
    np.testing.assert_allclose(whole[0].min(0), [0, 0, 0])
    np.testing.assert_allclose(whole[0].max(0), [6, 6, 6])
    again = merge_convex_parts([far, a, b], 2)
    assert all(np.array_equal(x[0], y[0]) and np.array_equal(x[1], y[1]) for x, y in zip(merged, again, strict=True))
    assert len(merge_convex_parts([far, a, b], 5)) == 3  # under the cap: every piece, in order
    # a volume budget stops the merging before the far cube joins (it would add 6^3 - 3 volumes)
    assert len(merge_convex_parts([far, a, b], 1, budget=0.01)) == 2
    assert len(merge_convex_parts([far, a, b], 1, budget=1.0)) == 2  # it adds 71 times the pieces' volume
    assert len(merge_convex_parts([far, a, b], 1, budget=0.0)) == 2  # the face-to-face pair adds nothing
    with pytest.raises(ValueError, match="max_pieces=0"):
        merge_convex_parts([a], 0)


def test_a_decomposition_over_the_cap_is_merged_into_a_cached_file_beside_it(tmp_path: Path) -> None:
    from opnet.synthesis.collision import _parts_obj

    cubes = [_box((2 * k, 0, 0), (2 * k + 1, 1, 1)) for k in range(5)]
    src = tmp_path / "coacd_abc.obj"
    src.write_text(_parts_obj(cubes, [np.array([[0, 1, 2]]) for _ in cubes]))
    assert merged_cached(src, 5) == src  # at the cap: the decomposition itself
    out = merged_cached(src, 3)
    assert out.name == "coacd_abc_max3.obj" and len(convex_parts(out)) == 3
    stamp = out.stat().st_mtime_ns
    assert merged_cached(src, 3) == out and out.stat().st_mtime_ns == stamp  # made once
    # cubes 1 apart: each merge fills the gap between two (a cube's volume, 20 % of the five's)
    kept = merged_cached(src, 3, budget=0.3)
    assert kept.name == "coacd_abc_max3_b0.3.obj" and len(convex_parts(kept)) == 4
    assert not list(tmp_path.glob(".merge_*"))  # no temporary file left


def test_the_dense_recipe_caps_pieces_and_leaves_a_built_in_part_as_it_was(cache_dir: Path) -> None:
    from opnet.studies.scenes import dense_scene

    scene = dense_scene(views=1)
    assert (scene.max_convex_pieces, scene.convex_merge_budget) == (20, 0.01)
    mesh = builtin_object("bracket").mesh
    capped = build_collision_model(mesh, SceneConfig(cache_dir=str(cache_dir), max_convex_pieces=20, convex_merge_budget=0.01))
    assert capped.obj_file == build_collision_model(mesh, SceneConfig(cache_dir=str(cache_dir))).obj_file
    # a cap under its pieces merges them (a budget of 1: whatever it adds)
    merged = build_collision_model(mesh, SceneConfig(cache_dir=str(cache_dir), max_convex_pieces=1, convex_merge_budget=1.0))
    assert merged.obj_file.name.endswith("_max1_b1.obj") and len(convex_parts(merged.obj_file)) == 1


def test_the_piece_cap_is_an_integer_of_zero_or_more() -> None:
    assert SceneConfig().max_convex_pieces == 0 and "max_convex_pieces" not in SceneConfig().to_dict()
    assert "convex_merge_budget" not in SceneConfig().to_dict()  # datasets made before keep their files
    assert SceneConfig(max_convex_pieces=20).to_dict()["max_convex_pieces"] == 20
    for bad in (-1, 2.5, True):
        with pytest.raises(ValueError, match="max_convex_pieces"):
            SceneConfig(max_convex_pieces=bad)
    for bad in (-0.1, 1.5, float("nan")):
        with pytest.raises(ValueError, match="convex_merge_budget"):
            SceneConfig(convex_merge_budget=bad)


def test_a_malformed_decomposition_file_names_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "parts.obj"
    bad.write_text("o part_0\nv 0 0 zero\n")
    with pytest.raises(ValueError, match=r"parts.obj:2: malformed vertex"):
        convex_parts(bad)
    bad.write_text("# nothing\n")
    with pytest.raises(ValueError, match=r"parts.obj: the convex decomposition holds no vertices"):
        convex_parts(bad)


def test_mujoco_piles_rest_without_parts_sinking_into_each_other() -> None:
    # 12 brackets (a CoACD decomposition) in a pile: at rest, no contact is deeper than 0.5 mm
    import mujoco

    cfg = SceneConfig(collision="vhacd")
    obj = builtin_object("bracket")
    rig = make_rig(obj, 12, 1, cfg)
    with make_simulator(rig, build_collision_model(obj.mesh, cfg), cfg) as sim:
        layout_rng, drop_rng = cycle_rngs(0, 0)
        states = sim.simulate(sample_layout(rig, cfg, layout_rng), 12, drop_rng)
        mujoco.mj_forward(sim.model, sim.data)
        depth = -min(c.dist for c in sim.data.contact[: sim.data.ncon])
    assert len(states.T_world_obj[-1]) == 12 and states.stats.unsettled <= 1
    assert depth < 5e-4
