"""Re-Net-T: DirectionNet-T without de-rotation, plus a scale branch (paper Sec. 3.3.1, Table 3).

The translation ``T = [dE, dN, dU]`` is split into its direction ``T / |T|`` and its length.

Grid and target: the 4096-point Fibonacci lattice; ``discrete_vmf(T / |T|, kappa)`` (sum 1).
Prediction: softmax over the lattice for the direction; the scale branch regresses
``|T| / rms`` through a softplus, where ``rms = sqrt(|mean|^2 + sum std^2)`` is the root mean
square length of the training translations, derived from the statistics buffers (so
``set_statistics`` is all the head needs, like the regression head).
Loss: ``L_dir + alpha * s * L_dis`` on the direction (as in ``pd_re_net``) plus
``scale_weight * (scale - |T*| / rms)^2``, mean over the batch.
Decoding: Eq. 9 expectation of the direction times ``scale * rms`` (metres).
Uncertainty: spherical variance ``1 - |E d|`` of the direction distribution, in [0, 1].
"""

from __future__ import annotations

import torch
from torch import Tensor
from torch.nn import functional

from benchmark.geometry import discrete_vmf, fibonacci_sphere
from benchmark.models import TranslationHead, register_head
from benchmark.models.heads import check_lattice_options, check_option, mlp
from benchmark.models.spherical import directionnet_loss, resultant_length

_MIN_LENGTH = 1e-6  # metres; below this the direction is undefined and e_z is used


@register_head("re_net_t")
class ReNetT(TranslationHead):
    """Options: n_points (4096), kappa (10), alpha (8e7), hidden (160), scale_weight (1)."""

    paper_name = "Re-Net-T"
    is_probabilistic = True

    def __init__(
        self,
        in_features: int,
        n_points: int = 4096,
        kappa: float = 10.0,
        alpha: float = 8e7,
        hidden: int = 160,
        scale_weight: float = 1.0,
    ) -> None:
        super().__init__(in_features)
        self.kappa, self.alpha = check_lattice_options("re_net_t", n_points, kappa, alpha)
        self.scale_weight = check_option(scale_weight, "scale_weight", "re_net_t", inclusive=True)
        self.register_buffer("grid", fibonacci_sphere(n_points), persistent=False)
        self.net = mlp(in_features, hidden, n_points + 1)

    def rms(self, dtype: torch.dtype) -> Tensor:
        """Root mean square training translation length (metres), from ``mean`` and ``std``."""
        return torch.sqrt((self.mean**2).sum() + (self.std**2).sum()).to(dtype)

    def forward(self, features: Tensor) -> dict[str, Tensor]:
        """(B, F) -> {"logits": (B, n) direction logits, "scale": (B,) length / rms, > 0}."""
        out = self.net(features)
        return {"logits": out[:, :-1], "scale": functional.softplus(out[:, -1])}

    def _split(self, T: Tensor) -> tuple[Tensor, Tensor]:
        length = torch.linalg.vector_norm(T, dim=-1)
        e_z = torch.zeros_like(T)
        e_z[..., 2] = 1
        direction = torch.where(
            (length < _MIN_LENGTH)[..., None], e_z, T / length.clamp_min(_MIN_LENGTH)[..., None]
        )
        return direction, length / self.rms(T.dtype)

    def distribution(self, raw: dict[str, Tensor]) -> dict[str, Tensor]:
        """{"direction": (B, n) probabilities, "scale": (B,) point estimate of |T| / rms}."""
        return {"direction": torch.softmax(raw["logits"], dim=-1), "scale": raw["scale"]}

    def target_distribution(self, T: Tensor) -> dict[str, Tensor]:
        direction, scale = self._split(T)
        return {
            "direction": discrete_vmf(direction, self.kappa, self.grid.to(T.dtype)),
            "scale": scale,
        }

    def decode_distribution(self, dist: dict[str, Tensor]) -> Tensor:
        p = dist["direction"]
        resultant = p @ self.grid.to(p.dtype)
        direction = resultant / torch.linalg.vector_norm(resultant, dim=-1, keepdim=True).clamp_min(
            1e-12
        )
        return direction * (dist["scale"] * self.rms(p.dtype))[..., None]

    def decode(self, raw: dict[str, Tensor]) -> Tensor:
        """(B, 3) metres."""
        return self.decode_distribution(self.distribution(raw))

    def loss(self, raw: dict[str, Tensor], T_gt: Tensor) -> Tensor:
        p = torch.softmax(raw["logits"], dim=-1)
        grid = self.grid.to(p.dtype)
        direction, scale = self._split(T_gt)
        target = discrete_vmf(direction, self.kappa, grid)
        l_dir = directionnet_loss(
            p[:, None], target[:, None], (p @ grid)[:, None], direction[:, None], self.alpha, 3
        )
        return (l_dir + self.scale_weight * (raw["scale"] - scale) ** 2).mean()

    def uncertainty(self, raw: dict[str, Tensor]) -> Tensor:
        """(B,) spherical variance of the direction distribution, in [0, 1]."""
        return 1 - resultant_length(torch.softmax(raw["logits"], dim=-1), self.grid)
