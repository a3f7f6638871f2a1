"""Checks every parameterization passes, shared by the tests of the configured ones and by the test
of a parameterization added from outside the package (tests/integration/test_seventh_parameterization.py).

The configured parameterizations are the YAML files of ``conf/parameterization/``: a test that
covers them all lists them with :func:`parameterization_names`, so a new one is tested by adding it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import pytest
import torch
from hydra import compose, initialize_config_dir

from opnet.analysis.toy_scenes import random_scene_batch
from opnet.cli.build import build_components
from opnet.geometry import Camera
from opnet.metrics.records import HypothesisSet
from opnet.parameterizations import GroundTruthBatch, Parameterization
from opnet.paths import config_dir


def parameterization_names(conf: Path | None = None) -> list[str]:
    """The parameterizations configured in ``<conf>/parameterization/*.yaml`` (the repository's conf/
    by default), sorted."""
    return sorted(p.stem for p in ((conf or config_dir()) / "parameterization").glob("*.yaml"))


# ---- the encode / decode contract ---------------------------------------------------------------
def pose_errors(param: Parameterization, R_gt: np.ndarray, t_gt: np.ndarray, R_hat: np.ndarray,
                t_hat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """Translation (m) and rotation (rad, up to symmetry; axis angle for revolution objects) errors.

    Angles from chord lengths (2 asin(chord / 2)), which stay accurate near zero, unlike acos.
    """
    space = param.obj.pose_space
    R_eq = space.closest_equivalent(torch.from_numpy(R_hat), torch.from_numpy(R_gt)).numpy()
    if space.revolution:
        chord = np.linalg.norm(R_eq[:, :, 2] - R_hat[:, :, 2], axis=-1)
    else:
        chord = np.linalg.norm(R_eq - R_hat, axis=(1, 2)) / np.sqrt(2)
    return np.linalg.norm(t_hat - t_gt, axis=1), 2 * np.arcsin(np.clip(chord / 2, 0, 1))


def assert_round_trip(param: Parameterization, gt: GroundTruthBatch, camera: Camera) -> None:
    """The contract: the target of ``gt`` lies in [0, 1], holds most instances, and decodes to one
    hypothesis per instance it holds, at that instance's pose, score 1 and visibility."""
    B = gt.batch_size
    target = param.encode(gt, camera)
    assert target.shape == (B, param.out_channels, param.grid_size, param.grid_size)
    assert target.dtype == torch.float32 and target.min() >= 0 and target.max() <= 1
    assigned = param.assigned(gt, camera)
    assert 0.5 * len(gt) < int(assigned.sum()) <= len(gt)
    hyps = param.decode(target, camera)
    assert len(hyps) == B
    for b, h in enumerate(hyps):
        sel = ((gt.batch_index == b) & assigned).numpy()
        R_gt, t_gt = gt.R_cam_obj.double().numpy()[sel], gt.t_cam_obj.double().numpy()[sel]
        assert len(h) == len(t_gt), "one hypothesis per represented instance"
        nearest = np.linalg.norm(t_gt[:, None] - h.t[None], axis=-1).argmin(1)
        assert len(set(nearest.tolist())) == len(t_gt)
        dt, dr = pose_errors(param, R_gt, t_gt, h.R[nearest], h.t[nearest])
        assert dt.max() < 1e-4 and dr.max() < 1e-4
        np.testing.assert_allclose(h.score, 1.0)
        np.testing.assert_allclose(h.visibility[nearest], gt.visibility.numpy()[sel], atol=1e-6)


# ---- decoding on the device, with fixed shapes --------------------------------------------------
def assert_same_hypotheses(host: list[HypothesisSet], device: list[HypothesisSet], atol: float = 1e-9) -> None:
    assert [len(h) for h in device] == [len(h) for h in host]
    for a, b in zip(host, device, strict=True):
        np.testing.assert_allclose(b.R, a.R, atol=atol, rtol=0)
        np.testing.assert_allclose(b.t, a.t, atol=atol, rtol=0)
        np.testing.assert_allclose(b.score, a.score, atol=atol, rtol=0)
        assert (a.visibility is None) == (b.visibility is None)
        if a.visibility is not None:
            np.testing.assert_allclose(b.visibility, a.visibility, atol=atol, rtol=0)


def noisy_outputs(param: Parameterization, camera: Camera, batch: int, seed: int) -> torch.Tensor:
    """Encoded random piles with noise and low-confidence cells above the threshold; image 1 holds
    one hypothesis, image 2 none (the averaging's special cases)."""
    gen = torch.Generator().manual_seed(seed)
    perfect = param.encode(random_scene_batch(param.obj, camera, batch, (5, 30), gen), camera)
    out = (perfect + 0.02 * torch.rand(perfect.shape, generator=gen)).clamp(0, 1)
    presence = param.split_slots(out)[:, :, param.layout.presence]  # a view: writes reach out
    presence[torch.rand(presence.shape, generator=gen) < 0.1] = 0.3
    presence[1:3] = 0.0
    presence[1, 0, 5, 7] = 0.9
    return out


class HostTraffic(torch.overrides.TorchFunctionMode):
    """Records what a CUDA-graph capture cannot hold: data copied between the host and the device
    (new tensors from host data, ``.to`` / ``copy_`` across devices, values read back)."""

    READ_BACK = frozenset((torch.Tensor.cpu, torch.Tensor.item, torch.Tensor.tolist, torch.Tensor.numpy,
                           torch.Tensor.__bool__))

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[str] = []

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        result = func(*args, **kwargs)
        if func in (torch.tensor, torch.from_numpy) or (func in (torch.as_tensor, torch.asarray)
                                                         and not isinstance(args[0], torch.Tensor)):
            self.seen.append(f"{func.__name__} of host data")
        elif func in self.READ_BACK:
            self.seen.append(f"Tensor.{func.__name__}")
        elif func is torch.Tensor.to and isinstance(result, torch.Tensor) and result.device != args[0].device:
            self.seen.append(f"Tensor.to from {args[0].device} to {result.device}")
        elif func is torch.Tensor.copy_ and args[1].device != args[0].device:
            self.seen.append(f"Tensor.copy_ from {args[1].device} to {args[0].device}")
        return result


def assert_graph_capturable(system: L.LightningModule) -> None:
    """What a CUDA graph captures, checked without one: on the meta device (which holds shapes,
    no values) the preprocessing and the decoding run, so no shape depends on the data (``nonzero``
    and reading a value fail there), and once warm they copy nothing between host and device. (The
    network is a stand-in of the output's shape: its head turns autocast off, which the meta device
    does not know; its forward alone has been replayed as a CUDA graph since it was written.)"""
    from opnet.inference import GraphedPipeline, InferenceSettings
    from opnet.parameterizations.dense_decoding import WIDTH

    param = system.parameterization
    camera = Camera.from_fov(50.0, 300, 236, 0.6, 1.2)
    pipeline = GraphedPipeline(system.backbone, InferenceSettings(), param, camera, 128)
    pipeline.decoding = type(pipeline.decoding)(param, pipeline.net_camera, 1, "meta")
    shape = (param.out_channels, param.grid_size, param.grid_size)
    pipeline.forward = lambda x: torch.nn.functional.interpolate(x, size=shape[1:]).expand(-1, shape[0], -1, -1)
    depth = torch.empty(1, 236, 300, device="meta")
    pipeline.compute(depth)  # warm: the resize tables and the group's tensors are made on the device
    with HostTraffic() as traffic:
        result, output = pipeline.compute(depth)
    assert traffic.seen == []
    assert result.device.type == "meta" and result.shape == (pipeline.decoding.cells * WIDTH + 3,)
    # the controls: the host's decoding and the torch averaging read values back
    with pytest.raises(NotImplementedError), HostTraffic():
        param.decode(output, [pipeline.net_camera])
    with HostTraffic() as traffic:
        param.decode(torch.rand(1, *shape), [pipeline.net_camera])
    assert traffic.seen


# ---- systems: built from a train config, exported ------------------------------------------------
def tiny_system(overrides: list[str]) -> L.LightningModule:
    """A train config's system (tiny network, random weights with non-trivial batch norm statistics)."""
    with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
        cfg = compose(config_name="train", overrides=["model=tiny", "object=zbracket", *overrides])
    torch.manual_seed(0)
    system = build_components(cfg).system
    for m in system.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-0.2, 0.2)
            m.running_var.uniform_(0.5, 1.5)
    return system.eval()


def assert_export_matches(system: L.LightningModule, cfg: Any, out: Path) -> dict[str, Any]:
    """Export ``system`` to ``out`` (ONNX): ONNX Runtime's dense outputs equal PyTorch's, and are the
    parameterization's own decoding of every cell; returns the metadata."""
    from opnet.cli import export as export_cli
    from opnet.deploy.export import export_onnx, max_abs_difference, reference_outputs
    from opnet.deploy.runtime import OnnxPoseEstimator

    meta = export_onnx(system, cfg, Path("none.ckpt"), out)
    est = OnnxPoseEstimator(out)
    images, cams = export_cli.synthetic_inputs(meta["input"]["size"], n=3)
    dense = est.run(images, cams)
    diff = max_abs_difference(dense, reference_outputs(system, images, cams))
    assert diff["presence"] < 1e-5 and diff["visibility"] < 1e-5, diff
    assert diff["translation"] < 1e-5, diff  # metres
    param = system.parameterization.with_decoding(threshold=0.0, min_visibility=0.0, score="p")
    with torch.no_grad():
        output = system(torch.from_numpy(images))
    cameras = [Camera(*c[:4], int(c[4]), int(c[5]), *c[6:]) for c in cams]
    _, R, t, p_hat, _ = param.decode_cells(output, cameras)  # every cell: a sigmoid's presence exceeds 0
    for ours, graph, atol in ((p_hat, dense[0], 1e-5), (t, dense[2], 1e-5), (R, dense[3], 1e-4)):  # R: ONNX Runtime's arithmetic
        np.testing.assert_allclose(graph.reshape(ours.shape), ours.numpy(), atol=atol, rtol=0)
    return meta
