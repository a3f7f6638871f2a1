"""Fresh spins per view (``scene.view_spin``): every view after the first turns each part about its own axis."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
import trimesh

from opnet.objects import ObjectModel, builtin_object
from opnet.synthesis import SceneConfig
from opnet.synthesis.cycle import CycleGenerator
from opnet.synthesis.layout import inverse_pose
from opnet.synthesis.spin import hull_flip, hull_spin_gap, resolve_view_spin

SCENE = SceneConfig(resolution=96, collision="convex_hull", views=3)
DROPS = 4


def wheel() -> ObjectModel:
    """A rim (a body of revolution) with one spoke across its inside: the hull is the rim's, the spin shows."""
    rim = trimesh.creation.annulus(r_min=0.020, r_max=0.025, height=0.015, sections=48)
    spoke = trimesh.creation.box(extents=(0.042, 0.006, 0.006))
    return ObjectModel.from_mesh("wheel", trimesh.util.concatenate([rim, spoke]), {"kind": "cyclic", "order": 2})


def bin_frame(result, record) -> np.ndarray:
    """(n, 4, 4) model-to-bin poses of a record of a generated cycle."""
    T_cam_bin = np.eye(4)
    T_cam_bin[:3, :3], T_cam_bin[:3, 3] = result.R_cam_bin, result.t_cam_bin
    T = np.tile(np.eye(4), (len(record.t_cam_obj), 1, 1))
    T[:, :3, :3], T[:, :3, 3] = record.R_cam_obj, record.t_cam_obj
    return inverse_pose(T_cam_bin) @ T


def spin_of(T: np.ndarray, T_spun: np.ndarray) -> np.ndarray:
    """(n,) degrees each part of ``T_spun`` is turned about its own z-axis from ``T`` (fails if any other turn)."""
    Q = np.swapaxes(T[:, :3, :3], -1, -2) @ T_spun[:, :3, :3]
    np.testing.assert_allclose(Q[:, 2], np.tile([0.0, 0.0, 1.0], (len(Q), 1)), atol=1e-9)
    return np.degrees(np.arctan2(Q[:, 1, 0], Q[:, 0, 0]))


def views(scene: SceneConfig, obj: ObjectModel) -> list:
    with CycleGenerator(obj, DROPS, scene, cycles=3) as generator:
        return list(generator.generate_views(seed=5, pile=0))


def test_the_hull_gap_of_a_square_prism_is_its_corner_turned_onto_a_face_normal() -> None:
    # half side a: turned by 45 degrees (one of the 72 turns tried) the corner lies a (sqrt 2 - 1) beyond the faces
    a = 0.01
    assert hull_spin_gap(trimesh.creation.box(extents=(2 * a, 2 * a, 0.03))) == pytest.approx(a * (math.sqrt(2) - 1))
    # a 48-gon's sag r (1 - cos(pi / 48)): a body of revolution up to its tessellation
    assert hull_spin_gap(wheel().mesh) < 0.025 * (1 - math.cos(math.pi / 48)) + 1e-9


def test_the_views_after_the_first_turn_each_part_about_its_own_axis_and_only_about_it() -> None:
    spun = views(SceneConfig.from_dict({**SCENE.to_dict(), "view_spin": True}), wheel())
    plain = views(SCENE, wheel())
    last = DROPS
    base = bin_frame(plain[0], plain[0].records[last])
    # view 0 is the physics' own pile, with or without the setting
    np.testing.assert_allclose(bin_frame(spun[0], spun[0].records[last]), base, atol=1e-9)
    np.testing.assert_array_equal(spun[0].records[last].depth, plain[0].records[last].depth)
    for k in (1, 2):
        T = bin_frame(spun[k], spun[k].records[last])
        np.testing.assert_allclose(T[:, :3, 3], base[:, :3, 3], atol=1e-9)  # the same places ...
        np.testing.assert_allclose(T[:, :3, 2], base[:, :3, 2], atol=1e-9)  # ... and axes
        assert (np.abs(spin_of(base, T)) > 1.0).sum() >= DROPS - 1  # each part a fresh spin (within 1 degree: rare)
        # without the setting the views keep the pile's spins
        np.testing.assert_allclose(bin_frame(plain[k], plain[k].records[last]), base, atol=1e-9)
    # a part keeps its spin through the cycle's drops: after drop 2 as after the last
    early = spin_of(bin_frame(plain[0], plain[0].records[2]), bin_frame(spun[1], spun[1].records[2]))
    np.testing.assert_allclose(early, spin_of(base, bin_frame(spun[1], spun[1].records[last]))[:2], atol=1e-6)
    assert len({spun[1].records[last].depth.tobytes(), spun[2].records[last].depth.tobytes()}) == 2


def test_a_part_whose_hull_is_no_body_of_revolution_is_refused_naming_it() -> None:
    scene = SceneConfig.from_dict({**SCENE.to_dict(), "view_spin": True})
    with pytest.raises(ValueError, match=r"scene.view_spin: bracket's convex hull is not a body of revolution.*% of D"):
        CycleGenerator(builtin_object("bracket"), DROPS, scene)


@pytest.mark.parametrize(("key", "value"), [("view_spin", "yes"), ("view_spin_tolerance", 0.0),
                                            ("view_spin_tolerance", 1.5)])
def test_bad_spin_settings_are_refused(key: str, value: object) -> None:
    with pytest.raises(ValueError, match=rf"scene config: {key}="):
        SceneConfig.from_dict({**SCENE.to_dict(), key: value})
    # with one view per pile there is no view to turn the parts in
    with pytest.raises(ValueError, match=r"scene config: view_spin=True, expected false with scene.views=1"):
        SceneConfig.from_dict({**SCENE.to_dict(), "views": 1, "view_spin": True})


def test_the_dense_recipe_takes_it_as_a_scene_setting_and_old_datasets_keep_their_record() -> None:
    from opnet.studies.scenes import dense_scene

    assert dense_scene(views=8, settings=["view_spin=true"]).view_spin is True
    assert dense_scene(views=8, settings=["view_spin=false"]).view_spin is False
    assert dense_scene(views=8).view_spin == "auto"  # the recipe decides by the part
    # left out of generation.json at its default: the datasets made before still match their settings
    assert "view_spin" not in SceneConfig().to_dict() and "view_spin_tolerance" not in SceneConfig().to_dict()
    assert SceneConfig(views=2, view_spin=True).to_dict()["view_spin"] is True


def test_auto_turns_the_views_of_exactly_the_parts_it_fits() -> None:
    """On for a part whose hull spins freely and whose spins are not free; off for a part whose spins are free (a
    revolution symmetry: every spin is the same pose), one whose hull is no body of revolution, and one view a pile."""
    auto = dataclasses.replace(SCENE, view_spin="auto")
    assert resolve_view_spin(auto, wheel()).view_spin is True
    rim = ObjectModel.from_mesh("rim", trimesh.creation.annulus(r_min=0.020, r_max=0.025, height=0.015, sections=48),
                                {"kind": "revolution"})
    assert resolve_view_spin(auto, rim).view_spin is False
    assert resolve_view_spin(auto, builtin_object("bracket")).view_spin is False
    assert resolve_view_spin(dataclasses.replace(auto, views=1), wheel()).view_spin is False
    # a setting given is kept: true still refused for the bracket by the generator, false never turns the wheel
    for given in (True, False):
        assert resolve_view_spin(dataclasses.replace(SCENE, view_spin=given), wheel()).view_spin is given


def test_a_dataset_records_what_auto_decided_and_one_made_otherwise_is_refused_naming_the_setting(
        tmp_path: Path) -> None:
    from opnet.synthesis import generate_dataset

    def made(out: Path, view_spin: object) -> dict:
        scene = dataclasses.replace(SCENE, views=2, view_spin=view_spin)
        generate_dataset(wheel(), out, cycles=2, drops=2, scene=scene, progress=False, previews=0)
        return json.loads((out / "generation.json").read_text())

    auto, on = made(tmp_path / "auto", "auto"), made(tmp_path / "on", True)
    assert auto["scene"]["view_spin"] is True and auto["scene"] == on["scene"]  # as if the setting were written
    depth = "p_depth/cycle_0001/002_depth_uint16.png"  # the second view of the pile: its parts turned
    assert (tmp_path / "auto" / depth).read_bytes() == (tmp_path / "on" / depth).read_bytes()
    with pytest.raises(ValueError, match=r"generation.json: .*scene.view_spin.*made with scene.view_spin=true"):
        made(tmp_path / "auto", False)


def hubbed_wheel() -> ObjectModel:
    """A rim with a hub off the middle of its width, inside the rim's envelope: the hull is symmetric about the
    rim's mid-plane, the part is not; its model origin (at the hub's side, as a part's surface centroid lies)
    lies off that plane."""
    rim = trimesh.creation.annulus(r_min=0.020, r_max=0.025, height=0.015, sections=48)
    hub = trimesh.creation.cylinder(radius=0.006, height=0.006, sections=24)
    hub.apply_translation((0.0, 0.0, 0.004))
    spoke = trimesh.creation.box(extents=(0.042, 0.004, 0.004))
    spoke.apply_translation((0.0, 0.0, 0.004))
    mesh = trimesh.util.concatenate([rim, hub, spoke])
    mesh.apply_translation((0.0, 0.0, -0.003))
    return ObjectModel.from_mesh("hubbed", mesh, {"kind": "cyclic", "order": 2})


def test_the_views_after_the_first_turn_half_the_parts_end_over_end_about_their_hull_middle() -> None:
    obj = hubbed_wheel()
    centre, gap = hull_flip(obj.mesh)
    assert gap < 1e-6 and centre == pytest.approx(-0.003)  # the hull's middle, not the model origin
    flip_scene = SceneConfig.from_dict({**SCENE.to_dict(), "view_flip": True})
    both = SceneConfig.from_dict({**SCENE.to_dict(), "view_flip": True, "view_spin": True})
    flipped, plain = views(flip_scene, obj), views(SCENE, obj)
    spun_only = views(SceneConfig.from_dict({**SCENE.to_dict(), "view_spin": True}), obj)
    spun_flipped = views(both, obj)
    last = DROPS
    base = bin_frame(plain[0], plain[0].records[last])
    middle = base @ np.array([0.0, 0.0, centre, 1.0])  # (n, 4) the hull's middle in the bin
    np.testing.assert_allclose(bin_frame(flipped[0], flipped[0].records[last]), base, atol=1e-9)  # view 0 as made
    turned = 0
    for k in (1, 2):
        T = bin_frame(flipped[k], flipped[k].records[last])
        np.testing.assert_allclose(T @ np.array([0.0, 0.0, centre, 1.0]), middle, atol=1e-9)  # hull where it was
        dot = np.einsum("ni,ni->n", T[:, :3, 2], base[:, :3, 2])
        np.testing.assert_allclose(np.abs(dot), 1.0, atol=1e-9)  # each axis kept or reversed, nothing between
        turned += int((dot < 0).sum())
        # with spins too: the parts not flipped are spun exactly as by the spins alone (streams apart)
        S, SF = (bin_frame(v[k], v[k].records[last]) for v in (spun_only, spun_flipped))
        same = np.einsum("ni,ni->n", SF[:, :3, 2], S[:, :3, 2]) > 0
        np.testing.assert_allclose(SF[same], S[same], atol=1e-9)
        np.testing.assert_array_equal(same, dot > 0)  # the same parts flipped, whatever the spins
    assert 0 < turned < 2 * DROPS  # about half the parts of each view


def test_a_part_whose_hull_is_not_symmetric_about_its_middle_is_refused_naming_it() -> None:
    cone = ObjectModel.from_mesh("cone", trimesh.creation.cone(radius=0.02, height=0.03, sections=48),
                                 {"kind": "cyclic", "order": 2})
    assert hull_flip(cone.mesh)[1] > 0.01  # its tip turned end over end lies far beyond its base
    scene = SceneConfig.from_dict({**SCENE.to_dict(), "view_flip": True})
    with pytest.raises(ValueError, match=r"scene.view_flip: cone's convex hull is not symmetric about its mid-plane"
                                         r".*% of D"):
        CycleGenerator(cone, DROPS, scene)
    with pytest.raises(ValueError, match=r"scene config: view_flip='yes'"):
        SceneConfig.from_dict({**SCENE.to_dict(), "view_flip": "yes"})
    with pytest.raises(ValueError, match=r"scene config: view_flip=True, expected false with scene.views=1"):
        SceneConfig.from_dict({**SCENE.to_dict(), "views": 1, "view_flip": True})
    assert "view_flip" not in SceneConfig().to_dict()  # datasets made before keep their record
