"""The Siamese pair model (paper Fig. 1) and the total loss of Algorithm 1.

Both images go through the same encoder; per level the UAV and satellite embeddings are
concatenated, ``[e_uav, e_sat] (B, 2 D_l)``. The final level feeds the attitude head and the
translation head; with a fusion variant (``f``, ``a-f``) the two auxiliary levels each feed their
own attitude head of the same kind, used in training only (paper Sec. 2.2.3).

Shared satellite images: a batch of UAV frames usually holds few distinct satellite images. Pass
``sat_ids (B,)`` (equal ids = identical images) and each distinct one is encoded once, then its
embeddings are gathered back with ``torch.unique(..., return_inverse=True)``. This is exact whenever
an image's embedding does not depend on the other images of the batch: always in eval mode, and in
training mode with the default per-sample GroupNorm (not with ``norm='batch'``, whose batch
statistics would change).

UAV-only control (``satellite_input="blank"``): the model replaces every satellite image by one
constant mid-grey image (0.5 in every channel, before normalisation) in training and at test time,
so training and evaluation run unchanged while the satellite branch carries no information. The
grey image is encoded once per batch (exact with per-sample GroupNorm; with ``norm='batch'`` in
training mode the batch statistics differ from encoding B grey copies).

Pair encoders (``benchmark.models.pair_encoder``, e.g. the matching encoder): the encoder takes
both images and the items' ``context`` and returns the heads' features ``(B, F)`` itself (heads
are built with ``in_features = F``, one level, no auxiliary heads) plus the tensors its own loss
needs (``PoseOutput.encoder``); ``PoseModel.loss`` adds its weighted term ``enc`` to the total
and reports its terms under their own keys. Distinct satellite images are encoded once as above.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor, nn

from benchmark.models.encoder import Encoder
from benchmark.models.heads import AttitudeHead, Raw, TranslationHead, check_option
from benchmark.models.model_config import (
    LEGACY_FIELDS,
    SATELLITE_INPUTS,
    ModelConfig,
    check_satellite_input,
)
from benchmark.models.pair_encoder import (
    IMAGENET_MEAN,
    IMAGENET_STD,
    PairEncoder,
    PairEncoding,
)
from benchmark.models.registry import create_encoder, create_head

__all__ = [
    "BLANK_GREY",
    "SATELLITE_INPUTS",
    "ModelConfig",
    "PoseModel",
    "PoseOutput",
    "build_model",
    "check_satellite_input",
    "create_model",
]

BLANK_GREY = 0.5  # the UAV-only control's satellite image, RGB in [0, 1]


@dataclass
class PoseOutput:
    """Raw head outputs. ``aux_attitude`` is empty in eval mode and for variants without fusion;
    ``encoder`` holds a pair encoder's tensors for its own loss (empty for Siamese encoders)."""

    attitude: Raw
    translation: Raw
    aux_attitude: tuple[Raw, ...] = ()
    encoder: dict[str, Tensor] = field(default_factory=dict)


class PoseModel(nn.Module):
    """Siamese encoder + attitude head(s) + translation head.

    Args:
        encoder: an ``Encoder`` whose ``embedding_dims`` has one entry per level, final last, or
            a ``PairEncoder`` (one level of ``F`` features for the heads).
        attitude_head: head on the final level (``in_features = 2 * D_final``; ``F`` for a pair
            encoder).
        translation_head: head on the final level.
        aux_attitude_heads: one head per auxiliary level (``len(embedding_dims) - 1`` of them).
        aux_weights: ``w_i`` of Algorithm 1, one float for all or one per auxiliary head.
        satellite_input: ``"image"`` or ``"blank"`` (every satellite image replaced by grey).
        shared_satellite: encode each distinct satellite image once when ``sat_ids`` is given;
            False ignores ``sat_ids`` (every satellite image encoded).
    """

    def __init__(
        self,
        encoder: Encoder | PairEncoder,
        attitude_head: AttitudeHead,
        translation_head: TranslationHead,
        aux_attitude_heads: Sequence[AttitudeHead] = (),
        aux_weights: float | Sequence[float] = 0.3,
        channels_last: bool = True,
        config: ModelConfig | None = None,
        satellite_input: str = "image",
        shared_satellite: bool = True,
    ) -> None:
        super().__init__()
        self.satellite_input = check_satellite_input(satellite_input, "PoseModel")
        self.shared_satellite = bool(shared_satellite)
        n_aux = len(encoder.embedding_dims) - 1
        if len(aux_attitude_heads) != n_aux:
            raise ValueError(
                f"encoder has {n_aux} auxiliary levels but {len(aux_attitude_heads)} auxiliary "
                "attitude heads were given"
            )
        weights = (
            [aux_weights] * n_aux if isinstance(aux_weights, (int, float)) else list(aux_weights)
        )
        if len(weights) != n_aux:
            raise ValueError(f"need {n_aux} aux_weights, got {weights}")
        for w in weights:
            check_option(w, "aux_weight", "PoseModel", inclusive=True)
        self.pair_encoder = isinstance(encoder, PairEncoder)
        factor = 1 if self.pair_encoder else 2  # a pair encoder gives the features; else [e, e]
        dims = encoder.embedding_dims
        heads = [*aux_attitude_heads, attitude_head]
        for level, (head, dim) in enumerate(zip(heads, dims, strict=True)):
            if head.in_features != factor * dim:
                raise ValueError(
                    f"attitude head of level {level} takes {head.in_features} features, the pair "
                    f"embedding has {factor} * {dim}"
                )
        if translation_head.in_features != factor * dims[-1]:
            raise ValueError(
                f"translation head takes {translation_head.in_features} features, the pair "
                f"embedding has {factor} * {dims[-1]}"
            )
        self.encoder = encoder
        self.attitude_head = attitude_head
        self.translation_head = translation_head
        self.aux_attitude_heads = nn.ModuleList(aux_attitude_heads)
        self.aux_weights = tuple(float(w) for w in weights)
        self.channels_last = channels_last
        self.config = config
        self.register_buffer(
            "input_mean", torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), persistent=False
        )
        self.register_buffer(
            "input_std", torch.tensor(IMAGENET_STD).view(1, 3, 1, 1), persistent=False
        )
        if channels_last:
            self.to(memory_format=torch.channels_last)

    def _normalize(self, x: Tensor) -> Tensor:
        x = (x - self.input_mean.to(x.dtype)) / self.input_std.to(x.dtype)
        return x.contiguous(memory_format=torch.channels_last) if self.channels_last else x

    def _distinct_satellites(
        self, uav: Tensor, sat: Tensor, sat_ids: Tensor | None
    ) -> tuple[Tensor, Tensor | None]:
        """The satellite images to encode ``(M, 3, H, W)`` and, when ``M < B`` may hold, the
        row of each pair's image among them ``(B,)`` (None: one per pair, in order)."""
        self.encoder.check_input(uav, "uav")
        self.encoder.check_input(sat, "sat")
        if uav.shape != sat.shape:
            raise ValueError(
                f"uav and sat must have the same shape, got {tuple(uav.shape)} and "
                f"{tuple(sat.shape)}"
            )
        batch = uav.shape[0]
        inverse = None
        if not self.shared_satellite:
            sat_ids = None
        if sat_ids is not None:
            if sat_ids.shape != (batch,) or sat_ids.is_floating_point():
                raise ValueError(
                    f"sat_ids must be an integer tensor of shape ({batch},), got "
                    f"{sat_ids.dtype} {tuple(sat_ids.shape)}"
                )
        if self.satellite_input == "blank":
            # UAV-only control: one grey image stands for every satellite image of the batch.
            sat = torch.full((1, *sat.shape[1:]), BLANK_GREY, dtype=sat.dtype, device=sat.device)
            inverse = torch.zeros(batch, dtype=torch.int64, device=sat.device)
        elif sat_ids is not None:
            _, inverse = torch.unique(sat_ids, return_inverse=True)
            n_unique = int(inverse.max()) + 1
            order = torch.arange(batch, device=inverse.device)
            first = torch.full((n_unique,), batch, device=inverse.device).scatter_reduce(
                0, inverse, order, reduce="amin"
            )
            # Cheap guard against ids that do not identify images (one comparison pass).
            if not torch.equal(sat, sat[first[inverse]]):
                raise ValueError("sat_ids gives the same id to satellite images that differ")
            sat = sat[first]
        return sat, inverse

    def encode_pair(
        self, uav: Tensor, sat: Tensor, sat_ids: Tensor | None = None, with_aux: bool = False
    ) -> list[Tensor]:
        """Per-level pair features ``[(B, 2 D_l)]``, final level last (Siamese encoders)."""
        if self.pair_encoder:
            raise TypeError("encode_pair is the Siamese path; a pair encoder runs in forward")
        batch = uav.shape[0]
        sat, inverse = self._distinct_satellites(uav, sat, sat_ids)
        # One encoder call for both images: shared weights, better throughput.
        embeddings = self.encoder(self._normalize(torch.cat([uav, sat])), with_aux=with_aux)
        features = []
        for e in embeddings:
            e_uav, e_sat = e[:batch], e[batch:]
            if inverse is not None:
                e_sat = e_sat[inverse]
            features.append(torch.cat([e_uav, e_sat], dim=1))
        return features

    def forward(
        self,
        uav: Tensor,
        sat: Tensor,
        sat_ids: Tensor | None = None,
        context: Mapping[str, Tensor] | None = None,
    ) -> PoseOutput:
        """``uav, sat (B, 3, H, W)`` float RGB in [0, 1]; ``sat_ids (B,)`` int64 or None;
        ``context``: the items' per-sample geometry (``PairDataset``), read by pair encoders
        only (a Siamese encoder ignores it)."""
        if self.pair_encoder:
            return self._forward_pair_encoder(uav, sat, sat_ids, context)
        with_aux = self.training and len(self.aux_attitude_heads) > 0
        features = self.encode_pair(uav, sat, sat_ids, with_aux=with_aux)
        aux = (
            tuple(h(f) for h, f in zip(self.aux_attitude_heads, features[:-1], strict=True))
            if with_aux
            else ()
        )
        return PoseOutput(
            attitude=self.attitude_head(features[-1]),
            translation=self.translation_head(features[-1]),
            aux_attitude=aux,
        )

    def encode_pairs(
        self,
        uav: Tensor,
        sat: Tensor,
        sat_ids: Tensor | None = None,
        context: Mapping[str, Tensor] | None = None,
    ) -> PairEncoding:
        """A pair encoder's output for ``uav, sat (B, 3, H, W)`` in [0, 1] (the satellite input
        blanked for the UAV-only control, distinct images encoded once): ``features (B, F)``
        and the extras its loss reads."""
        if not self.pair_encoder:
            raise TypeError("encode_pairs is the pair-encoder path; a Siamese encoder uses "
                            "encode_pair")  # fmt: skip
        sat, inverse = self._distinct_satellites(uav, sat, sat_ids)
        if inverse is None:
            inverse = torch.arange(uav.shape[0], device=uav.device)
        return self.encoder(self._normalize(uav), self._normalize(sat), inverse, context)

    def forward_features(self, features: Tensor) -> PoseOutput:
        """The heads on precomputed pair-encoder ``features (B, F)`` (a frozen encoder's,
        ``benchmark.training.encoded``): the output ``forward`` gives without the encoder's
        extras, so :meth:`loss` adds no encoder term."""
        if not self.pair_encoder:
            raise TypeError("forward_features takes a pair encoder's features; this model has a "
                            "Siamese encoder")  # fmt: skip
        return PoseOutput(
            attitude=self.attitude_head(features), translation=self.translation_head(features)
        )

    def _forward_pair_encoder(
        self,
        uav: Tensor,
        sat: Tensor,
        sat_ids: Tensor | None,
        context: Mapping[str, Tensor] | None,
    ) -> PoseOutput:
        enc = self.encode_pairs(uav, sat, sat_ids, context)
        out = self.forward_features(enc.features)
        out.encoder = dict(enc.extras)
        return out

    def loss(self, output: PoseOutput, R_gt: Tensor, T_gt: Tensor) -> dict[str, Tensor]:
        """Algorithm 1: ``total = tran + att``, ``att = att_final + sum_i w_i att_aux{i}``.

        ``R_gt (B, 3, 3)`` is ``R_uav^sat``; ``T_gt (B, 3)`` metres. Returns scalars under
        ``total``, ``att``, ``tran``, ``att_final`` and, when the output has them (training mode,
        fusion variants), the unweighted ``att_aux1``, ``att_aux2``.
        """
        terms: dict[str, Tensor] = {"att_final": self.attitude_head.loss(output.attitude, R_gt)}
        att = terms["att_final"]
        for i, (head, raw, w) in enumerate(
            zip(self.aux_attitude_heads, output.aux_attitude, self.aux_weights, strict=False), 1
        ):
            terms[f"att_aux{i}"] = head.loss(raw, R_gt)
            att = att + w * terms[f"att_aux{i}"]
        tran = self.translation_head.loss(output.translation, T_gt)
        if self.pair_encoder and output.encoder:
            # The pair encoder's own terms (``enc`` = their weighted sum; weight 0 = heads only).
            enc_terms = self.encoder.loss(output.encoder, R_gt, T_gt)
            return {"total": att + tran + enc_terms["enc"], "att": att, "tran": tran, **terms,
                    **enc_terms}  # fmt: skip
        return {"total": att + tran, "att": att, "tran": tran, **terms}

    def decode(self, output: PoseOutput) -> tuple[Tensor, Tensor]:
        """``(R_uav^sat (B, 3, 3), T (B, 3) metres)`` from the final-level outputs."""
        return self.attitude_head.decode(output.attitude), self.translation_head.decode(
            output.translation
        )


def build_model(config: ModelConfig, input_size: int | None = None) -> PoseModel:
    """Build a ``PoseModel`` from a ``ModelConfig`` through the encoder and head registries.

    ``input_size`` (px) fills a config whose ``input_size`` is None (the dataset's size; 224 when
    neither gives one); the model's ``config`` is the resolved config, so a checkpoint rebuilds
    exactly this model.
    """
    config = config.resolved(input_size)
    encoder = create_encoder(
        config.encoder,
        variant=config.variant,
        width=config.width,
        input_size=config.input_size,
        **config.encoder_options,
    )
    dims = encoder.embedding_dims
    factor = 1 if isinstance(encoder, PairEncoder) else 2  # pair encoders give the features
    heads = [
        create_head(config.attitude, "attitude", in_features=factor * d, **config.attitude_options)
        for d in dims
    ]
    translation = create_head(
        config.translation,
        "translation",
        in_features=factor * dims[-1],
        **config.translation_options,
    )
    return PoseModel(
        encoder,
        heads[-1],
        translation,
        heads[:-1],
        config.aux_weight,
        config.channels_last,
        config,
        satellite_input=config.satellite_input,
        shared_satellite=config.shared_satellite,
    )


def create_model(config: ModelConfig | None = None, /, **fields: Any) -> PoseModel:
    """``create_model(ModelConfig(...))``, or the same with keyword fields of ``ModelConfig``:
    ``create_model(variant="a-f", attitude="pd_re_net", attitude_options={"kappa": 5})``
    (``input_size`` defaults to 224 here). Fields given with a config replace its values."""
    known = [f.name for f in dataclasses.fields(ModelConfig)]
    for name in fields:
        if name in LEGACY_FIELDS:
            raise ValueError(f"create_model: {name} is now called {LEGACY_FIELDS[name]}")
        if name not in known:
            raise ValueError(f"create_model: unknown field {name!r}; known: {', '.join(known)}")
    config = ModelConfig(**fields) if config is None else dataclasses.replace(config, **fields)
    return build_model(config)
