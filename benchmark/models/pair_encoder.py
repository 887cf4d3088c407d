"""The pair-encoder contract: one module that sees both images of a pair at once (issue 21).

The Siamese ``Encoder`` (``benchmark.models.encoder``) embeds each image alone and ``PoseModel``
concatenates ``[e_uav, e_sat]``, so the heads get ``2 D`` features. A ``PairEncoder`` instead
takes the pair and its per-sample geometry and returns the heads' features itself::

    enc = encoder(uav (B, 3, H, W), sat (M, 3, H, W), sat_index (B,) int64, context)
    enc.features      # (B, F): what every head gets (heads are built with in_features = F)
    enc.extras        # dict of tensors its own loss needs (e.g. the pose volume)
    terms = encoder.loss(enc.extras, R_gt (B, 3, 3), T_gt (B, 3))
    terms["enc"]      # the weighted sum PoseModel.loss adds to the heads' loss (0: heads only)

Images arrive normalised (ImageNet statistics, as for every encoder). ``sat`` holds the distinct
satellite images of the batch and ``sat_index`` says which one each pair uses (``PoseModel``
encodes each distinct image once; ``sat_index = arange(B)`` when every pair brings its own).
``context`` is the dict ``PairDataset`` puts under each item's ``"context"`` (collated to
``(B, ...)`` tensors; see ``benchmark.data.dataset``): ``fov`` (rad), ``sat_footprint_m`` (E, N),
``sat_height_m``, ``prior_attitude`` (pitch, roll rad) and ``prior_altitude_m``. A pair encoder
has one level (no auxiliary attitude heads) and reads what it needs from ``context``; training and
evaluation pass the dict through without knowing what is in it.

A pair encoder with a pose volume (the matching encoder) puts it in ``extras["log_volume"]``
``(B, K, P, Q)`` (log-probabilities over UAV yaw, north, east) and describes its axes by
:meth:`PairEncoder.pose_volume_axes`; the flight fusion then fuses the volume itself as a belief
(``benchmark.evaluation.volume_beliefs``). The default is None: no volume.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from torch import Tensor, nn

from benchmark.models.encoder import Encoder

# GoogLeNet's ImageNet input statistics: every encoder gets (x - mean) / std of RGB in [0, 1]
# (``PoseModel`` normalises; a pair encoder that needs the pixels back inverts it).
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)

__all__ = ["PairEncoder", "PairEncoding", "PoseVolumeAxes"]


@dataclass
class PairEncoding:
    """``features (B, F)`` for the heads; ``extras``: tensors the encoder's own loss needs."""

    features: Tensor
    extras: dict[str, Tensor] = field(default_factory=dict)


@dataclass(frozen=True)
class PoseVolumeAxes:
    """The axes of a pose volume ``extras["log_volume"] (B, K, P, Q)``: bin centres ``yaw (K,)``
    rad (the UAV's yaw in the navigation frame, Eq. 1; equally spaced over the circle), row
    offsets ``north (P,)`` and column offsets ``east (Q,)`` metres from the satellite image's
    centre (the translation label's origin, ``T = [dE, dN, dU]``), both equally spaced by
    ``cell_m`` (in any order)."""

    yaw: Tensor
    north: Tensor
    east: Tensor
    cell_m: float


class PairEncoder(nn.Module):
    """Base class of pair encoders. Subclasses set ``feature_dim`` (F) and ``min_input_size``
    (px) and implement ``forward`` and ``loss``. ``embedding_dims = (F,)``: one level."""

    is_pair_encoder = True
    feature_dim: int = 0
    min_input_size: int = 1

    @property
    def embedding_dims(self) -> tuple[int, ...]:
        return (self.feature_dim,)

    check_input = Encoder.check_input

    def forward(
        self,
        uav: Tensor,
        sat: Tensor,
        sat_index: Tensor,
        context: Mapping[str, Tensor] | None = None,
    ) -> PairEncoding:
        raise NotImplementedError

    def loss(self, extras: Mapping[str, Tensor], R_gt: Tensor, T_gt: Tensor) -> dict[str, Tensor]:
        """Named scalar terms; ``"enc"`` is the weighted sum added to the total loss."""
        raise NotImplementedError

    def pose_volume_axes(self) -> PoseVolumeAxes | None:
        """The axes of ``extras["log_volume"]`` (module docstring); None: no pose volume."""
        return None
