"""Generated scenes are geometrically right, in memory and read back through the IPA reader."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from opnet.datasets.ipa import IPADataset
from opnet.datasets.record import SceneRecord
from opnet.objects import builtin_object, object_from_config
from opnet.synthesis import CycleGenerator, SceneConfig, generate_dataset, read_generation

BUILTINS = ["bracket", "zbracket", "shaft", "pin"]
# 512 x 512 as the geometry check asks; convex hulls keep the physics fast (geometry does not care)
SCENE = SceneConfig(resolution=512, collision="convex_hull")


def surface_distances(record: SceneRecord, mesh: trimesh.Trimesh, per_instance: int = 400) -> dict[int, np.ndarray]:
    """Distance (m) to the mesh surface of instance k's depth pixels mapped back to the model frame."""
    points = record.camera.depth_to_points(record.depth)
    rng = np.random.default_rng(0)
    query = trimesh.proximity.ProximityQuery(mesh)
    out = {}
    for i, k in enumerate(record.instance_id):
        p = points[(record.segmentation == k) & np.isfinite(record.depth)]
        if len(p) == 0:
            continue
        p = p[rng.choice(len(p), min(per_instance, len(p)), replace=False)]
        p_model = (p - record.t_cam_obj[i]) @ record.R_cam_obj[i]  # R^T (p - t), row-wise
        out[int(k)] = np.abs(query.signed_distance(p_model))
    return out


def _check_geometry(record: SceneRecord, mesh: trimesh.Trimesh) -> None:
    dist = surface_distances(record, mesh)
    assert len(dist) >= record.num_objects - 1  # at most one part may be hidden completely
    for k, d in dist.items():
        assert np.median(d) < 1e-3, f"{record.name} instance {k}: median {np.median(d):.2e} m off the surface"
        assert np.percentile(d, 95) < 1e-3


@pytest.mark.parametrize("name", BUILTINS)
def test_scene_geometry_in_memory_and_read_back(name: str, tmp_path: Path) -> None:
    obj = builtin_object(name)
    with CycleGenerator(obj, 2, SCENE) as gen:
        result = gen.generate(seed=5, cycle=0)
    for record in result.records[1:]:
        _check_geometry(record, obj.mesh)

    generate_dataset(obj, tmp_path, cycles=1, drops=2, seed=5, scene=SCENE, progress=False, previews=1)
    dataset = IPADataset(tmp_path)
    assert dataset.scenes() == [(0, 0), (0, 1), (0, 2)]
    for n, mem in enumerate(result.records):
        disk = dataset.read(0, n)
        _check_geometry(disk, obj.mesh)
        # round trip: the reader gives back exactly what was generated in memory
        np.testing.assert_array_equal(disk.instance_id, mem.instance_id)
        np.testing.assert_array_equal(disk.R_cam_obj, mem.R_cam_obj)
        np.testing.assert_array_equal(disk.t_cam_obj, mem.t_cam_obj)
        np.testing.assert_array_equal(disk.visibility, mem.visibility)
        np.testing.assert_array_equal(disk.segmentation, mem.segmentation)
        np.testing.assert_array_equal(np.isnan(disk.depth), np.isnan(mem.depth))
        step = (disk.camera.clip_end - disk.camera.clip_start) / 65535
        np.testing.assert_allclose(disk.depth, mem.depth, atol=0.51 * step + 1e-6, equal_nan=True)
        assert disk.camera == mem.camera


@pytest.mark.shared
@pytest.mark.parametrize("name", ["bunny", "ring_screw", "gear_shaft"])
def test_scene_geometry_of_the_real_meshes(name: str, shared: Path) -> None:
    from opnet.cli.evaluate import resolve_object

    obj = resolve_object(name)
    with CycleGenerator(obj, 3, SceneConfig(resolution=256, collision="convex_hull")) as gen:
        result = gen.generate(seed=0, cycle=0)
    _check_geometry(result.records[-1], obj.mesh)


def test_dataset_root_files_describe_the_object(tmp_path: Path) -> None:
    obj = builtin_object("zbracket")
    report = generate_dataset(obj, tmp_path, cycles=3, drops=2, seed=1, scene=SceneConfig(resolution=64, collision="convex_hull"),
                              progress=False, previews=2)
    assert (report.cycles_generated, report.scenes_written) == (3, 9)
    rebuilt = object_from_config(json.loads((tmp_path / "object.json").read_text()))
    assert rebuilt.name == "zbracket" and rebuilt.symmetry == obj.symmetry
    poseutils = json.loads((tmp_path / "poseutils.json").read_text())
    assert poseutils["type"] == "AffinePoseUtils" and len(poseutils["G"]) == 2
    assert poseutils["distance_threshold"] == pytest.approx(obj.delta)
    assert sorted(p.name for p in (tmp_path / "preview").iterdir()) == ["cycle_0000_002.png", "cycle_0002_002.png"]
    assert read_generation(tmp_path)["seed"] == 1
    params = json.loads((tmp_path / "parameter.json").read_text())
    assert (params["number_cycles"], params["shapeDropLimit"], params["resolutionX"]) == (3, 2, 64)
    # the written visibilities are fractions and the bin row is the camera-frame bin pose
    ds = IPADataset(tmp_path)
    assert all(0.0 <= v <= 1.0 for c, n in ds.scenes() for v in ds.read(c, n).visibility)


def test_a_custom_mesh_object_is_stored_with_its_mesh(tmp_path: Path) -> None:
    mesh = trimesh.creation.box(extents=(0.05, 0.03, 0.02))
    from opnet.objects import ObjectModel

    obj = ObjectModel.from_mesh("brick", mesh, {"kind": "cyclic", "order": 2})
    generate_dataset(obj, tmp_path / "ds", cycles=1, drops=1, scene=SceneConfig(resolution=48, collision="convex_hull"),
                     progress=False)
    rebuilt = object_from_config(json.loads((tmp_path / "ds" / "object.json").read_text()))
    assert rebuilt.symmetry == obj.symmetry and rebuilt.diameter == pytest.approx(obj.diameter)


def test_same_seed_same_scenes_other_seed_other_scenes() -> None:
    obj = builtin_object("pin")
    scene = SceneConfig(resolution=64, collision="convex_hull")
    with CycleGenerator(obj, 3, scene) as gen:
        a, b, c = gen.generate(7, 2), gen.generate(7, 2), gen.generate(8, 2)
    for ra, rb in zip(a.records, b.records):
        np.testing.assert_array_equal(ra.t_cam_obj, rb.t_cam_obj)
        np.testing.assert_array_equal(ra.depth, rb.depth)
        np.testing.assert_array_equal(ra.visibility, rb.visibility)
    assert not np.allclose(a.records[-1].t_cam_obj, c.records[-1].t_cam_obj)


def test_existing_dataset_with_other_settings_is_refused(tmp_path: Path) -> None:
    obj = builtin_object("pin")
    scene = SceneConfig(resolution=32, collision="convex_hull")
    generate_dataset(obj, tmp_path, cycles=1, drops=1, seed=0, scene=scene, progress=False, previews=0)
    again = generate_dataset(obj, tmp_path, cycles=2, drops=1, seed=0, scene=scene, progress=False, previews=0)
    assert (again.cycles_skipped, again.cycles_generated) == (1, 1)  # more cycles extend the dataset
    with pytest.raises(ValueError, match=r"generation\.json.*seed"):
        generate_dataset(obj, tmp_path, cycles=2, drops=1, seed=1, scene=scene, progress=False)
