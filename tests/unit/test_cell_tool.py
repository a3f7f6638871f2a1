"""opnet-cell: a cell measured from its depth frames alone, in the generator's terms.

The references are external to the tool: generated piles of known rigs (the generator's own settings), and
for the real IPD Photoneo frames the camera pose their ground truth implies (opnet.synthesis.camera_pose,
read here only) and the ground-truth plates the basket must hold. Each acceptance check is also run on a
deliberately broken estimate and must fail there.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

from opnet.cell import bin_view, planes, rig  # noqa: E402
from opnet.cell.estimate import measure_cell  # noqa: E402
from opnet.cell.frames import read_frames  # noqa: E402
from opnet.datasets.camera_file import read_camera_file  # noqa: E402

#: a camera whose principal point lies off the image centre (the generator's height and the distance along
#: the optical axis differ for it)
CAMERA_YAML = "fx: 300\nfy: 302\ncx: 170.3\ncy: 111.7\nwidth: 320\nheight: 240\nclip_start: 0.5\nclip_end: 3.0\n"
#: (name, tilt, azimuth, clearance, x, y, yaw): the generated rigs, on the floor and on a stand
RIGS = (("level_floor", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), ("tilt20_floor", 20.0, -30.0, 0.0, 0.05, -0.03, 25.0),
        ("tilt35_stand", 35.0, 60.0, 0.3, -0.04, 0.02, -40.0), ("tilt10_stand", 10.0, 150.0, 0.5, 0.0, 0.0, 80.0))
INNER, WALL, THICKNESS, HEIGHT = (0.3, 0.5), 0.12, 0.004, 1.2


def _generate(root: Path, camera: Path, tilt: float, azimuth: float, clearance: float, x: float, y: float,
              yaw: float) -> Path:  # fmt: skip
    from opnet.objects.library import builtin_object
    from opnet.synthesis.config import SceneConfig
    from opnet.synthesis.generate import generate_dataset

    scene = SceneConfig(camera_file=str(camera), clip="camera", camera_height=HEIGHT, camera_tilt_deg=tilt,
                        camera_azimuth_deg=azimuth, bin_inner=INNER[0], bin_inner_y=INNER[1], bin_wall_height=WALL,
                        bin_wall_thickness=THICKNESS, bin_clearance=clearance, camera_jitter_m=0.0,
                        camera_jitter_deg=0.0, bin_area=(x, y, x, y), bin_yaw_deg=(yaw, yaw), outside_clip="clamp")
    generate_dataset(builtin_object("zbracket"), root, cycles=1, drops=2, workers=1, seed=0, scene=scene,
                     progress=False, previews=0)
    return root


@pytest.fixture(scope="module")
def rigs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Path, tuple]]:
    """Each rig's dataset folder (its depth PNGs are the frames), camera file and settings."""
    base = tmp_path_factory.mktemp("cell_rigs")
    camera = base / "camera.yaml"
    camera.write_text(CAMERA_YAML)
    return {name: (_generate(base / name, camera, *settings), camera, settings) for name, *settings in RIGS}


def _measure(root: Path, camera_file: Path):
    camera = read_camera_file(camera_file)
    return measure_cell(read_frames(root, camera, camera_file), camera)


def _leaning(plane: planes.Plane, axis: np.ndarray) -> planes.Plane:
    """A broken plane fit: the normal turned 1.5 degrees about ``axis``."""
    from opnet.synthesis.layout import rotation_about

    return planes.Plane(rotation_about(axis, math.radians(1.5)) @ plane.normal, plane.offset)


def _check_rig(cell, settings: tuple) -> None:
    tilt, azimuth, clearance, x, y, yaw = settings
    assert abs(cell.tilt_deg - tilt) < 0.5
    if tilt > 0:
        assert abs((cell.azimuth_deg - azimuth + 180) % 360 - 180) < 1.0
    assert abs(cell.camera_height - HEIGHT) < 0.005
    assert np.allclose(cell.sides, INNER, atol=0.01)
    assert abs(cell.wall_height - WALL) < 0.01
    assert abs(cell.clearance - clearance) < 0.01
    px, py, pyaw = np.median(cell.placements, axis=0)
    assert abs(px - x) < 0.01 and abs(py - y) < 0.01
    assert abs((pyaw - yaw + 90) % 180 - 90) < 2.0


@pytest.mark.parametrize("name", [r[0] for r in RIGS])
def test_a_generated_rig_is_measured_as_the_generator_set_it(rigs, name) -> None:
    root, camera, settings = rigs[name]
    cell = _measure(root, camera)
    assert len(cell.views) == 3  # the empty bin and two drops: the bin found in each
    _check_rig(cell, settings)
    # the working volume holds the bin anywhere in the area, the crop holds the bin in any yaw
    corners = rig.anywhere_in(cell.area, cell.sides, cell.thickness, cell.wall_height)
    depths = rig.camera_depths(cell.T_world_cam, corners)
    assert cell.clip[0] < depths.min() and depths.max() < cell.clip[1]
    assert cell.crop_side >= 1.1 * math.hypot(*(s + 2 * cell.thickness for s in cell.sides)) - 1e-9


def test_the_rig_checks_fail_on_a_broken_estimate(rigs, monkeypatch) -> None:
    """The same checks on estimates broken on purpose: the height along the optical axis instead of the
    image centre's ray, and a plane fit whose normal leans 1.5 degrees."""
    root, camera, settings = rigs["tilt20_floor"]
    monkeypatch.setattr(rig, "generator_height", lambda plane, cam: rig.axis_height(plane))
    with pytest.raises(AssertionError):
        _check_rig(_measure(root, camera), settings)
    monkeypatch.undo()
    fit = planes.fit_plane

    monkeypatch.setattr(planes, "fit_plane", lambda points: _leaning(fit(points), np.array([1.0, 0.0, 0.0])))
    with pytest.raises(AssertionError):
        _check_rig(_measure(root, camera), settings)


def test_the_generator_height_is_the_image_centre_ray_not_the_optical_axis(rigs) -> None:
    """For a principal point off the image centre the two differ (here by 8 mm); the generator's is the first."""
    root, camera, _ = rigs["tilt20_floor"]
    cell = _measure(root, camera)
    assert abs(cell.camera_height - HEIGHT) < 0.002
    assert abs(rig.axis_height(cell.floor) - HEIGHT) > 0.005


# ------------------------------------------------------------------------------------------- the IPD cell


def _ipd_reference(split: Path):
    """The camera pose the frames' ground truth implies (parts lying flat), as opnet.synthesis.camera_pose
    computes it, and the plates' vertices in the camera frame (metres)."""
    from opnet.datasets.bop import models_dir_of
    from opnet.datasets.autodetect import open_dataset
    from opnet.objects.bop import bop_object
    from opnet.synthesis import camera_pose

    dataset = open_dataset(split, object_id=18)
    obj = bop_object(models_dir_of(split), 18)
    axis, thickness = camera_pose.thin_axis(np.asarray(obj.mesh.vertices))
    R = np.concatenate([dataset[i].R_cam_obj for i in range(len(dataset))])
    t = np.concatenate([dataset[i].t_cam_obj for i in range(len(dataset))])
    pose = camera_pose.estimate_pose(R, t, axis, thickness)
    normals = camera_pose._normals(R, t, axis)
    keep = np.degrees(np.arccos(np.clip(normals @ camera_pose._normal(pose), -1, 1))) <= 10.0
    pose = camera_pose.estimate_pose(R[keep], t[keep], axis, thickness)
    vertices = np.asarray(obj.mesh.vertices)
    plates = [vertices @ Ri.T + ti for Ri, ti in zip(R, t, strict=True)]
    return pose, plates


@pytest.fixture(scope="module")
def ipd(shared: Path):
    folder = shared / "data" / "ipd_real_obj18"
    camera_file = folder / "camera_photoneo.yaml"
    camera = read_camera_file(camera_file)
    frames = read_frames(folder / "test", camera, camera_file)
    return frames, camera, _ipd_reference(folder / "test")


def _check_ipd(cell, reference) -> None:
    pose, plates = reference
    assert abs(cell.tilt_deg - pose.camera_tilt_deg) < 1.0
    assert abs(cell.azimuth_deg - pose.camera_azimuth_deg) < 2.0
    # the height as camera_pose defines it (along the optical axis) and as the generator does (the image
    # centre's ray), both from the ground truth's floor plane
    assert abs(rig.axis_height(cell.floor) - pose.camera_height) < 0.01
    tilt, az = math.radians(pose.camera_tilt_deg), math.radians(pose.camera_azimuth_deg)
    normal = np.array([-math.cos(az) * math.sin(tilt), math.sin(az) * math.sin(tilt), -math.cos(tilt)])
    floor = planes.Plane(normal, pose.camera_height * math.cos(tilt))
    assert abs(cell.camera_height - rig.generator_height(floor, cell.camera)) < 0.01
    for view in cell.views:  # every ground-truth plate inside the basket measured in each frame
        for plate in plates:
            rel = plate - view.centre
            assert np.abs(rel @ view.axis).max() <= view.sides[0] / 2 + 0.005
            assert np.abs(rel @ view.across).max() <= view.sides[1] / 2 + 0.005


@pytest.mark.shared
def test_the_ipd_cell_matches_what_its_ground_truth_implies(ipd) -> None:
    frames, camera, reference = ipd
    cell = measure_cell(frames, camera)
    _check_ipd(cell, reference)
    each = cell.per_frame()
    assert np.ptp(each["camera_tilt_deg"]) < 0.3 and np.ptp(each["camera_height"]) < 0.003
    assert np.ptp(each["bin_inner"]) < 0.01 and np.ptp(each["bin_inner_y"]) < 0.01
    # the basket, as hand-measured for the cell study (inner 0.30 x 0.65 m, walls 0.10 m, 0.6 m over the
    # ground), is not what its depth shows: its ground-truth plates span 0.316 m across, and its far wall and
    # visible floor end 0.60 m apart; the rim stands 0.138 m over the floor the plates lie on
    assert np.allclose(cell.sides, (0.323, 0.593), atol=0.01)
    assert abs(cell.wall_height - 0.138) < 0.005
    assert 0.5 < cell.clearance < 0.6


@pytest.mark.shared
def test_the_ipd_checks_fail_on_a_broken_plane_fit(ipd, monkeypatch) -> None:
    frames, camera, reference = ipd
    refit = bin_view.refit

    def leaning(points: np.ndarray, plane: planes.Plane, tol: float) -> tuple[planes.Plane, np.ndarray]:
        fitted, inliers = refit(points, plane, tol)
        return _leaning(fitted, np.array([0.0, 1.0, 0.0])), inliers

    monkeypatch.setattr(bin_view, "refit", leaning)  # the bin floor's least-squares refit
    with pytest.raises(AssertionError):
        _check_ipd(measure_cell(frames, camera), reference)


def test_a_floor_without_walls_is_no_bin() -> None:
    """A plane alone (a table, the ground) is refused as no bin, naming the frame."""
    from opnet.geometry.camera import Camera

    camera = Camera(300.0, 300.0, 159.5, 119.5, 320, 240, 0.5, 3.0)
    v, u = np.mgrid[0:240, 0:320]
    depth = np.full((240, 320), 1.2, np.float32) + 0.0005 * (u - 160) / 160  # a plane facing the camera
    with pytest.raises(bin_view.BinNotFound, match="frame.npy: no bin"):
        bin_view.find_bin(depth, camera, "frame.npy")
