"""The protocol every output parameterization implements (docs/method.md#the-six-parameterizations).

A parameterization owns both directions: :meth:`Parameterization.encode` turns ground truth into
the network's target tensor and :meth:`Parameterization.decode` turns a network output back into
pose hypotheses. The contract: decoding a perfect output (the target itself) recovers every
instance the parameterization represents (:meth:`Parameterization.assigned`) up to symmetry.

Channel layout (slot-major): ``channel = slot * channels_per_slot + c`` with c indexing
``[p, v, x, y, z, φ1, φ2, (φ3)]``; slots are the depth slabs of Z, the pose slots of MP, else one.
:class:`ChannelLayout` (``Parameterization.layout``) says where each quantity lies: code that
reads or writes a channel goes through it, never through a literal index.

A new parameterization subclasses :class:`Parameterization` and implements two hooks,
:meth:`Parameterization.candidates` (which cells an instance fills, with which position channels)
and :meth:`Parameterization.decode_position` (those position channels back to pixels and depth;
the mixins of :mod:`opnet.parameterizations.positions` implement it for the two usual encodings).
Optional overrides: :meth:`Parameterization.presence_mask`, :meth:`Parameterization.presence_weight`,
``pose_weighting``, ``needs_segmentation``. docs/extending.md walks through it.
"""

from __future__ import annotations

import abc
import copy
import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch

from opnet.geometry.camera import Camera
from opnet.metrics.records import HypothesisSet
from opnet.objects.model import ObjectModel
from opnet.parameterizations.assignment import Candidates, resolve
from opnet.parameterizations.averaging import PoseAveraging
from opnet.parameterizations.averaging_torch import average_batch
from opnet.parameterizations.batch import POSE_CHANNEL_NAMES, QUALITY_CHANNEL_NAME, ChannelLayout, GroundTruthBatch
from opnet.parameterizations.euler_codec import EulerCodec
from opnet.parameterizations.rotation import RotationCodec
from opnet.parameterizations.turns import quarters, turned_back, turned_camera
from opnet.parameterizations.positions import (
    CameraBatch,
    CellIndex,
    DecodedPosition,
    ObjectProjection,
    project_origins,
)
from opnet.settings_schema import (
    DECODING_SCALARS,
    OVERRIDE,
    QUALITY_SCORES,
    TRAINING,
    SettingError,
    check_settings,
    hypothesis_score,
    read_settings,
)

POSE_WEIGHTINGS = ("cubic", "linear")
class Parameterization(abc.ABC):
    """Encode ground truth into OP-Net's output grid and decode network outputs into poses.

    Args:
        obj: the object model (symmetry, diameter, pose space).
        grid: output grid size S (the network outputs (B, out_channels, S, S)).
        rotation: the orientation channels (conf/rotation/); None: the paper's Euler angles in
            the convention ``euler``.
        euler: Euler convention of the orientation channels when ``rotation`` is None
            (docs/method.md#orientation).
        threshold: presence threshold τ of a hypothesis (docs/method.md#decoding).
        score: hypothesis score: "p" (p̂), "p*v" (p̂ v̂) or "v" (v̂); with ``quality`` also "p*q" and "p*v*q".
        averaging: cluster and average the hypotheses of each image (docs/method.md#decoding).
        averaging_eps: DBSCAN radius as a fraction of δ.
        averaging_min_samples: DBSCAN core-point threshold.
        averaging_score: cluster score, "max", "sum" or "mean".
        slots: slots per cell (Z: depth slabs, MP: poses per cell).
        min_target_visibility: parts less visible than this are not assigned to any cell (their
            cells are trained as empty: a part hidden that deeply cannot be seen in the depth
            image); 0 = every part, the paper's encoding.
        min_visibility: decode only cells whose predicted visibility is at least this (0: all, the
            paper); instances more than half occluded need not be found (the metric ignores them)
            but their poses are the least trained, so gating them removes false positives.
        turns: the input's quarter turns the decoding pools (1, 2 or 4; docs/method.md#decoding).
        quality: one more channel per slot, q, trained to estimate how right the slot's orientation is
            (:func:`opnet.losses.quality_target`), for the scores "p*q" and "p*v*q"
            (docs/method.md#orientation-quality); False: the paper's channels.

    Attributes:
        grid_size, slots, channels_per_slot (8, or 7 for revolution objects), out_channels,
        layout (:class:`ChannelLayout` of one slot), pose_weighting ("cubic": λ3 = 8 v³, "linear":
        λ3 = v), needs_segmentation, slot_conditional (slot l + 1 is read only where slots 1..l are
        present, as MP's are; the ONNX export records it for the runtime), rotation (the orientation codec).

    A subclass implements :meth:`candidates` and :meth:`decode_position` (module docstring).
    """

    pose_weighting: str = "cubic"
    needs_segmentation: bool = False  # encode needs GroundTruthBatch.segmentation
    slot_conditional: bool = False  # slot l + 1 decoded only where slots 1..l are present (presence_mask)

    def __init__(
        self,
        obj: ObjectModel,
        grid: int,
        rotation: RotationCodec | None = None,
        euler: str = "ZYZ",
        threshold: float = 0.1,
        score: str = "p",
        averaging: bool = False,
        averaging_eps: float = 0.5,
        averaging_min_samples: int = 1,
        averaging_score: str = "max",
        slots: int = 1,
        min_visibility: float = 0.0,
        min_target_visibility: float = 0.0,
        turns: int = 1,
        quality: bool = False,
    ) -> None:
        check_settings({"grid": grid, "slots": slots, "threshold": threshold, "min_visibility": min_visibility,
                        "turns": turns, "quality": quality,
                        "score": score, "averaging": averaging, "averaging.eps": averaging_eps,
                        "averaging.min_samples": averaging_min_samples, "averaging.cluster_score": averaging_score,
                        "min_target_visibility": min_target_visibility}, TRAINING)  # fmt: skip
        assert self.pose_weighting in POSE_WEIGHTINGS
        self.obj = obj
        self.grid_size = int(grid)
        self.slots = int(slots)
        self.threshold = float(threshold)
        self.score = score
        self.min_visibility = float(min_visibility)
        self.turns = int(turns)
        self.min_target_visibility = float(min_target_visibility)
        self.rotation = rotation if rotation is not None else EulerCodec(obj.symmetry, euler)
        if self.rotation.revolution != obj.symmetry.is_revolution:
            raise ValueError(
                f"rotation codec {self.rotation.name!r} was built for another symmetry than "
                f"object {obj.name!r}'s ({obj.symmetry.kind})"
            )
        # a subclass may replace it after this __init__ with another order of the same channels
        self.layout = ChannelLayout.for_rotation(self.rotation.num_channels, bool(quality))
        self._check_score(self.score, "parameterization.score")
        self.averaging = (
            PoseAveraging(obj.pose_space, averaging_eps, averaging_min_samples, averaging_score)
            if averaging
            else None
        )

    # ---- layout ------------------------------------------------------------------------------
    @property
    def channels_per_slot(self) -> int:
        return self.layout.channels

    @property
    def out_channels(self) -> int:
        return self.slots * self.channels_per_slot

    def channel_layout(self) -> list[str]:
        """Name of every output channel, e.g. "p", "phi2" (one slot) or "p[1]" (several slots)."""
        lay, names = self.layout, [""] * self.layout.channels
        names[lay.presence], names[lay.visibility] = POSE_CHANNEL_NAMES[:2]
        names[lay.position], names[lay.rotation] = POSE_CHANNEL_NAMES[2:], self.rotation.channel_names
        if lay.quality is not None:
            names[lay.quality] = QUALITY_CHANNEL_NAME
        if self.slots == 1:
            return list(names)
        return [f"{name}[{slot}]" for slot in range(self.slots) for name in names]

    @property
    def name(self) -> str:
        """The config name: ``conf/parameterization/<name>.yaml`` of class ``<Name>Parameterization``
        (``VanillaParameterization`` -> ``vanilla``); recorded in exports."""
        return type(self).__name__.removesuffix("Parameterization").lower()

    def presence_channels(self) -> list[int]:
        """The flat output channel of each slot's presence (slot-major)."""
        return [slot * self.channels_per_slot + self.layout.presence for slot in range(self.slots)]

    def split_slots(self, tensor: torch.Tensor) -> torch.Tensor:
        """(B, out_channels, S, S) -> (B, slots, channels_per_slot, S, S) view."""
        B = tensor.shape[0]
        if tuple(tensor.shape[1:]) != (self.out_channels, self.grid_size, self.grid_size):
            raise ValueError(
                f"{type(self).__name__}: expected a tensor of shape "
                f"(B, {self.out_channels}, {self.grid_size}, "
                f"{self.grid_size}), got {tuple(tensor.shape)}"
            )
        return tensor.reshape(B, self.slots, self.channels_per_slot, self.grid_size, self.grid_size)

    # ---- encoding ----------------------------------------------------------------------------
    def encode(self, gt: GroundTruthBatch, camera: Camera | Sequence[Camera]) -> torch.Tensor:
        """Target tensor of a batch.

        Args:
            gt: ground truth, camera frame, metres.
            camera: the network-input camera (one for all images, or one per image).
        Returns:
            (B, out_channels, S, S) float32 in [0, 1]; cells without an object are all zero.
        """
        winners = self._assign(gt, camera)
        S, L, C, lay = self.grid_size, self.slots, self.channels_per_slot, self.layout
        values = torch.zeros(len(winners.index), C, dtype=torch.float64, device=gt.t_cam_obj.device)
        values[:, lay.presence] = 1.0
        values[:, lay.visibility] = gt.visibility[winners.index].double()
        values[:, lay.position] = winners.position
        values[:, lay.rotation] = self.rotation.encode(gt.R_cam_obj[winners.index])
        if lay.quality is not None:  # what a cell that writes exactly this orientation should say of it (q* = 1);
            values[:, lay.quality] = 1.0  # the loss computes each prediction's own target (losses.quality_target)
        target = torch.zeros(
            gt.batch_size * L * S * S, C, dtype=torch.float32, device=gt.t_cam_obj.device
        )
        target[winners.cell] = values.float()
        return (
            target.reshape(gt.batch_size, L, S, S, C)
            .permute(0, 1, 4, 2, 3)
            .reshape(gt.batch_size, L * C, S, S)
        )

    def assigned(self, gt: GroundTruthBatch, camera: Camera | Sequence[Camera]) -> torch.Tensor:
        """(M,) bool: the instances that appear in the target (the others cannot be predicted)."""
        mask = torch.zeros(len(gt), dtype=torch.bool, device=gt.t_cam_obj.device)
        mask[self._assign(gt, camera).index] = True
        return mask

    def target_cells(
        self, gt: GroundTruthBatch, camera: Camera | Sequence[Camera]
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Which cell of the target holds which instance, and from which source (diagnostics).

        Returns:
            index (W,) long instance, cell (W,) long flat index into the (B, slots, S, S) grid, and
            origin (W,) bool: the cell is the one of the instance's projected origin (vanilla's
            cell); False for an EVE extension, an AP additional point's cell, an SI mask cell.
        """
        winners = self._assign(gt, camera)
        cams = CameraBatch.of(camera, gt.batch_size, gt.t_cam_obj.device)
        origin = project_origins(gt.t_cam_obj, gt.batch_index, cams).cells(self.grid_size)
        S = self.grid_size
        row, col = (winners.cell // S) % S, winners.cell % S
        is_origin = (row == origin.row[winners.index]) & (col == origin.col[winners.index])
        return winners.index, winners.cell, is_origin

    def _assign(self, gt: GroundTruthBatch, camera: Camera | Sequence[Camera]) -> Candidates:
        cams = CameraBatch.of(camera, gt.batch_size, gt.t_cam_obj.device)
        proj = project_origins(gt.t_cam_obj, gt.batch_index, cams)
        candidates = self.candidates(gt, proj)
        if self.min_target_visibility > 0:  # parts hidden this deeply are no target: nothing shows them
            candidates = candidates.select(gt.visibility[candidates.index] >= self.min_target_visibility)
        return resolve(candidates)

    @abc.abstractmethod
    def candidates(self, gt: GroundTruthBatch, proj: ObjectProjection) -> Candidates:
        """The (instance, cell) pairs this variant would fill (hook of every parameterization).

        Args:
            gt: the batch's ground truth (M instances).
            proj: their origins projected by their image's camera (:func:`project_origins`).
        Returns:
            ``Candidates(index, cell, priority, position)``: for each of K proposals the instance
            (K,) long, its flat cell in the (B, slots, S, S) grid (:func:`~opnet.parameterizations.assignment.flat_cell`),
            a priority (K,) float64 (the highest wins a cell contested by several instances;
            :data:`~opnet.parameterizations.assignment.ORIGIN_PRIORITY` marks an origin cell)
            and the (K, 3) float64 position channels in [0, 1] that :meth:`decode_position` reads back.
        """

    # ---- decoding ----------------------------------------------------------------------------
    def decode(
        self, output: torch.Tensor, camera: Camera | Sequence[Camera], device_side: bool = False,
        turned: Sequence[tuple[int, torch.Tensor]] | None = None,
    ) -> list[HypothesisSet]:
        """Pose hypotheses of every image.

        Args:
            output: (B, out_channels, S, S) network output in [0, 1].
            camera: the network-input camera (one for all images, or one per image).
            device_side: average on the output's device, every image at once
                (:mod:`opnet.parameterizations.averaging_torch`), and bring the result to the host
                in one transfer; False: each image's hypotheses averaged on the host in numpy. The
                same hypotheses either way (to float rounding).
            turned: with ``turns`` 2 or 4, the network's outputs of the same images turned by each other
                quarter turn of :func:`~opnet.parameterizations.turns.quarters` as ``(q, output)`` pairs
                (:meth:`opnet.estimator.PoseEstimator.decode` makes them): their hypotheses, turned back,
                are pooled with the image's before the averaging.
        Returns:
            B hypothesis sets, camera frame, metres (averaged per image when ``averaging`` is set).

        Raises:
            ValueError: ``turns`` above 1 without the outputs of exactly its other turns.
        """
        b, R, t, score, v_hat = self.decode_cells(output, camera)
        B = output.shape[0]
        if self.turns > 1 or turned:
            b, R, t, score, v_hat = self._pool_turns((b, R, t, score, v_hat), camera, B, turned or ())
        if B == 0:
            return []
        if device_side:
            return self._decode_on_device(b, R, t, score, v_hat, B)
        splits = np.cumsum(torch.bincount(b, minlength=B).tolist())[:-1]
        per_image = zip(
            *(np.split(x.cpu().numpy(), splits) for x in (R, t, score, v_hat)), strict=True
        )
        hyps = [HypothesisSet(*arrays) for arrays in per_image]
        return [self.averaging(h) for h in hyps] if self.averaging is not None else hyps

    def _pool_turns(self, cells: tuple[torch.Tensor, ...], camera: Camera | Sequence[Camera], B: int,
                    turned: Sequence[tuple[int, torch.Tensor]]) -> tuple[torch.Tensor, ...]:  # fmt: skip
        """:meth:`decode_cells` of the image and of each turned output, turned back, ordered by image."""
        wanted = quarters(self.turns)[1:]
        if sorted(q for q, _ in turned) != list(wanted):
            raise ValueError(f"decoding.turns={self.turns} pools the outputs of the input turned by {list(wanted)} "
                             f"quarter turns; given {sorted(q for q, _ in turned)}")  # fmt: skip
        cams = list(camera) if isinstance(camera, Sequence) else [camera] * B
        parts = [cells]
        for q, out in turned:
            b, R, t, score, v_hat = self.decode_cells(out, [turned_camera(c, q) for c in cams])
            R, t = turned_back(R, t, q)
            parts.append((b, R, t, score, v_hat))
        pooled = [torch.cat(x) for x in zip(*parts, strict=True)]
        order = torch.argsort(pooled[0], stable=True)
        return tuple(x[order] for x in pooled)

    def decode_cells(
        self, output: torch.Tensor, camera: Camera | Sequence[Camera]
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """The hypothesis of every cell (slot) above the threshold, on the output's device: image
        index (N,) long (sorted), R (N, 3, 3), t (N, 3) metres, score (N,), visibility (N,) float64."""
        grid5 = self.split_slots(output.detach())  # (B, L, C, S, S)
        B = grid5.shape[0]
        b, slot, row, col = self.cells_to_decode(grid5).nonzero(as_tuple=True)
        feat = grid5.permute(0, 1, 3, 4, 2)[b, slot, row, col].to(torch.float64)  # (N, C)
        cams = CameraBatch.of(camera, B, output.device).take(b)
        t, R = self.decode_poses(feat, (slot, row, col), cams)
        score, v_hat = self.hypothesis_scores(feat)
        return b, R, t, score, v_hat

    def cells_to_decode(self, grid5: torch.Tensor) -> torch.Tensor:
        """(B, slots, C, S, S) output -> (B, slots, S, S) bool: :meth:`presence_mask`, and the
        predicted visibility at least ``min_visibility``."""
        present = self.presence_mask(grid5[:, :, self.layout.presence])
        if self.min_visibility > 0:  # heavily occluded parts need not be found and are poorly posed
            present = present & (grid5[:, :, self.layout.visibility] >= self.min_visibility)
        return present

    def decode_poses(
        self, feat: torch.Tensor, cells: CellIndex, cams: CameraBatch
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The poses of feature vectors (N, C) float64 of cells (slot, row, col) seen by ``cams``:
        t (N, 3) metres, camera frame, and R (N, 3, 3)."""
        t = self.decode_translations(feat[:, self.layout.position], cells, cams)
        return t, self.rotation.decode(feat[:, self.layout.rotation])

    @property
    def has_quality(self) -> bool:
        """The network writes a quality channel q (``parameterization.quality``; the scores ``p*q``, ``p*v*q``)."""
        return self.layout.quality is not None

    def _check_score(self, score: str, key: str) -> None:
        if score in QUALITY_SCORES and not self.has_quality:
            raise SettingError(key, score, "reads the quality channel q, and this network has none (it was trained "
                               "without parameterization.quality=true): use p, p*v or v")

    def hypothesis_scores(self, feat: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Score (N,) (``score``: p̂, p̂ v̂, v̂, p̂ q̂ or p̂ v̂ q̂) and predicted visibility (N,) of feature vectors (N, C)."""
        p_hat, v_hat = feat[:, self.layout.presence], feat[:, self.layout.visibility]
        q_hat = feat[:, self.layout.quality] if self.has_quality else None
        return hypothesis_score(self.score, p_hat, v_hat, q_hat), v_hat

    def _decode_on_device(self, b: torch.Tensor, R: torch.Tensor, t: torch.Tensor, score: torch.Tensor,
                          v_hat: torch.Tensor, B: int) -> list[HypothesisSet]:  # fmt: skip
        """:meth:`decode` with ``device_side``: averaged on the device, one transfer to the host."""
        found = torch.bincount(b, minlength=B)
        if self.averaging is not None:
            b, R, t, score, v_hat = average_batch(self.averaging, b, R, t, score, v_hat, B)
        packed = torch.cat((R.reshape(-1, 9), t, score[:, None], v_hat[:, None]), 1)
        counts = torch.bincount(b, minlength=B)
        host = torch.cat((packed.reshape(-1), counts.to(packed.dtype), found.to(packed.dtype))).cpu().numpy()
        rows = host[: packed.numel()].reshape(-1, 14)
        counts, found = host[packed.numel() :].astype(np.int64).reshape(2, B)
        hyps = []
        for k, part in enumerate(np.split(rows, np.cumsum(counts)[:-1])):
            if self.averaging is not None and found[k] > 1 and not len(part):
                hyps.append(HypothesisSet.empty())  # every hypothesis noise, as the numpy averaging returns it
            else:
                hyps.append(HypothesisSet(part[:, :9], part[:, 9:12], part[:, 12], part[:, 13]))
        return hyps

    def with_decoding(self, **settings: Any) -> Parameterization:
        """A copy with other decoding settings (the encoding is unchanged), for tuning on data.

        Keys: ``threshold``, ``score``, ``min_visibility``, ``turns``, and ``averaging`` (False, or a dict of
        ``eps``, ``min_samples``, ``cluster_score``, overriding the current ones), checked by the schema
        (:mod:`opnet.settings_schema`): a bad or unknown one raises a ``SettingError`` naming ``decoding.<key>``.
        """
        given = read_settings({"decoding": settings}, OVERRIDE, closed=("decoding", "decoding.averaging"))
        if "score" in given:
            self._check_score(given["score"], "decoding.score")
        new = copy.copy(self)
        for key in DECODING_SCALARS:
            if key in given:
                setattr(new, key, given[key])
        if given.get("averaging") is False:
            new.averaging = None
        elif given.get("averaging"):
            changes = {name.split(".")[1]: value for name, value in given.items() if name.startswith("averaging.")}
            new.averaging = dataclasses.replace(self.averaging or PoseAveraging(self.obj.pose_space), **changes)
        return new

    def presence_mask(self, presence: torch.Tensor) -> torch.Tensor:
        """(B, slots, S, S) presence channel -> bool mask of the cells/slots to decode: above the threshold
        and, with :attr:`slot_conditional`, only where every slot before is too."""
        present = presence > self.threshold
        if self.slot_conditional:
            return torch.cummin(present.to(torch.uint8), dim=1).values.bool()
        return present

    def decode_translations(
        self, position: torch.Tensor, cells: CellIndex, cams: CameraBatch
    ) -> torch.Tensor:
        """Object origins from the position channels of some cells (differentiable, for the loss).

        Args:
            position: (N, 3) the x, y, z channels of the cells.
            cells: (slot, row, col) of each, (N,) long.
            cams: the camera of each (N rows).
        Returns:
            (N, 3) float64 metres, camera frame.
        """
        u, v, z_norm = self.decode_position(position, cells, cams)
        return cams.backproject(u, v, cams.denormalize_depth(z_norm))

    @abc.abstractmethod
    def decode_position(
        self, position: torch.Tensor, cells: CellIndex, cams: CameraBatch
    ) -> DecodedPosition:
        """Position channels (N, 3) of cells (slot, row, col) -> u, v (N,) pixels, normalized
        depth (N,) (hook of every parameterization: the inverse of the positions :meth:`candidates`
        writes; differentiable, the loss and the exported graph run it; inherit it from
        :class:`~opnet.parameterizations.positions.CellRelativePosition` or
        :class:`~opnet.parameterizations.positions.MultiCellPosition` where one fits)."""

    def decode_rotations(self, output: torch.Tensor) -> torch.Tensor:
        """Per-cell rotations decoded from the angle channels (differentiable, for the loss).

        Args:
            output: (B, out_channels, S, S).
        Returns:
            (B, slots, S, S, 3, 3) rotations, camera frame (spin-free for revolution objects).
        """
        angles = self.split_slots(output)[:, :, self.layout.rotation].permute(0, 1, 3, 4, 2)  # (B, L, S, S, A)
        return self.rotation.decode(angles)

    # ---- loss weights ------------------------------------------------------------------------
    def pose_weight(self, visibility: torch.Tensor) -> torch.Tensor:
        """λ3 of the loss from the ground-truth visibility: 8 v³ (cubic) or v (linear, SI)."""
        return 8 * visibility**3 if self.pose_weighting == "cubic" else visibility

    def presence_weight(self, target: torch.Tensor) -> torch.Tensor:
        """(B, slots, S, S) weight of the presence term per cell/slot (ones by default)."""
        return torch.ones_like(self.split_slots(target)[:, :, self.layout.presence])
