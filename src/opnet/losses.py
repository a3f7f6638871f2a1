"""The multi-task loss of OP-Net (method.md §5, paper "Loss Function").

``L = Σ_cells,slots ( λ1 L_p w_p + [ λ2 L_v + λ3 (L_pos + λ4 L_ori) ] p )``, summed over cells and
slots and averaged over the batch, with ``λ3 = 8 v³`` (``v`` for SI) and ``p``, ``v`` the
ground-truth presence and visibility; ``w_p`` is the parameterization's presence weight (1 except
for MP's optional conditional presence). All terms are squared L2. The orientation term is either
the paper's squared L2 on the normalized Euler channels (``euler_l2``) or the symmetry-aware
squared Brégier rotation distance ``min_g ||(R̂ - R g) Λ||²_F / δ²`` on the rotation decoded from
the predicted channels (``sym_rotation``; revolution objects:
``λ² min_g ||R̂ e_z - R g e_z||² / δ²``).
"""

from __future__ import annotations

import torch
from torch import nn

from opnet.parameterizations.base import Parameterization

ORIENTATION_LOSSES = ("euler_l2", "sym_rotation")


class MultiTaskLoss(nn.Module):
    """OP-Net's weighted sum of presence, visibility, position and orientation errors.

    Args:
        lambda_p: λ1, weight of the presence term.
        lambda_v: λ2, weight of the visibility term.
        lambda_ori: λ4, weight of the orientation term relative to the position term.
        orientation: "euler_l2" (paper) or "sym_rotation" (symmetry-aware rotation distance).
    """

    def __init__(
        self,
        lambda_p: float = 0.1,
        lambda_v: float = 0.25,
        lambda_ori: float = 1.0,
        orientation: str = "euler_l2",
    ) -> None:
        super().__init__()
        if orientation not in ORIENTATION_LOSSES:
            raise ValueError(
                f"loss orientation must be one of {ORIENTATION_LOSSES}, got {orientation!r}"
            )
        self.lambda_p, self.lambda_v, self.lambda_ori = (
            float(lambda_p),
            float(lambda_v),
            float(lambda_ori),
        )
        self.orientation = orientation

    def forward(
        self, output: torch.Tensor, target: torch.Tensor, parameterization: Parameterization
    ) -> dict[str, torch.Tensor]:
        """Loss terms of a batch.

        Args:
            output: (B, C, S, S) network output in [0, 1].
            target: (B, C, S, S) the parameterization's encoded ground truth.
            parameterization: the one that produced ``target``.
        Returns:
            scalars "presence", "visibility", "position", "orientation" (each already weighted) and
            their sum "total"; sums over cells and slots, means over the batch.
        """
        if output.shape != target.shape:
            raise ValueError(
                f"loss: output shape {tuple(output.shape)} != target shape {tuple(target.shape)}"
            )
        out = parameterization.split_slots(output)  # (B, L, C, S, S)
        tgt = parameterization.split_slots(target)
        batch = output.shape[0]
        p, v = tgt[:, :, 0], tgt[:, :, 1]  # (B, L, S, S)
        pose_weight = parameterization.pose_weight(v) * p
        terms = {
            "presence": self.lambda_p
            * (parameterization.presence_weight(target) * (out[:, :, 0] - p) ** 2),
            "visibility": self.lambda_v * p * (out[:, :, 1] - v) ** 2,
            "position": pose_weight * ((out[:, :, 2:5] - tgt[:, :, 2:5]) ** 2).sum(2),
            "orientation": self.lambda_ori
            * pose_weight
            * self._orientation_error(output, target, parameterization),
        }
        losses = {name: term.sum() / batch for name, term in terms.items()}
        losses["total"] = sum(losses.values())  # type: ignore[assignment]
        return losses

    def _orientation_error(
        self, output: torch.Tensor, target: torch.Tensor, parameterization: Parameterization
    ) -> torch.Tensor:
        """(B, L, S, S) orientation error of every cell/slot."""
        if self.orientation == "euler_l2":
            out, tgt = parameterization.split_slots(output), parameterization.split_slots(target)
            return ((out[:, :, 5:] - tgt[:, :, 5:]) ** 2).sum(2)
        return symmetric_rotation_error(
            parameterization.decode_rotations(output),
            parameterization.decode_rotations(target).detach(),
            parameterization,
        )


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
