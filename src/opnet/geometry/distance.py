"""The symmetry-aware pose distance of Brégier et al. (docs/method.md#pose-distance).

``d(P1, P2) = min_{g in G} sqrt(||t1 - t2||^2 + ||(R1 - R2 g) Lambda||_F^2)`` for finite groups, and
``sqrt(||t1 - t2||^2 + lam^2 ||R1 e_z - R2 e_z||^2)`` for revolution objects (minimised over the
axis flip with rotoreflection). As in the official tool, poses are taken as given in the mesh
frame: the distance is the Euclidean distance between *representatives* ``[vec(R g Lambda), t]``
(or ``[lam R e_z, t]``), minimised over the representatives of one side.

Used by the evaluator, the symmetry-aware loss and the pose clustering alike.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from opnet.geometry._array import numpy_compatible


@dataclass(frozen=True)
class PoseSpace:
    """What the pose distance of one object needs.

    Attributes:
        Lambda: (3, 3) float64 metres, square root of the surface covariance, in the mesh frame
            (finite groups). For revolution objects it is kept for reference only.
        group: (K, 3, 3) float64 finite symmetry group (identity first). For revolution objects:
            {I} or, with rotoreflection, {I, half-turn ⟂ z}.
        revolution: True for objects with a revolution symmetry about z.
        lam: metres, ``sqrt(lam_r^2 + lam_z^2)`` for revolution objects.
        delta: metres, the distance threshold of a correct pose (0.1 x diameter).
    """

    Lambda: np.ndarray = field(compare=False)
    group: np.ndarray = field(compare=False)
    delta: float
    revolution: bool = False
    lam: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "Lambda", np.asarray(self.Lambda, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "group", np.asarray(self.group, dtype=np.float64).reshape(-1, 3, 3))
        if not np.isfinite(self.delta) or self.delta <= 0:
            raise ValueError(f"pose distance threshold delta must be positive, got {self.delta}")
        if self.revolution and not self.lam > 0:
            raise ValueError(f"revolution objects need lam > 0, got {self.lam}")

    @property
    def num_representatives(self) -> int:
        return len(self.group)

    @property
    def representative_dim(self) -> int:
        return 6 if self.revolution else 12

    def representatives(self, R: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """All representatives of poses.

        Args:
            R: (..., 3, 3) rotations, t: (..., 3) translations in metres (same frame).
        Returns:
            (..., K, D) with D = 12 (finite group) or 6 (revolution).
        """
        return _representatives(R, t, self)

    def distance(self, R1: torch.Tensor, t1: torch.Tensor, R2: torch.Tensor, t2: torch.Tensor) -> torch.Tensor:
        """Element-wise pose distance (metres) of broadcastable batches of poses: -> (...)."""
        r1 = self.representatives(R1, t1)[..., 0, :]
        r2 = self.representatives(R2, t2)
        return (r2 - r1.unsqueeze(-2)).norm(dim=-1).amin(dim=-1)

    def distance_matrix(self, R_a: torch.Tensor, t_a: torch.Tensor, R_b: torch.Tensor, t_b: torch.Tensor) -> torch.Tensor:
        """Pairwise distances (A, B), metres, between poses (A, 3, 3), (A, 3) and (B, 3, 3), (B, 3)."""
        ra = self.representatives(R_a, t_a)[:, 0, :]  # (A, D)
        rb = self.representatives(R_b, t_b)  # (B, K, D)
        K, D = rb.shape[1], rb.shape[2]
        d = torch.cdist(ra.unsqueeze(0), rb.reshape(1, -1, D)).reshape(len(ra), -1, K)
        return d.amin(dim=-1)

    def closest_equivalent(self, R_ref: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
        """The symmetric equivalent ``R g`` of R closest to R_ref (finite part of the group).

        For revolution objects the spin about z is left as it is; only the axis flip (with
        rotoreflection) is chosen. Shapes: (..., 3, 3) broadcastable -> (..., 3, 3).
        """
        L, G = self.to_torch(R.dtype, R.device)
        cand = R.unsqueeze(-3) @ G  # (..., K, 3, 3)
        if self.revolution:
            err = (cand[..., :, 2] - R_ref.unsqueeze(-3)[..., :, 2]).square().sum(-1)
        else:
            err = ((cand - R_ref.unsqueeze(-3)) @ L).square().sum((-1, -2))
        best = err.argmin(dim=-1)
        idx = best[..., None, None, None].expand(best.shape + (1, 3, 3))
        return torch.gather(cand, -3, idx).squeeze(-3)

    def to_torch(self, dtype: torch.dtype = torch.float32, device: torch.device | str = "cpu") -> tuple[torch.Tensor, torch.Tensor]:
        """(Lambda (3, 3), group (K, 3, 3)) as tensors, made once per dtype and device (so a
        computation captured in a CUDA graph copies nothing from the host)."""
        key = f"{dtype} {torch.device(device)}"
        cache = self.__dict__.get("_tensors")  # not a field: neither compared nor pickled
        if cache is None:
            cache = {}
            object.__setattr__(self, "_tensors", cache)
        if key not in cache:
            cache[key] = (torch.as_tensor(self.Lambda, dtype=dtype, device=device),
                          torch.as_tensor(self.group, dtype=dtype, device=device))  # fmt: skip
        return cache[key]

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "_tensors"}


@numpy_compatible
def _representatives(R: torch.Tensor, t: torch.Tensor, space: PoseSpace) -> torch.Tensor:
    t = t.to(R.dtype)
    K = space.num_representatives
    if space.revolution:
        axes = space.to_torch(R.dtype, R.device)[1][:, :, 2]  # (K, 3): g e_z
        rot_part = space.lam * torch.einsum("...ij,kj->...ki", R, axes)  # (..., K, 3)
    else:
        Lambda, G = space.to_torch(R.dtype, R.device)
        RGL = R.unsqueeze(-3) @ G @ Lambda  # (..., K, 3, 3)
        rot_part = RGL.transpose(-1, -2).reshape(RGL.shape[:-2] + (9,))  # column-major vec
    t_part = t.unsqueeze(-2).expand(t.shape[:-1] + (K, 3))
    return torch.cat((rot_part, t_part), dim=-1)
