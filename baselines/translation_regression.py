"""Translation by regression: the Pd/Re-Net translation branch (paper Sec. 2.1, Algorithm 1 step 8).

Two fully connected layers map the pair embedding to ``[dE, dN, dU]`` standardised with the
training-set mean and std (buffers ``mean``/``std``, saved with the model; set them with
``fit_statistics(T_train)`` or ``set_statistics``). Loss: least squares on the standardised values,
summed over the three axes, mean over the batch (Algorithm 1 step 8, ``(T - T*)^2``, computed in
standard units so that the three axes weigh alike whatever their spread). Decoding: metres.
Discontinuities: none (an affine map of R^3).
"""

from __future__ import annotations

from benchmark.models import RegressionTranslationHead, register_head


@register_head("regression")
class TranslationRegression(RegressionTranslationHead):
    """Args: in_features; hidden (1024). Raw: (B, 3) standardised translation; decode: metres
    ``[dE, dN, dU]`` (the representation is the base's: ``(T - mean) / std``)."""

    paper_name = "Pd/Re-Net"
