"""Export a trained model to ONNX: the network and a dense decoder in one graph, plus metadata.

The graph takes ``depth`` (B, 1, S_in, S_in) float32, the normalized network input of
:func:`opnet.data.preprocess.to_network_input`, and ``camera`` (B, 8) float64, the network-input
camera ``fx fy cx cy width height clip_start clip_end``. It returns, for every cell and slot
(N = slots x S x S, the order of ``Parameterization.decode``): ``presence`` (B, N),
``visibility`` (B, N), ``translation`` (B, N, 3) metres in the camera frame and ``rotation``
(B, N, 3, 3), all float64: the parameterization's own decoding of every cell, traced from the
same code; a network with a quality channel also ``quality`` (B, N), q̂ of every cell, after them.
The network is traced in its fused inference arithmetic
(:func:`opnet.models.fused.export_form`: batch norms folded, transitions pooled first, the paper
network's 3x3 convolutions split 48 + 2; the same function, faster in ONNX Runtime too); the
export's self-check compares it with the network as trained. What stays outside the graph needs no PyTorch (:mod:`opnet.deploy.runtime`): the
preprocessing, the presence threshold, the score, and the pose averaging (DBSCAN).

The metadata (ONNX ``metadata_props``, key ``opnet``, JSON) holds what those steps need: input
size and framing, the decoding settings, the object's pose space for the averaging, the object
and parameterization names and the output layout; ``opnet_version`` and the source checkpoint;
``T_base_cam`` (the camera's pose in the robot's base frame) when the checkpoint records one.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch

from opnet import __version__
from opnet.fileio.atomic import temporary_beside, write_errors_named
from opnet.deploy.metadata import OUTPUTS, QUALITY_OUTPUT
from opnet.geometry.camera import CAMERA_FIELDS
from opnet.geometry.pose_numpy import PoseSpaceArrays
from opnet.models.fused import export_form
from opnet.parameterizations.base import Parameterization
from opnet.parameterizations.positions import CameraBatch

METADATA_KEY = "opnet"
FORMATS = ("onnx",)
#: the ONNX opset of the export (onnxruntime 1.32 runs up to 23)
OPSET = 17


def graph_outputs(param: Parameterization) -> tuple[str, ...]:
    """The names of the exported graph's outputs for ``param``: :data:`OUTPUTS`, and ``quality`` where it has one."""
    return (*OUTPUTS, QUALITY_OUTPUT) if param.has_quality else OUTPUTS


class DenseDecodingNetwork(torch.nn.Module):
    """The backbone followed by the decoding of every cell (the graph that is exported)."""

    def __init__(self, backbone: torch.nn.Module, parameterization: Parameterization) -> None:
        super().__init__()
        self.backbone = backbone
        self.param = parameterization
        L, S = parameterization.slots, parameterization.grid_size
        slot, row, col = torch.meshgrid(torch.arange(L), torch.arange(S), torch.arange(S), indexing="ij")
        self.register_buffer("slot", slot.reshape(-1), persistent=False)
        self.register_buffer("row", row.reshape(-1), persistent=False)
        self.register_buffer("col", col.reshape(-1), persistent=False)

    def forward(self, depth: torch.Tensor, camera: torch.Tensor) -> tuple[torch.Tensor, ...]:
        out = self.backbone(depth)
        B = out.shape[0]
        L, S, C = self.param.slots, self.param.grid_size, self.param.channels_per_slot
        N = L * S * S
        feat = out.reshape(B, L, C, S, S).permute(0, 1, 3, 4, 2).reshape(B * N, C).to(torch.float64)
        cams = CameraBatch(camera.to(torch.float64)[:, None, :].expand(B, N, 8).reshape(B * N, 8))
        cells = (self.slot.repeat(B), self.row.repeat(B), self.col.repeat(B))
        t, R = self.param.decode_poses(feat, cells, cams)
        lay = self.param.layout
        outs = (feat[:, lay.presence].reshape(B, N), feat[:, lay.visibility].reshape(B, N), t.reshape(B, N, 3),
                R.reshape(B, N, 3, 3))
        return (*outs, feat[:, lay.quality].reshape(B, N)) if lay.quality is not None else outs


def parameterization_name(param: Parameterization) -> str:
    """The config name of a parameterization (:attr:`Parameterization.name`: ``VanillaParameterization``
    -> ``vanilla``)."""
    return param.name


def export_metadata(system: Any, cfg: Any, ckpt: Path) -> dict[str, Any]:
    """Everything the torch-free runtime needs besides the graph: the system's settings
    (:attr:`~opnet.estimator.PoseEstimator.settings`: framing, training clip planes, decoding, written by
    their ``to_metadata``), its object's pose space and ICP points, the network's layout.

    Args:
        cfg: the run config; unused (the settings travel with the system), kept for the callers.
    """
    param: Parameterization = system.parameterization
    settings = system.settings
    framing = settings.input.to_metadata()
    return {
        "format": 1,
        "opnet_version": __version__,
        "checkpoint": str(ckpt),
        "object": param.obj.name,
        "parameterization": parameterization_name(param),
        "rotation": param.rotation.name,
        "grid_size": param.grid_size,
        "slots": param.slots,
        "slot_conditional": bool(param.slot_conditional),
        "channels_per_slot": param.channels_per_slot,
        "out_channels": param.out_channels,
        "input": {**framing["input"],
                  "layout": "NCHW float32, (z - clip_start) / (clip_end - clip_start), missing depth filled"},
        "camera_input": list(CAMERA_FIELDS),
        # the training scenes' clip planes: the runtime normalizes an input's depth with them
        "trained_clip": framing["trained_clip"],
        "outputs": list(graph_outputs(param)),
        **settings.decoding.to_metadata(),
        "pose_space": PoseSpaceArrays.of(param.obj.pose_space).to_dict(),
        "icp_model": icp_model_metadata(param.obj, settings.refine),
        # the refinement the model is meant to run with (train.py's deploy_refine), None: as decoded
        "refine": settings.refine,
        # the training camera's pose in the robot's base frame (its cell's T_base_cam), when recorded
        **settings.base_pose_entry(),
        # the training scenes' camera: the runtime's camera for an image given without one
        **settings.camera_entry(),
    }


def icp_model_metadata(obj: Any, refine: str | None = None) -> dict[str, Any] | None:
    """The points ICP fits (:class:`opnet.refine.ModelCloud`: as many as the recorded refinement ``refine`` takes,
    ``icp.model_points``; the default without one), so that the runtime refines without the mesh, and where that
    refinement ranks on points of its own (``search.rank_points``) those too (``rank_points``, ``rank_normals``);
    None for an object without a mesh."""
    from opnet.refine import ICPSettings, ModelCloud, rank_cloud
    from opnet.refine.settings import refine_config, settings_from_config

    if obj.mesh is None:
        return None
    settings = settings_from_config(refine_config(refine)) if refine else ICPSettings()
    cloud = ModelCloud.from_mesh(obj.mesh, settings.model_points, obj.diameter)
    out = {"points": cloud.points.tolist(), "normals": cloud.normals.tolist(), "diameter": cloud.diameter}
    rank = rank_cloud(obj.mesh, obj.diameter, settings)
    if rank is not None:
        out.update(rank_points=rank.points.tolist(), rank_normals=rank.normals.tolist())
    return out


def export_onnx(system: Any, cfg: Any, ckpt: Path, out: Path, opset: int = OPSET) -> dict[str, Any]:
    """Write ``out`` (.onnx, with metadata); returns the metadata."""
    import onnx

    meta = export_metadata(system, cfg, ckpt)
    size = meta["input"]["size"]
    names = list(graph_outputs(system.parameterization))
    model = DenseDecodingNetwork(export_form(system.backbone), system.parameterization).eval()
    depth = torch.rand(2, 1, size, size)
    cam = torch.tensor([[size * 1.2, size * 1.2, (size - 1) / 2, (size - 1) / 2, size, size, 0.5, 1.5]] * 2,
                       dtype=torch.float64)
    with write_errors_named(out):  # a read-only folder or a full disk: one line naming out
        fd, tmp = temporary_beside(out)
    os.close(fd)  # the exporters write by name
    try:  # a failure (a full disk) leaves neither the temporary file nor a partial out
        with write_errors_named(out):
            with torch.no_grad(), warnings.catch_warnings():
                warnings.simplefilter("ignore", torch.jit.TracerWarning)  # the backbone's shape checks become constants
                torch.onnx.export(model, (depth, cam), str(tmp), input_names=["depth", "camera"],
                                  output_names=names, opset_version=opset, dynamo=False,
                                  dynamic_axes={"depth": {0: "batch"}, "camera": {0: "batch"},
                                                **{k: {0: "batch"} for k in names}})
            proto = onnx.load(str(tmp))
            entry = proto.metadata_props.add()
            entry.key, entry.value = METADATA_KEY, json.dumps(meta)
            proto.producer_name, proto.producer_version = "opnet", __version__
            onnx.checker.check_model(proto)
            onnx.save(proto, str(tmp))
            tmp.replace(out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return meta


def reference_outputs(system: Any, depth: np.ndarray, camera: np.ndarray) -> tuple[np.ndarray, ...]:
    """The dense outputs of the PyTorch model as trained (for the export's self-check)."""
    model = DenseDecodingNetwork(system.backbone, system.parameterization).eval()
    with torch.no_grad():
        return tuple(x.numpy() for x in model(torch.from_numpy(depth), torch.from_numpy(camera)))


def max_abs_difference(a: tuple[np.ndarray, ...], b: tuple[np.ndarray, ...]) -> dict[str, float]:
    names = (*OUTPUTS, QUALITY_OUTPUT)[: len(a)]
    return {name: float(np.max(np.abs(x - y))) if x.size else 0.0 for name, x, y in zip(names, a, b, strict=True)}

