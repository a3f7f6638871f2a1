"""The multi-task loss of OP-Net (docs/method.md#the-papers-formulation-or-our-measured-best, paper
"Loss Function"), and its balanced variant.

``L = Σ_cells,slots ( λ1 L_p w_p + [ λ2 L_v + λ_pose λ3 (L_pos + λ4 L_ori) ] p )``, summed over
cells and slots and averaged over the batch, with ``λ3 = 8 v³`` (``v`` for SI) and ``p``, ``v``
the ground-truth presence and visibility; ``w_p`` is the parameterization's presence weight (1
except for MP's optional conditional presence). ``L_p`` and ``L_v`` are squared L2.

Position term ``L_pos`` (``position``):
- ``channels`` (paper): squared L2 on the x, y, z channels. Their units differ between
  parameterizations: a δ-sized error costs ~0.12 per axis with vanilla's cell-relative offsets but
  ~1.7e-4 with the enlarged-image positions of EVE / AP / SI, so those barely learn position.
- ``metric``: ``||t̂ - t||² / δ²`` with both origins decoded from the channels through the
  parameterization's own decoder and the image's camera (differentiable). The same units for every
  parameterization, and the units of the metric: an error of δ costs 1.

Orientation term ``L_ori`` (``orientation``):
- ``euler_l2`` (paper; alias ``channel_l2``): squared L2 on the orientation channels.
- ``sym_channel_l2``: the squared L2 to the nearest of the channel targets of the symmetric
  equivalents ``R g`` (the object's finite group; the axis and its flip for revolution objects):
  the paper's channel loss without the seams of a canonical choice of equivalent.
- ``sym_rotation``: the squared Brégier rotation distance ``min_g ||(R̂ - R g) Λ||²_F / δ²`` of the
  rotations decoded from the channels (revolution objects: ``λ² min_g ||R̂ e_z - R g e_z||² / δ²``).
  With ``position=metric`` the pose term is then exactly the squared Brégier pose distance in units
  of δ (the evaluation's threshold), its two parts balanced by construction (λ4 = 1).

Unseen spins (``spin_unseen_deg``, not part of the paper; off by default): for a part spun about its model z-axis
(a wheel, a rim, a flange; opnet-object puts a part's main axis there) whose axis lies more than ``spin_unseen_deg``
from the camera's optical axis, the depth hardly shows the turn about that axis. There ``sym_channel_l2`` asks for
the axis only: the target's x column is the network's own x column made perpendicular to the target's axis (the
spin that the output already has), so no gradient asks the network to learn a spin the image does not hold
(docs/method.md#unseen-spins).

Quality term ``L_q`` (only for a parameterization with a quality channel, ``parameterization.quality``): on every
occupied cell/slot, ``λ_q (q̂ - q*)²`` with ``q* = 2^-(d/δ)²``, ``d`` the symmetry-aware Brégier rotation distance
of the orientation decoded from the cell's own rotation channels to the truth (held fixed: the term teaches q̂ to
estimate how right the orientation is, and moves no orientation channel). q* is 1 for an exact orientation and ½
at the metric's threshold (docs/method.md#orientation-quality). Not part of the paper.

``loss=paper`` (``channels`` + ``euler_l2``, λ_pose = 1) is the paper's loss, computed densely over
every cell exactly as before; the other combinations gather the occupied cells first.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence

import torch
from torch import nn

from opnet.geometry.camera import Camera
from opnet.parameterizations.base import Parameterization
from opnet.parameterizations.batch import ChannelLayout
from opnet.parameterizations.positions import CameraBatch
from opnet.parameterizations.rotation import RotationCodec, SixDCodec

ORIENTATION_LOSSES = ("euler_l2", "channel_l2", "sym_channel_l2", "sym_rotation")
POSITION_LOSSES = ("channels", "metric")
ROBUST = ("none", "charbonnier")


class MultiTaskLoss(nn.Module):
    """OP-Net's weighted sum of presence, visibility, position and orientation errors.

    Args:
        lambda_p: λ1, weight of the presence term.
        lambda_v: λ2, weight of the visibility term.
        lambda_ori: λ4, weight of the orientation term relative to the position term.
        orientation: "euler_l2" (paper), "channel_l2" (the same for any rotation codec),
            "sym_channel_l2" (the nearest symmetric equivalent's channels) or "sym_rotation"
            (symmetry-aware rotation distance / δ²).
        position: "channels" (paper) or "metric" (origin distance / δ, squared).
        lambda_pose: factor on λ3 (the weight of position and orientation together); 1 in the paper.
        lambda_pos: weight of the position term (1 in the paper); with ``position=metric`` 0.1
            makes a δ-sized origin error cost what it costs in vanilla's channel units.
        lambda_z: with ``position=channels``, the weight of the depth channel against the two
            image-plane channels (1 in the paper). The depth channel spans the clip range (0.83 m for
            the Siléane camera) while x and y span a cell (about 3.5 cm there), so at weight 1 a depth
            error costs about 500 times less than the same error across the image, and dense piles
            are missed on depth (results/dense/ab.md).
        lambda_xy: with ``position=channels``, the weight of the two image-plane channels (1 in the
            paper). The cell-offset channels span the part's projected diameter on either side of the
            cell (at least two cells), so an origin error of δ costs about (1/20)² whatever the part,
            little beside the orientation channels of a flat part, whose turns the metric prices
            high (results/flat_parts/README.md).
        spin_unseen_deg: null (off) or the angle between a part's model z-axis and the optical axis beyond which
            ``sym_channel_l2`` asks for the axis only, the spin left as the network has it
            (:func:`unseen_spin_targets`).
        robust: "none" (squared errors, the paper) or "charbonnier": each pose term ``e`` (a
            squared error) becomes ``2 (sqrt(1 + e) - 1)``: the same near zero, but growing only
            linearly with the error, so that the large errors of early training do not swamp the
            presence and visibility gradients (AdamW's per-parameter scaling remembers them for
            about a thousand steps).
    """

    def __init__(
        self,
        lambda_p: float = 0.1,
        lambda_v: float = 0.25,
        lambda_ori: float = 1.0,
        orientation: str = "euler_l2",
        position: str = "channels",
        lambda_pose: float = 1.0,
        robust: str = "none",
        lambda_pos: float = 1.0,
        lambda_z: float = 1.0,
        lambda_xy: float = 1.0,
        lambda_quality: float = 1.0,
        spin_unseen_deg: float | None = None,
    ) -> None:
        super().__init__()
        if orientation not in ORIENTATION_LOSSES:
            raise ValueError(
                f"loss.orientation must be one of {ORIENTATION_LOSSES}, got {orientation!r}"
            )
        if robust not in ROBUST:
            raise ValueError(f"loss.robust must be one of {ROBUST}, got {robust!r}")
        if position not in POSITION_LOSSES:
            raise ValueError(f"loss.position must be one of {POSITION_LOSSES}, got {position!r}")
        for key, value in (("lambda_p", lambda_p), ("lambda_v", lambda_v),
                           ("lambda_ori", lambda_ori), ("lambda_pose", lambda_pose),
                           ("lambda_pos", lambda_pos), ("lambda_z", lambda_z), ("lambda_xy", lambda_xy),
                           ("lambda_quality", lambda_quality)):  # fmt: skip
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not value >= 0:
                raise ValueError(f"loss.{key} must be a number >= 0, got {value!r}")
        self.lambda_p, self.lambda_v, self.lambda_ori = (
            float(lambda_p),
            float(lambda_v),
            float(lambda_ori),
        )
        self.lambda_pose = float(lambda_pose)
        self.lambda_pos = float(lambda_pos)
        self.lambda_z = float(lambda_z)
        self.lambda_xy = float(lambda_xy)
        self.lambda_quality = float(lambda_quality)
        if spin_unseen_deg is not None:
            if (isinstance(spin_unseen_deg, bool) or not isinstance(spin_unseen_deg, numbers.Real)
                    or not 0 < spin_unseen_deg < 90):
                raise ValueError(f"loss.spin_unseen_deg must be null or an angle in (0, 90) degrees, "
                                 f"got {spin_unseen_deg!r}")
            if orientation != "sym_channel_l2":
                raise ValueError(f"loss.spin_unseen_deg needs loss.orientation=sym_channel_l2, got {orientation!r}")
        self.spin_unseen_deg = None if spin_unseen_deg is None else float(spin_unseen_deg)
        self.orientation = orientation
        self.position = position
        self.robust = robust

    @property
    def is_paper(self) -> bool:
        """The paper's dense channel-space formulation (``loss=paper``)."""
        return (
            self.position == "channels"
            and self.orientation in ("euler_l2", "channel_l2")
            and self.lambda_pose == 1.0
            and self.lambda_pos == 1.0
            and self.lambda_z == 1.0
            and self.lambda_xy == 1.0
            and self.robust == "none"
        )

    def forward(
        self,
        output: torch.Tensor,
        target: torch.Tensor,
        parameterization: Parameterization,
        cameras: Camera | Sequence[Camera] | None = None,
    ) -> dict[str, torch.Tensor]:
        """Loss terms of a batch.

        Args:
            output: (B, C, S, S) network output in [0, 1].
            target: (B, C, S, S) the parameterization's encoded ground truth.
            parameterization: the one that produced ``target``.
            cameras: the network-input camera(s) of the batch (needed by ``position=metric``).
        Returns:
            scalars "presence", "visibility", "position", "orientation", with a quality channel "quality" (each
            already weighted), and their sum "total"; sums over cells and slots, means over the batch.
        """
        if output.shape != target.shape:
            raise ValueError(
                f"loss: output shape {tuple(output.shape)} != target shape {tuple(target.shape)}"
            )
        out = parameterization.split_slots(output)  # (B, L, C, S, S)
        tgt = parameterization.split_slots(target)
        lay = parameterization.layout
        batch = output.shape[0]
        p, v = tgt[:, :, lay.presence], tgt[:, :, lay.visibility]  # (B, L, S, S)
        terms = {
            "presence": self.lambda_p
            * (parameterization.presence_weight(target) * (out[:, :, lay.presence] - p) ** 2),
            "visibility": self.lambda_v * p * (out[:, :, lay.visibility] - v) ** 2,
        }
        if self.is_paper:
            pose_weight = parameterization.pose_weight(v) * p
            position, rotation = lay.position, lay.rotation
            terms["position"] = pose_weight * ((out[:, :, position] - tgt[:, :, position]) ** 2).sum(2)
            terms["orientation"] = (
                self.lambda_ori * pose_weight * ((out[:, :, rotation] - tgt[:, :, rotation]) ** 2).sum(2)
            )
        if not self.is_paper or parameterization.has_quality:  # the occupied cells gathered once for both
            occupied = occupied_cells(out, tgt, lay)
            if not self.is_paper:
                terms.update(self._pose_terms(occupied, batch, parameterization, cameras))
            if parameterization.has_quality:
                terms["quality"] = self.lambda_quality * quality_error(*occupied[1:], parameterization)
        losses = {name: term.sum() / batch for name, term in terms.items()}
        losses["total"] = sum(losses.values())  # type: ignore[assignment]
        return losses

    def _pose_terms(
        self,
        occupied: tuple[tuple[torch.Tensor, ...], torch.Tensor, torch.Tensor],
        batch: int,
        parameterization: Parameterization,
        cameras: Camera | Sequence[Camera] | None,
    ) -> dict[str, torch.Tensor]:
        """Position and orientation terms (P,) of the occupied cells/slots only (:func:`occupied_cells`; ``batch``:
        the batch's size)."""
        lay = parameterization.layout
        (b, slot, row, col), o, t = occupied
        weight = self.lambda_pose * parameterization.pose_weight(t[:, lay.visibility])  # (P,)
        o_pos, t_pos, o_rot, t_rot = o[:, lay.position], t[:, lay.position], o[:, lay.rotation], t[:, lay.rotation]
        delta = parameterization.obj.delta
        if self.position == "metric":
            if cameras is None:
                raise ValueError("loss.position=metric needs the cameras of the batch")
            cams = CameraBatch.of(cameras, batch, o.device).take(b)
            cells = (slot, row, col)
            t_hat = parameterization.decode_translations(o_pos, cells, cams)
            t_gt = parameterization.decode_translations(t_pos, cells, cams)
            position = (((t_hat - t_gt) / delta) ** 2).sum(-1).to(o.dtype)
        else:
            axes = o.new_tensor([self.lambda_xy, self.lambda_xy, self.lambda_z])
            position = (((o_pos - t_pos) ** 2) * axes).sum(-1)
        rotation = parameterization.rotation
        if self.orientation == "sym_rotation":
            orientation = symmetric_rotation_error(
                rotation.decode(o_rot), rotation.decode(t_rot).detach(), parameterization
            )
        elif self.orientation == "sym_channel_l2":
            group = torch.as_tensor(parameterization.obj.pose_space.group, device=o.device)
            targets = rotation.equivalent_channels(rotation.decode(t_rot.double()), group)
            if self.spin_unseen_deg is not None:
                targets = unseen_spin_targets(o_rot, targets, rotation, self.spin_unseen_deg)
            targets = targets.to(o.dtype)
            orientation = ((o_rot[:, None] - targets.detach()) ** 2).sum(-1).amin(-1)  # (P,)
        else:
            orientation = ((o_rot - t_rot) ** 2).sum(-1)
        if self.robust == "charbonnier":
            position = 2 * (torch.sqrt(1 + position) - 1)
            orientation = 2 * (torch.sqrt(1 + orientation) - 1)
        return {
            "position": self.lambda_pos * weight * position,
            "orientation": self.lambda_ori * weight * orientation,
        }


def unseen_spin_targets(o_rot: torch.Tensor, targets: torch.Tensor, rotation: RotationCodec,
                        unseen_deg: float) -> torch.Tensor:
    """The channel targets (P, K, A) of the symmetric equivalents with the spin left to the network where the
    part's axis lies more than ``unseen_deg`` from the optical axis: there each target is turned about its axis to
    the spin of the output ``o_rot`` (P, A) (:meth:`SixDCodec.with_spin_of`). Axes nearer the optical axis keep
    their targets; a revolution part's channels hold its axis alone already and are returned as they are.

    Raises:
        ValueError: the codec is not the 6-D one (``rotation=r6d``), the only one whose axis and spin lie apart.
    """
    if not isinstance(rotation, SixDCodec):
        raise ValueError(f"loss.spin_unseen_deg needs rotation=r6d, got the {rotation.name!r} codec")
    if rotation.revolution:
        return targets
    free = rotation.with_spin_of(targets, o_rot[:, None].detach().to(targets.dtype))
    axis_z = rotation.axis(targets)[..., 2]  # (P, K) the equivalents' axes' z in the camera frame
    unseen = axis_z.abs() < math.cos(math.radians(unseen_deg))  # the axis far from the line of sight
    return torch.where(unseen[..., None], free, targets)


def quality_target(out_rot: torch.Tensor, tgt_rot: torch.Tensor, parameterization: Parameterization) -> torch.Tensor:
    """q* (P,) of occupied cells from their predicted and target rotation channels (P, A): ``2^-(d/δ)²``, ``d``
    the symmetry-aware rotation distance of the decoded orientations (no gradient)."""
    with torch.no_grad():
        codec = parameterization.rotation
        err = symmetric_rotation_error(codec.decode(out_rot.double()), codec.decode(tgt_rot.double()), parameterization)
        return torch.exp2(-err).to(out_rot.dtype)


def occupied_cells(out: torch.Tensor, tgt: torch.Tensor,
                   lay: ChannelLayout) -> tuple[tuple[torch.Tensor, ...], torch.Tensor, torch.Tensor]:
    """The cells/slots that hold a part in slot-split targets (B, L, C, S, S): their indices (b, slot, row, col)
    and the output's and the target's feature vectors there, (P, C) each."""
    b, slot, row, col = torch.nonzero(tgt[:, :, lay.presence] > 0, as_tuple=True)
    o = out.permute(0, 1, 3, 4, 2)[b, slot, row, col]  # (P, C)
    t = tgt.permute(0, 1, 3, 4, 2)[b, slot, row, col]
    return (b, slot, row, col), o, t


def quality_error(o: torch.Tensor, t: torch.Tensor, parameterization: Parameterization) -> torch.Tensor:
    """``(q̂ - q*)²`` (P,) of occupied cells/slots from their output and target feature vectors (P, C)
    (:func:`occupied_cells`)."""
    lay = parameterization.layout
    return (o[:, lay.quality] - quality_target(o[:, lay.rotation], t[:, lay.rotation], parameterization)) ** 2


def symmetric_rotation_error(
    R_hat: torch.Tensor, R: torch.Tensor, parameterization: Parameterization
) -> torch.Tensor:
    """Squared Brégier rotation distance over δ², minimised over the symmetry group.

    Args:
        R_hat, R: (..., 3, 3) predicted and ground-truth rotations, camera frame.
        parameterization: gives the object's pose space (Λ, group, λ, δ).
    Returns:
        (...) dimensionless errors.
    """
    space = parameterization.obj.pose_space
    Lambda, group = space.to_torch(R_hat.dtype, R_hat.device)
    if space.revolution:
        axes = torch.einsum("...ij,kj->...ki", R, group[:, :, 2])  # (..., K, 3): R g e_z
        err = space.lam**2 * ((R_hat[..., None, :, 2] - axes) ** 2).sum(-1)
    else:
        diff = (R_hat.unsqueeze(-3) - R.unsqueeze(-3) @ group) @ Lambda  # (..., K, 3, 3)
        err = (diff**2).sum((-1, -2))
    return err.amin(-1) / space.delta**2
