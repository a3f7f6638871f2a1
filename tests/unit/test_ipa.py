"""IPA layout: writer -> reader round trip, the camera frame, the depth code and bad input."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from opnet.datasets.ipa import IPADataset, read_ipa_scene, scene_paths, write_ipa_scene
from opnet.datasets.ipa_csv import CSV_HEADER, IPAGroundTruth, read_ipa_csv, write_ipa_csv
from opnet.datasets.ipa_params import IPAParameters, read_parameters, write_parameters
from opnet.datasets.png import decode_depth, encode_depth
from opnet.datasets.record import SceneRecord
from opnet.geometry import Camera, quaternion_to_matrix

CAMERA = Camera.from_fov(55.0, 32, 24, 0.6, 1.4)
BIN_POSE = (np.diag([1.0, -1.0, -1.0]), np.array([0.01, -0.02, 1.2]))


def make_record(n: int = 3, seed: int = 0, camera: Camera = CAMERA) -> SceneRecord:
    rng = np.random.default_rng(seed)
    depth = rng.uniform(0.5, 1.5, size=(camera.height, camera.width)).astype(np.float32)
    depth[0, :3] = np.nan
    return SceneRecord(
        name=f"scene_{seed}",
        depth=depth,
        camera=camera,
        segmentation=rng.integers(0, n + 1, size=depth.shape).astype(np.int32),
        R_cam_obj=quaternion_to_matrix(rng.normal(size=(n, 4))),
        t_cam_obj=rng.normal(size=(n, 3)),
        visibility=np.append(
            rng.uniform(0, 1, max(n - 1, 0)), [1.25] if n else []
        ),  # IPA scores may exceed 1
        instance_id=np.arange(1, n + 1),
        object_name="thing",
    )


def make_folder(tmp_path: Path, scenes: dict[int, list[int]]) -> Path:
    root = tmp_path / "Thing_part_1"
    write_parameters(
        root, IPAParameters.from_camera(CAMERA, number_cycles=len(scenes), shape_drop_limit=5)
    )
    for cycle, counts in scenes.items():
        for n in counts:
            write_ipa_scene(root, cycle, make_record(n, seed=100 * cycle + n), BIN_POSE)
    return root


def test_round_trip_is_exact(tmp_path: Path) -> None:
    rec = make_record(4)
    root = make_folder(tmp_path, {})
    write_ipa_scene(root, 7, rec, BIN_POSE)
    back = IPADataset(root).read(7, 4)
    assert back.name == "cycle_0007_004" and back.object_name == "Thing"
    np.testing.assert_array_equal(back.R_cam_obj, rec.R_cam_obj)
    np.testing.assert_array_equal(back.t_cam_obj, rec.t_cam_obj)
    np.testing.assert_array_equal(back.visibility, rec.visibility)
    np.testing.assert_array_equal(back.instance_id, rec.instance_id)
    np.testing.assert_array_equal(back.segmentation, rec.segmentation)
    inside = (rec.depth >= 0.6) & (rec.depth <= 1.4)
    assert np.isnan(back.depth[~inside]).all() and not np.isnan(back.depth[inside]).any()
    half_step = (1.4 - 0.6) / 65535 / 2
    assert np.abs(back.depth[inside] - rec.depth[inside]).max() <= half_step + 1e-7
    bin_ = read_ipa_csv(scene_paths(root, 7, 4)["csv"])
    np.testing.assert_array_equal(bin_.R_cam_bin, BIN_POSE[0])
    np.testing.assert_array_equal(bin_.t_cam_bin, BIN_POSE[1])


def test_writer_is_byte_deterministic(tmp_path: Path) -> None:
    a, b = make_folder(tmp_path / "a", {3: [0, 2]}), make_folder(tmp_path / "b", {3: [0, 2]})
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert len(files) == 7  # parameter.json + 2 scenes x (csv, depth, segmentation)
    assert all((a / f).read_bytes() == (b / f).read_bytes() for f in files)
    assert not list(a.rglob(".*.tmp"))


def test_segmentation_png_uses_255_for_no_object(tmp_path: Path) -> None:
    rec = make_record(2)
    root = make_folder(tmp_path, {})
    write_ipa_scene(root, 0, rec, BIN_POSE)
    png = cv2.imread(str(scene_paths(root, 0, 2)["segmentation"]), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint8
    np.testing.assert_array_equal(png == 255, rec.segmentation == 0)


def test_reader_maps_bin_background_and_unknown_values_to_zero(tmp_path: Path) -> None:
    root = make_folder(tmp_path, {1: [2]})
    seg = np.full((24, 32), 255, np.uint8)
    seg[0, :4] = [0, 1, 2, 9]  # bin, object 1, object 2, no such object
    cv2.imwrite(str(scene_paths(root, 1, 2)["segmentation"]), seg)
    rec = IPADataset(root).read(1, 2)
    assert rec.segmentation.dtype == np.int32
    assert rec.segmentation[0, :4].tolist() == [0, 1, 2, 0] and (rec.segmentation[1:] == 0).all()


def test_parameters_camera_uses_pixel_centre_canvas(tmp_path: Path) -> None:
    p = IPAParameters(
        90.0, 0.5, 2.0, 40, 30, 100, 10, 20, 1, 5, (0.0, 0.0, 1.0), (0.0, 1.0, 0.0, 0.0)
    )
    cam = p.camera()
    assert cam.fx == pytest.approx(50.0) and cam.fy == cam.fx  # 100 / (2 tan 45°)
    assert (cam.cx, cam.cy, cam.width, cam.height) == (49.5 - 10, 49.5 - 20, 40, 30)
    # the original IPA back-projection: x_ipa = -(u + offset - (N/2 - 0.5)) z / f, same for y
    u, v, z = 7.0, 11.0, 1.3
    x, y, _ = cam.backproject(u, v, z)
    assert (-x, -y) == pytest.approx((-(u + 10 - 49.5) * z / 50.0, -(v + 20 - 49.5) * z / 50.0))
    write_parameters(tmp_path, p)
    assert read_parameters(tmp_path) == p
    assert json.loads((tmp_path / "parameter.json").read_text())["pixelOffset_Y_KoSyTopLeft"] == 20


def test_from_camera_inverts_camera_and_rejects_unrepresentable() -> None:
    for cam in (
        CAMERA,
        Camera(400.0, 400.0, 100.5, 30.5, 180, 80, 0.2, 3.0),
        CAMERA.cropped(-3, 5, 20, 10),
    ):
        back = IPAParameters.from_camera(cam, 1, 1).camera()
        assert back.fx == pytest.approx(cam.fx, rel=1e-12) and back.fy == back.fx
        assert (back.cx, back.cy, back.width, back.height, back.clip_end) == (
            cam.cx,
            cam.cy,
            cam.width,
            cam.height,
            cam.clip_end,
        )
    with pytest.raises(ValueError, match="square pixels"):
        IPAParameters.from_camera(Camera(400.0, 410.0, 10.5, 10.5, 20, 20, 0.2, 3.0), 1, 1)
    with pytest.raises(ValueError, match="half-integer"):
        IPAParameters.from_camera(Camera(400.0, 400.0, 10.3, 10.5, 20, 20, 0.2, 3.0), 1, 1)
    with pytest.raises(ValueError, match="both"):
        IPAParameters.from_camera(Camera(400.0, 400.0, 10.0, 10.5, 20, 20, 0.2, 3.0), 1, 1)
    with pytest.raises(ValueError, match="canvas"):
        IPAParameters.from_camera(CAMERA, 1, 1, resolution_big=20)


def test_csv_frame_and_column_major_rotation(tmp_path: Path) -> None:
    path = tmp_path / "001.csv"
    # object 1 at IPA (0.1, 0.2, 1.0); its x-axis is IPA +y, y-axis IPA -x, z-axis IPA +z
    path.write_text(
        ",".join(CSV_HEADER)
        + "\n0,0,0,0,1.5,1,0,0,0,1,0,0,0,1,1,1\n1,3,0.1,0.2,1.0,0,1,0,-1,0,0,0,0,1,0.5,0.75\n"
    )
    gt = read_ipa_csv(path)
    np.testing.assert_allclose(gt.t_cam_obj, [[-0.1, -0.2, 1.0]])
    np.testing.assert_allclose(
        gt.R_cam_obj[0], [[0, 1, 0], [-1, 0, 0], [0, 0, 1]]
    )  # x-axis -> camera -y
    assert gt.instance_id.tolist() == [1] and gt.object_class.tolist() == [3]
    assert gt.visibility_o.tolist() == [0.5] and gt.visibility_p.tolist() == [0.75]
    np.testing.assert_allclose(gt.t_cam_bin, [0, 0, 1.5])
    np.testing.assert_allclose(gt.R_cam_bin, np.diag([-1.0, -1.0, 1.0]))


def test_depth_code() -> None:
    z = np.array([[np.nan, 0.59, 0.6, 1.0, 1.4, 1.41, 1.4 - 1e-7]])
    code = encode_depth(z, 0.6, 1.4)
    assert code.dtype == np.uint16
    assert code.tolist() == [[65535, 65535, 0, 32768, 65534, 65535, 65534]]
    back = decode_depth(code, 0.6, 1.4)
    assert back.dtype == np.float32 and np.isnan(back[0, [0, 1, 5]]).all()
    zs = np.random.default_rng(1).uniform(0.6, 1.4, size=(50, 50))
    assert (
        np.abs(decode_depth(encode_depth(zs, 0.6, 1.4), 0.6, 1.4) - zs).max()
        <= 0.8 / 65535 / 2 + 1e-7
    )


def test_dataset_listing_and_filters(tmp_path: Path) -> None:
    root = make_folder(tmp_path, {2: [0, 1, 3], 5: [0, 2]})
    ds = IPADataset(root)
    assert (
        ds.scenes() == [(2, 0), (2, 1), (2, 3), (5, 0), (5, 2)]
        and len(ds) == 5
        and ds.cycles() == [2, 5]
    )
    assert ds[2].num_objects == 3 and ds[0].num_objects == 0 and ds.camera == ds.params.camera()
    assert IPADataset(root, cycles=range(3, 9)).scenes() == [(5, 0), (5, 2)]
    assert IPADataset(root, include_empty=False).scenes() == [(2, 1), (2, 3), (5, 2)]
    assert IPADataset(root, min_objects=2, object_name="x").scenes() == [(2, 3), (5, 2)]
    gt = ds.read_ground_truth(2, 3)
    np.testing.assert_array_equal(gt.t, ds[2].t_cam_obj)
    assert gt.occlusion_rate[-1] == 0.0  # visibility 1.25 clipped


def test_writer_rejects_bad_ids_and_camera_mismatch(tmp_path: Path) -> None:
    root = make_folder(tmp_path, {})
    rec = make_record(2)
    rec.instance_id = np.array([1, 300])
    with pytest.raises(ValueError, match="1..254"):
        write_ipa_scene(root, 0, rec, BIN_POSE)
    rec = make_record(2)
    rec.segmentation[0, 0] = 7
    with pytest.raises(ValueError, match=r"\[7\]"):
        write_ipa_scene(root, 0, rec, BIN_POSE)
    other = make_record(2, camera=Camera.from_fov(40.0, 32, 24, 0.6, 1.4))
    with pytest.raises(ValueError, match="parameter.json"):
        write_ipa_scene(root, 0, other, BIN_POSE)


# ---- bad input: every error names the file ------------------------------------------------------
def test_bad_depth_pngs_are_refused(tmp_path: Path) -> None:
    root = make_folder(tmp_path, {1: [1]})
    params, depth_png = read_parameters(root), scene_paths(root, 1, 1)["depth"]
    good = depth_png.read_bytes()
    cases = {
        "corrupt": good[:8] + bytes(range(256)) * 4,
        "truncated": good[: len(good) // 2],
        "8-bit": cv2.imencode(".png", np.zeros((24, 32), np.uint8))[1].tobytes(),
        "32x32": cv2.imencode(".png", np.zeros((32, 32), np.uint16))[1].tobytes(),
        "signature": b"not a png at all",
    }
    for expected, data in cases.items():
        depth_png.write_bytes(data)
        with pytest.raises(ValueError, match=expected) as err:
            read_ipa_scene(root, 1, 1, params)
        assert str(depth_png) in str(err.value)
    depth_png.unlink()
    with pytest.raises(FileNotFoundError, match="001_depth_uint16.png"):
        read_ipa_scene(root, 1, 1, params)


@pytest.mark.parametrize(
    ("line", "expected"),
    [
        ("1,1,0.1,0.2", "line 3: 4 columns, expected 16"),
        ("1,1,abc" + ",0" * 13, "line 3: unparsable"),
        ("1,1,nan" + ",0" * 13, "line 3: expected finite"),
        ("0,1" + ",0" * 14, "line 3: duplicate id 0"),
    ],
)
def test_bad_csv_is_refused(tmp_path: Path, line: str, expected: str) -> None:
    path = tmp_path / "001.csv"
    path.write_text(",".join(CSV_HEADER) + "\n0,0" + ",0" * 14 + "\n" + line + "\n")
    with pytest.raises(ValueError, match=expected) as err:
        read_ipa_csv(path)
    assert str(path) in str(err.value)


def test_bad_parameter_json_is_refused(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="parameter.json"):
        read_parameters(tmp_path)
    with pytest.raises(FileNotFoundError, match="parameter.json"):
        IPADataset(tmp_path)
    good = IPAParameters.from_camera(CAMERA, 1, 1).to_json_dict()
    path = tmp_path / "parameter.json"
    for key, value, expected in [
        ("clip_end", None, "missing field 'clip_end'"),
        ("resolutionX", 32.5, "'resolutionX' is 32.5, expected an integer"),
        ("rotation", [1, 0, 0], "'rotation' is .*quaternion"),
        ("perspectiveAngle", "60", "'perspectiveAngle' is '60', expected a number"),
        ("clip_start", 2.0, "clip_start < clip_end"),
    ]:
        data = dict(good)
        if value is None:
            del data[key]
        else:
            data[key] = value
        path.write_text(json.dumps(data))
        with pytest.raises(ValueError, match=expected) as err:
            read_parameters(path)
        assert str(path) in str(err.value)


@settings(max_examples=25, deadline=None, derandomize=True)
@given(
    quaternion=st.lists(st.floats(-1.0, 1.0, width=64), min_size=4, max_size=4).filter(
        lambda q: float(np.linalg.norm(q)) > 0.1),
    t=st.lists(st.floats(-50.0, 50.0, width=64), min_size=3, max_size=3),
    visibility=st.lists(st.floats(0.0, 2.0, width=64), min_size=2, max_size=2),
)
def test_csv_floats_survive_exactly(tmp_path_factory: pytest.TempPathFactory, quaternion: list, t: list,
                                    visibility: list) -> None:
    """Any float64 pose (the rotation from any quaternion, all 17 digits) reads back bit for bit;
    values outside the plausible ranges are refused (tests/unit/test_input_validation.py)."""
    path = tmp_path_factory.mktemp("csv") / "001.csv"
    w, x, y, z = np.asarray(quaternion) / np.linalg.norm(quaternion)
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    gt = IPAGroundTruth(
        instance_id=np.array([1]),
        object_class=np.array([2]),
        R_cam_obj=R.reshape(1, 3, 3),
        t_cam_obj=np.array(t).reshape(1, 3),
        visibility_o=np.array(visibility[:1]),
        visibility_p=np.array(visibility[1:]),
    )
    write_ipa_csv(path, gt)
    back = read_ipa_csv(path)
    assert back.R_cam_bin is None
    for key in ("R_cam_obj", "t_cam_obj", "visibility_o", "visibility_p"):
        got, want = getattr(back, key), getattr(gt, key)
        np.testing.assert_array_equal(got, want, err_msg=key)  # exact (0.0 == -0.0)


def test_pile_fingerprint_tells_other_piles_from_the_same(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    from opnet.datasets.check import main as check_main
    from opnet.datasets.check import pile_fingerprint

    a, b = (make_folder(tmp_path / name, {0: [0, 2, 3]}) for name in ("a", "b"))
    same = pile_fingerprint(a)
    assert same == pile_fingerprint(b) and same[1] == 3
    rec = make_record(3, seed=3)
    rec.t_cam_obj[1, 2] += 1e-9  # under the hash's rounding (1 µm): the same pile written otherwise
    write_ipa_scene(b, 0, rec, BIN_POSE)
    assert pile_fingerprint(b) == same
    rec.t_cam_obj[1, 2] += 2e-5  # a part settled 20 µm away: another pile
    write_ipa_scene(b, 0, rec, BIN_POSE)
    assert pile_fingerprint(b)[0] != same[0]
    assert check_main(["--fingerprint", str(a), str(tmp_path / "none")]) == 2
    out, err = capsys.readouterr()
    assert out.split() == [same[0], "3", "scenes", str(a)] and "none" in err
