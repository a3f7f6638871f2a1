"""Device-side inference (``inference.device_side``): the torch preprocessing and the torch pose
averaging give what the host's OpenCV / numpy code gives, on rendered and real depth and on random
and real network outputs; the system, predict.py and validation decode where the setting says.
The CUDA cases run where a GPU is present."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import cv2
import lightning as L
import numpy as np
import pytest
import torch
from hydra.utils import instantiate
from hypothesis import given, settings
from hypothesis import strategies as st
from omegaconf import OmegaConf
from scipy.spatial import cKDTree
from sklearn.cluster import DBSCAN

from opnet.cli.build import load_checkpoint
from opnet.cli.predict import predict_image
from opnet.data import preprocess_torch
from opnet.data.preprocess import network_camera, to_network_input
from opnet.data.sample import collate, make_sample
from opnet.datasets.depth_inputs import DepthImage
from opnet.datasets.ipa import IPADataset
from opnet.geometry import Camera
from opnet.geometry.camera import with_clip
from opnet.geometry.pose_numpy import pose_distance
from opnet.objects import builtin_object
from opnet.parameterizations.averaging_torch import dbscan_graph, neighbour_pairs
from opnet.paths import REPO_ROOT, config_dir
from opnet.settings_schema import CANVAS_FITS
from param_checks import (
    assert_graph_capturable,
    assert_same_hypotheses,
    noisy_outputs,
    parameterization_names,
    tiny_system,
)

CUDA = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
ZBRACKET = builtin_object("zbracket")


@pytest.fixture(scope="session")
def pile(tmp_path_factory: pytest.TempPathFactory) -> list:
    """Rendered piles of zbrackets under the structured-light sensor model (about 30 % of the pixels
    missing: shadows, edges, dropouts) at 300 x 236: a shrink to 128 by a non-integer factor. Where
    ``OPNET_PILE`` names an IPA-layout dataset (a GPU machine without the renderer), its first eight
    frames instead."""
    given = os.environ.get("OPNET_PILE")
    if given:
        dataset = IPADataset(Path(given))
        return [dataset[i] for i in range(min(8, len(dataset)))]
    from opnet.synthesis import SceneConfig, generate_dataset

    root = tmp_path_factory.mktemp("pile") / "zbracket"
    sensor = OmegaConf.to_container(OmegaConf.load(config_dir() / "sensor" / "structured_light.yaml"))
    generate_dataset(ZBRACKET, root, cycles=1, drops=6, workers=1, seed=3, progress=False, previews=0,
                     scene=SceneConfig(resolution=300, width=300, height=236), sensor=sensor,
                     object_config={"name": "zbracket", "builtin": "zbracket"})  # fmt: skip
    dataset = IPADataset(root)
    records = [dataset[i] for i in range(len(dataset))]
    assert min(np.isnan(r.depth).mean() for r in records[1:]) > 0.1  # the sensor model left holes to fill
    return records


# ---- preprocessing -----------------------------------------------------------------------------
@pytest.mark.parametrize(("source", "size"), [(512, 128), (300, 128), (2064, 128), (128, 128), (129, 128),
                                              (100, 128), (37, 128), (1000, 333), (2500, 1001)])  # fmt: skip
def test_the_resize_is_opencvs_inter_area(source: int, size: int) -> None:
    """Shrinking by integer and fractional factors (2500 -> 1001: partial pixels under 1e-3, which
    OpenCV drops), the identity, and enlarging (OpenCV's area mode then interpolates with its own
    fractions)."""
    image = np.random.default_rng(source).random((source, source), dtype=np.float32)
    ours = preprocess_torch.area_resize(torch.from_numpy(image), (0, 0, source), size).numpy()
    np.testing.assert_allclose(ours, cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA), atol=1e-6, rtol=0)


@pytest.mark.parametrize("fit", CANVAS_FITS)
@pytest.mark.parametrize("size", [128, 400])
def test_preprocessing_equals_the_host_on_rendered_depth(pile: list, fit: str, size: int) -> None:
    """Every frame of the pile in one batch: the same input (to float32 rounding) and camera as
    OpenCV / numpy frame by frame, holes filled the same way."""
    depths = [r.depth for r in pile]
    camera = pile[0].camera
    images, cam = preprocess_torch.to_network_input(depths, camera, size, fit)
    assert images.shape == (len(pile), 1, size, size) and images.dtype == torch.float32
    for depth, image in zip(depths, images, strict=True):
        ref, ref_cam = to_network_input(depth, camera, size, cv2.INTER_AREA, fit)
        np.testing.assert_allclose(image[0].numpy(), ref, atol=1e-5, rtol=0)
        assert cam == ref_cam
    assert cam == network_camera(camera, size, fit)


def test_preprocessing_edge_cases_equal_the_host() -> None:
    camera = Camera(200.0, 200.0, 40.3, 70.8, 90, 120, 0.5, 1.5)  # off-centre principal point: padding
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.3, 1.8, (120, 90)).astype(np.float32)  # beyond both clip planes too
    depth[rng.random(depth.shape) < 0.4] = np.nan
    depth[:, :20] = np.nan  # a missing band along the edge
    depth[50:52] = 0.0  # z = 0 is missing too
    cases = [(depth, None), (np.full_like(depth, np.nan), None), (depth, (-30, 10, 100)), (depth, (5, -40, 300))]
    for image, canvas in cases:
        ref, ref_cam = to_network_input(image, camera, 64, cv2.INTER_AREA, canvas=canvas)
        ours, cam = preprocess_torch.to_network_input(torch.from_numpy(image), camera, 64, canvas=canvas)
        np.testing.assert_allclose(ours[0, 0].numpy(), ref, atol=1e-5, rtol=0)
        assert cam == ref_cam
    assert (preprocess_torch.to_network_input(cases[1][0], camera, 64)[0] == 1.0).all()  # no depth: the far plane
    with pytest.raises(ValueError, match="does not match the camera"):
        preprocess_torch.to_network_input(depth[:100], camera)
    with pytest.raises(ValueError, match="infinite"):
        preprocess_torch.to_network_input(torch.full((120, 90), float("inf")), camera)


@pytest.mark.shared
def test_preprocessing_equals_the_host_on_real_sensor_frames(shared: Path) -> None:
    """The IPD Photoneo frames (2064 x 1544, real holes), whole and cut to the trained box."""
    from opnet.datasets.bop import BOPDataset

    frames = BOPDataset(shared / "data" / "ipd_real_obj18" / "test", 18, clip=(1.55, 2.05))
    for i in range(len(frames)):
        record = frames[i]
        assert np.isnan(record.depth).mean() > 0.01
        for depth, camera in [(record.depth, record.camera),
                              (record.depth[230:1160, 560:1250], record.camera.cropped(560, 230, 690, 930))]:
            ref, ref_cam = to_network_input(depth, camera, 128, cv2.INTER_AREA, "image")
            ours, cam = preprocess_torch.to_network_input(depth, camera, 128, "image")
            np.testing.assert_allclose(ours[0, 0].numpy(), ref, atol=1e-5, rtol=0)
            assert cam == ref_cam


# ---- decoding ----------------------------------------------------------------------------------
AVERAGINGS = [
    False,
    {"eps": 1.5, "cluster_score": "sum"},  # the tuned decoding
    {"eps": 0.5},
    {"eps": 0.6, "min_samples": 3, "cluster_score": "mean"},  # noise dropped
    {"eps": 0.8, "min_samples": 2, "keep_noise": True},  # noise kept as single hypotheses
]


def _parameterization(name: str, obj: object = ZBRACKET, **settings: object) -> object:
    return instantiate(OmegaConf.load(config_dir() / "parameterization" / f"{name}.yaml"), _partial_=True)(
        obj=obj, **settings)


def _with_averaging(param: object, averaging: bool | dict) -> object:
    if not isinstance(averaging, dict):
        return param.with_decoding(averaging=averaging, score="p*v")
    settings = dict(averaging)
    keep_noise = settings.pop("keep_noise", False)
    param = param.with_decoding(averaging=settings, score="p*v")
    param.averaging = dataclasses.replace(param.averaging, keep_noise=keep_noise)
    return param


@pytest.mark.parametrize("averaging", AVERAGINGS, ids=["none", "tuned", "eps0.5", "min3-mean", "min2-noise"])
@pytest.mark.parametrize("name", parameterization_names())
@pytest.mark.parametrize("obj", ["zbracket", "pin"])  # a finite group; a revolution object (mean axis)
def test_device_averaging_equals_the_host_on_random_outputs(obj: str, name: str, averaging: bool | dict) -> None:
    param = _with_averaging(_parameterization(name, builtin_object(obj)), averaging)
    camera = network_camera(Camera.from_fov(50.0, 512, 512, 0.6, 1.2))
    out = noisy_outputs(param, camera, 6, seed=len(name))
    host = param.decode(out, camera)
    device = param.decode(out, camera, device_side=True)
    assert_same_hypotheses(host, device)
    assert len(host[1]) == 1 and len(host[2]) == 0
    decoded = sum(len(h) for h in param.with_decoding(averaging=False).decode(out, camera))
    assert decoded > 20
    if averaging and name in ("eve", "mp"):  # several cells per part: clusters of several to average
        assert sum(len(h) for h in host) < decoded


def test_device_averaging_equals_the_host_on_a_tiny_networks_outputs(pile: list) -> None:
    """Real network outputs (a tiny network's on the rendered pile, the threshold at the median
    presence: hypotheses in half the cells), decoded with the tuned averaging and with noise dropped."""
    system = tiny_system(["parameterization=eve", "decoding=tuned"])
    batch = collate([make_sample(r, 128, fit="image") for r in pile])
    with torch.no_grad():
        out = system(batch.images)
    median = float(out[:, :: system.parameterization.channels_per_slot].median())
    for averaging in ({"eps": 1.5, "cluster_score": "sum"}, {"eps": 2.0, "min_samples": 3}):
        param = system.parameterization.with_decoding(averaging=averaging, threshold=median)
        host = param.decode(out, batch.cameras)
        assert_same_hypotheses(host, param.decode(out, batch.cameras, device_side=True))
        assert sum(len(h) for h in host) > 10


@pytest.mark.shared
def test_device_side_prediction_equals_the_host_with_a_trained_model_on_a_real_frame(shared: Path) -> None:
    """predict.py's path end to end, both ways: the trained plate model on the IPD Photoneo frames."""
    from opnet.datasets.bop import BOPDataset

    ckpt = REPO_ROOT / "models" / "fixed_box_ipd_plate.ckpt"
    system, _ = load_checkpoint(str(ckpt))
    clip = system.settings.input.trained_clip
    frames = BOPDataset(shared / "data" / "ipd_real_obj18" / "test", 18, clip=clip)
    for i in range(len(frames)):
        record = frames[i]
        image = DepthImage(Path(f"{record.name}.png"), record.depth, with_clip(record.camera, clip))
        results = []
        for side in (False, True):
            system.configure_decoding(side)
            results.append(predict_image(system, image))
        # inputs equal to float32 rounding (1e-7), which the network amplifies to 1e-5 in its output
        assert_same_hypotheses([results[0]], [results[1]], atol=1e-4)
        assert len(results[0]) > 0


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(0, 60), min_samples=st.sampled_from([1, 2, 3, 5]),
       eps=st.floats(0.05, 0.6))  # fmt: skip
def test_dbscan_on_tensors_matches_sklearn(seed: int, n: int, min_samples: int, eps: float) -> None:
    rng = np.random.default_rng(seed)
    points = rng.uniform(0, 3, (4, 2))[rng.integers(0, 4, n)] + rng.normal(0, 0.25, (n, 2))
    distance = np.linalg.norm(points[:, None] - points[None], axis=-1)
    i, j = np.nonzero((distance <= eps) & ~np.eye(n, dtype=bool))
    ours = dbscan_graph(n, torch.from_numpy(i), torch.from_numpy(j), min_samples).numpy()
    if n:
        np.testing.assert_array_equal(ours, DBSCAN(eps=eps, min_samples=min_samples, metric="precomputed").fit(distance).labels_)


@pytest.mark.parametrize("name", ["zbracket", "pin"])
def test_the_grid_finds_the_k_d_trees_pairs(name: str) -> None:
    """Pairs within eps in pose space: the grid of cubes on tensors against the k-d tree and the numpy
    pose distance, image by image (a finite group and a revolution object)."""
    obj = builtin_object(name)
    param = _with_averaging(_parameterization("eve", obj), {"eps": 3.0})
    camera = network_camera(Camera.from_fov(50.0, 512, 512, 0.6, 1.2))
    out = noisy_outputs(param, camera, 4, seed=7)
    b, R, t, _, _ = param.decode_cells(out, camera)
    i, j = neighbour_pairs(param.averaging, b, R, t, 4)
    ours = {(int(x), int(y)) for x, y in zip(i, j, strict=True) if x < y}
    eps = 3.0 * obj.pose_space.delta
    Rn, tn, bn = R.numpy(), t.numpy(), b.numpy()
    ref = set()
    for k in range(4):
        index = np.flatnonzero(bn == k)
        pairs = cKDTree(tn[index]).query_pairs(eps, output_type="ndarray")
        a, c = index[pairs[:, 0]], index[pairs[:, 1]]
        near = pose_distance(obj.pose_space, Rn[a], tn[a], Rn[c], tn[c]) <= eps
        ref |= {(int(min(x, y)), int(max(x, y))) for x, y in zip(a[near], c[near], strict=True)}
    assert ours == ref and len(ref) > 10


# ---- where the system decodes ------------------------------------------------------------------
def test_the_system_decodes_where_the_setting_says(pile: list, monkeypatch: pytest.MonkeyPatch) -> None:
    system = tiny_system(["parameterization=vanilla"])
    assert system.device_side is False  # auto on the CPU: the host is faster there
    seen: list[bool] = []
    decode = type(system.parameterization).decode
    monkeypatch.setattr(type(system.parameterization), "decode",
                        lambda self, out, cams, device_side=False, turned=None: seen.append(device_side)
                        or decode(self, out, cams, device_side, turned))
    samples = [make_sample(r, 128, fit="image") for r in pile[:2]]
    batch, loader = collate(samples), torch.utils.data.DataLoader(samples, batch_size=2, collate_fn=collate)
    trainer = L.Trainer(accelerator="cpu", logger=False, enable_checkpointing=False, enable_progress_bar=False,
                        enable_model_summary=False, limit_val_batches=1)
    for setting, expected in (("auto", False), (True, True), (False, False)):
        system.configure_decoding(setting)
        trainer.validate(system, dataloaders=loader, verbose=False)  # validation_step
        system.predict_poses(batch)  # eval.py's path
        assert seen[-2:] == [expected, expected]
    assert "preprocessing and averaging on the device" in system.configure_inference({"device_side": True})
    assert system.device_side is True
    with pytest.raises(ValueError, match="inference.device_side='yes'"):
        system.configure_inference({"device_side": "yes"})
    with pytest.raises(ValueError, match="inference.device_side=2"):
        system.configure_decoding(2)


def test_predict_image_gives_the_same_poses_either_way(pile: list) -> None:
    """predict.py's preprocessing, network and decoding: on the device (here the CPU) as on the host."""
    system = tiny_system(["parameterization=eve", "decoding=tuned", "data.fit=image", "presence_prior_logit=0.0"])
    results = []
    for side in (False, True):
        system.configure_inference({"device_side": side})
        results.append([predict_image(system, DepthImage(Path(f"{r.name}.png"), r.depth, r.camera)) for r in pile])
    assert_same_hypotheses(results[0], results[1], atol=1e-4)  # float32 inputs through a network
    assert sum(len(h) for h in results[0]) > 10


# ---- on a GPU ----------------------------------------------------------------------------------
@CUDA
def test_on_cuda_the_preprocessing_and_averaging_equal_the_host(pile: list) -> None:
    camera = pile[0].camera
    images, _ = preprocess_torch.to_network_input([r.depth for r in pile], camera, 128, "image", device="cuda")
    assert images.device.type == "cuda"
    for depth, image in zip([r.depth for r in pile], images, strict=True):
        np.testing.assert_allclose(image[0].cpu().numpy(), to_network_input(depth, camera, 128, fit="image")[0],
                                   atol=1e-5, rtol=0)
    param = _with_averaging(_parameterization("eve"), {"eps": 1.5, "cluster_score": "sum"})
    net_cam = network_camera(Camera.from_fov(50.0, 512, 512, 0.6, 1.2))
    out = noisy_outputs(param, net_cam, 6, seed=1)
    assert_same_hypotheses(param.decode(out, net_cam), param.decode(out.cuda(), net_cam, device_side=True))


# ---- the graphed pipeline: every shape fixed ---------------------------------------------------
DENSE_NAMES = [n for n in parameterization_names() if n != "z"]  # z (16 x 16 x 16 cells) below, with two settings


@pytest.mark.parametrize("averaging", AVERAGINGS, ids=["none", "tuned", "eps0.5", "min3-mean", "min2-noise"])
@pytest.mark.parametrize("name", DENSE_NAMES)
@pytest.mark.parametrize("obj", ["zbracket", "pin"])
def test_dense_decoding_equals_the_host_on_random_outputs(obj: str, name: str, averaging: bool | dict) -> None:
    """Every cell decoded and averaged with fixed shapes (what the CUDA graph runs) gives the host's
    hypotheses: the same clusters, order, poses and scores."""
    from opnet.parameterizations.dense_decoding import DenseDecoding

    param = _with_averaging(_parameterization(name, builtin_object(obj)), averaging)
    camera = network_camera(Camera.from_fov(50.0, 512, 512, 0.6, 1.2))
    out = noisy_outputs(param, camera, 4, seed=len(name))
    dense = DenseDecoding(param, camera, 4, "cpu")
    host = param.decode(out, camera)
    assert_same_hypotheses(host, dense.decode(out))
    assert len(host[1]) == 1 and len(host[2]) == 0
    assert bool(dense(out)[1].all())  # every clustering settled within the rounds: nothing fell back


@pytest.mark.parametrize("averaging", [AVERAGINGS[1], AVERAGINGS[3]], ids=["tuned", "min3-mean"])
def test_dense_decoding_of_z_equals_the_host(averaging: dict) -> None:
    from opnet.parameterizations.dense_decoding import DenseDecoding

    # 4 depth slabs, not 16: every pair of a grid's hypotheses is compared, 16 times fewer pairs on a CPU
    param = _with_averaging(_parameterization("z", depth_slabs=4), averaging)
    camera = network_camera(Camera.from_fov(50.0, 512, 512, 0.6, 1.2))
    out = noisy_outputs(param, camera, 3, seed=1)
    assert_same_hypotheses(param.decode(out, camera), DenseDecoding(param, camera, 3, "cpu").decode(out))


def test_a_clustering_that_has_not_settled_is_decoded_by_the_parameterization() -> None:
    """With too few propagation rounds an image's labels are flagged unsettled and the image is
    decoded the host's way: the hypotheses stay right; with the default rounds a chain of 60
    hypotheses, each within eps of the next only, settles."""
    from opnet.parameterizations.dense_decoding import DenseDecoding

    param = _with_averaging(_parameterization("eve"), {"eps": 1.5, "cluster_score": "sum"})
    camera = network_camera(Camera.from_fov(50.0, 512, 512, 0.6, 1.2))
    out = noisy_outputs(param, camera, 4, seed=2)
    dense = DenseDecoding(param, camera, 4, "cpu")
    dense.rounds = 0
    settled = dense(out)[1]
    assert not bool(settled[0]) and bool(settled[2])  # image 0 has clusters, image 2 no hypothesis
    assert_same_hypotheses(param.decode(out, camera), dense.decode(out))


@pytest.mark.parametrize("seed", range(6))
def test_component_roots_are_scipys_components(seed: int) -> None:
    """Fixed-shape connected components against scipy's, on random graphs, and on a path of 256
    nodes numbered at random (the slow case): one round does not settle it and says so, the default
    six do."""
    from scipy.sparse.csgraph import connected_components

    from opnet.parameterizations.dense_decoding import component_roots

    rng = np.random.default_rng(seed)
    n = 80
    adjacency = rng.random((n, n)) < rng.uniform(0.005, 0.05)
    adjacency = np.triu(adjacency, 1)
    adjacency = adjacency | adjacency.T
    core = rng.random(n) < 0.8
    adjacency &= core[:, None] & core[None, :]
    roots, settled = component_roots(torch.from_numpy(adjacency)[None], torch.from_numpy(core)[None])
    assert bool(settled[0])
    labels = connected_components(adjacency, directed=False)[1]
    expected = np.array([np.flatnonzero(labels == labels[i]).min() if core[i] else n for i in range(n)])
    np.testing.assert_array_equal(roots[0].numpy(), expected)
    order = rng.permutation(256)
    path = np.zeros((256, 256), bool)
    path[order[:-1], order[1:]] = path[order[1:], order[:-1]] = True
    for rounds, settles in ((1, False), (6, True)):
        roots, settled = component_roots(torch.from_numpy(path)[None], torch.ones(1, 256, dtype=torch.bool), rounds)
        assert bool(settled[0]) == settles
    assert set(roots[0].tolist()) == {0}


def test_the_graphed_pipeline_equals_predict_image(pile: list) -> None:
    """The whole pipeline with fixed shapes (here without a graph, on the CPU) gives predict.py's
    hypotheses; bad input is refused as predict.py refuses it."""
    from opnet.inference import GraphedPipeline, InferenceSettings

    system = tiny_system(["parameterization=eve", "decoding=tuned", "data.fit=image", "presence_prior_logit=0.0"])
    system.configure_inference({"device_side": False})
    camera = pile[0].camera
    pipeline = GraphedPipeline(system.backbone, InferenceSettings(), system.parameterization, camera, 128, "image")
    assert not pipeline.graph_wanted
    host = [predict_image(system, DepthImage(Path(f"{r.name}.png"), r.depth, r.camera)) for r in pile]
    assert_same_hypotheses(host, [pipeline(r.depth) for r in pile], atol=1e-4)
    assert sum(len(h) for h in host) > 10
    bad = pile[0].depth.copy()
    bad[3, 4] = np.inf
    with pytest.raises(ValueError, match="infinite"):
        pipeline(bad)
    with pytest.raises(ValueError, match="does not match the camera"):
        pipeline(bad[:-1])
    with pytest.raises(ValueError, match="float"):
        pipeline(np.zeros(bad.shape, np.int32))


@pytest.mark.parametrize("formulation", ["ours", "paper"])  # 6-D orientation; Euler angles
@pytest.mark.parametrize("name", ["vanilla", "eve", "si"])
def test_the_graphed_pipeline_reads_nothing_back_and_has_no_data_dependent_shape(name: str, formulation: str) -> None:
    """:func:`param_checks.assert_graph_capturable`: no shape depends on the data, nothing crosses
    between host and device once warm."""
    assert_graph_capturable(tiny_system([f"parameterization={name}", "decoding=tuned", f"formulation={formulation}"]))


@pytest.mark.slow
def test_the_compiled_pipeline_equals_the_plain_one(pile: list, monkeypatch: pytest.MonkeyPatch) -> None:
    """``inference.compile_pipeline``: the preprocessing and decoding compiled give the same hypotheses;
    a setting that is no boolean is refused naming the key. The whole-image pipeline runs on a GPU
    only: there Inductor generates the kernels; without one, Dynamo traces the same code and AOT
    Autograd decomposes it (``aot_eager``) but no C++ is generated for a CPU nobody runs it on (a
    minute of compiling, cold, on a 2-core CPU)."""
    from opnet.inference import GraphedPipeline, InferenceSettings

    if not torch.cuda.is_available():
        compile_ = torch.compile
        monkeypatch.setattr(torch, "compile", lambda fn, **kw: compile_(fn, backend="aot_eager", **kw))
    system = tiny_system(["parameterization=eve", "decoding=tuned", "data.fit=image", "presence_prior_logit=0.0"])
    camera = pile[0].camera
    plain = GraphedPipeline(system.backbone, InferenceSettings(), system.parameterization, camera, 128, "image")
    fused = GraphedPipeline(system.backbone, InferenceSettings(), system.parameterization, camera, 128, "image",
                            fuse=True)  # fmt: skip
    assert_same_hypotheses([plain(r.depth) for r in pile[:3]], [fused(r.depth) for r in pile[:3]], atol=1e-4)
    assert InferenceSettings.from_config({"compile_pipeline": True}).compile_pipeline is True
    with pytest.raises(ValueError, match="inference.compile_pipeline='yes'"):
        InferenceSettings.from_config({"compile_pipeline": "yes"})


def test_the_system_keeps_a_few_whole_image_graphs(monkeypatch: pytest.MonkeyPatch) -> None:
    """One pipeline per camera and framing, at most MAX_GRAPHED_CAMERAS (a region of interest per image
    makes a camera per image: further ones run the ordinary way instead of holding ever more GPU memory)."""
    from opnet.inference import InferenceSettings
    from opnet.estimator import MAX_GRAPHED_CAMERAS

    monkeypatch.setattr(InferenceSettings, "graphed", lambda self, device: True)  # as on a GPU
    system = tiny_system(["parameterization=eve", "decoding=tuned"])
    system.configure_inference({"device_side": True})
    cameras = [Camera.from_fov(50.0, 300 + k, 236, 0.6, 1.2) for k in range(MAX_GRAPHED_CAMERAS + 2)]
    made = [system.graphed_pipeline(c, 128, "pad") for c in cameras]
    assert all(m is not None for m in made[:MAX_GRAPHED_CAMERAS]) and made[MAX_GRAPHED_CAMERAS:] == [None, None]
    assert system.graphed_pipeline(cameras[0], 128, "pad") is made[0]  # kept


def test_the_system_graphs_whole_images_only_on_a_gpu() -> None:
    system = tiny_system(["parameterization=eve", "decoding=tuned"])
    camera = Camera.from_fov(50.0, 300, 236, 0.6, 1.2)
    assert system.graphed_pipeline(camera, 128, "pad") is None  # not configured
    system.configure_inference({"device_side": True, "cuda_graph": True})
    assert system.graphed_pipeline(camera, 128, "pad") is None  # the CPU: no graph
    if torch.cuda.is_available():
        system.cuda().configure_inference({"device_side": True})
        pipeline = system.graphed_pipeline(camera, 128, "pad")
        assert pipeline is not None and pipeline is system.graphed_pipeline(camera, 128, "pad")
        system.configure_inference({"device_side": False})
        assert system.graphed_pipeline(camera, 128, "pad") is None


@CUDA
@pytest.mark.parametrize("precision", ["32", "bf16"])
def test_on_cuda_the_graph_replays_the_pipeline(pile: list, precision: str) -> None:
    """The captured graph gives what the same pipeline gives without a graph, image after image."""
    from opnet.inference import GraphedPipeline, InferenceSettings

    system = tiny_system(["parameterization=eve", "decoding=tuned", "data.fit=image", "presence_prior_logit=0.0"]).cuda()
    settings = InferenceSettings(precision, True)
    camera = pile[0].camera
    graphed = GraphedPipeline(system.backbone, settings, system.parameterization, camera, 128, "image")
    eager = GraphedPipeline(system.backbone, settings, system.parameterization, camera, 128, "image", graph=False)
    assert graphed.graph_wanted
    for r in pile:
        assert_same_hypotheses([eager(r.depth)], [graphed(r.depth)], atol=1e-6)
    assert graphed._graph is not None
