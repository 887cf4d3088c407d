"""Translation by regression: the Pd/Re-Net translation branch (paper Sec. 2.1, Algorithm 1 step 8).

Two fully connected layers map the pair embedding to ``[dE, dN, dU]`` standardised with the
training-set mean and std (buffers ``mean``/``std``, saved with the model; set them with
``fit_statistics(T_train)`` or ``set_statistics``). Loss: least squares on the standardised values,
summed over the three axes, mean over the batch (Algorithm 1 step 8, ``(T - T*)^2``, computed in
standard units so that the three axes weigh alike whatever their spread). Decoding: metres.
Discontinuities: none (an affine map of R^3).
"""

from __future__ import annotations

from torch import Tensor

from benchmark.models import TranslationHead, mlp, register_head


@register_head("regression")
class TranslationRegression(TranslationHead):
    """Args: in_features; hidden (1024)."""

    paper_name = "Pd/Re-Net"

    def __init__(self, in_features: int, hidden: int = 1024) -> None:
        super().__init__(in_features)
        self.net = mlp(in_features, hidden, 3)

    def forward(self, features: Tensor) -> Tensor:
        """(B, F) -> (B, 3) standardised translation."""
        return self.net(features)

    def decode(self, raw: Tensor) -> Tensor:
        """(B, 3) metres ``[dE, dN, dU]``."""
        return self.unstandardize(raw)

    def loss(self, raw: Tensor, T_gt: Tensor) -> Tensor:
        return ((raw - self.standardize(T_gt)) ** 2).sum(-1).mean()
