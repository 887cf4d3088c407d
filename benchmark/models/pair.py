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
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
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

# GoogLeNet's ImageNet input statistics; images enter the model as float RGB in [0, 1].
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
BLANK_GREY = 0.5  # the UAV-only control's satellite image, RGB in [0, 1]


@dataclass
class PoseOutput:
    """Raw head outputs. ``aux_attitude`` is empty in eval mode and for variants without fusion."""

    attitude: Raw
    translation: Raw
    aux_attitude: tuple[Raw, ...] = ()


class PoseModel(nn.Module):
    """Siamese encoder + attitude head(s) + translation head.

    Args:
        encoder: an ``Encoder`` whose ``embedding_dims`` has one entry per level, final last.
        attitude_head: head on the final level (``in_features = 2 * D_final``).
        translation_head: head on the final level.
        aux_attitude_heads: one head per auxiliary level (``len(embedding_dims) - 1`` of them).
        aux_weights: ``w_i`` of Algorithm 1, one float for all or one per auxiliary head.
        satellite_input: ``"image"`` or ``"blank"`` (every satellite image replaced by grey).
        shared_satellite: encode each distinct satellite image once when ``sat_ids`` is given;
            False ignores ``sat_ids`` (every satellite image encoded).
    """

    def __init__(
        self,
        encoder: Encoder,
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
        dims = encoder.embedding_dims
        heads = [*aux_attitude_heads, attitude_head]
        for level, (head, dim) in enumerate(zip(heads, dims, strict=True)):
            if head.in_features != 2 * dim:
                raise ValueError(
                    f"attitude head of level {level} takes {head.in_features} features, the pair "
                    f"embedding has 2 * {dim}"
                )
        if translation_head.in_features != 2 * dims[-1]:
            raise ValueError(
                f"translation head takes {translation_head.in_features} features, the pair "
                f"embedding has 2 * {dims[-1]}"
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

    def encode_pair(
        self, uav: Tensor, sat: Tensor, sat_ids: Tensor | None = None, with_aux: bool = False
    ) -> list[Tensor]:
        """Per-level pair features ``[(B, 2 D_l)]``, final level last."""
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
        # One encoder call for both images: shared weights, better throughput.
        embeddings = self.encoder(self._normalize(torch.cat([uav, sat])), with_aux=with_aux)
        features = []
        for e in embeddings:
            e_uav, e_sat = e[:batch], e[batch:]
            if inverse is not None:
                e_sat = e_sat[inverse]
            features.append(torch.cat([e_uav, e_sat], dim=1))
        return features

    def forward(self, uav: Tensor, sat: Tensor, sat_ids: Tensor | None = None) -> PoseOutput:
        """``uav, sat (B, 3, H, W)`` float RGB in [0, 1]; ``sat_ids (B,)`` int64 or None."""
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
    heads = [
        create_head(config.attitude, "attitude", in_features=2 * d, **config.attitude_options)
        for d in dims
    ]
    translation = create_head(
        config.translation, "translation", in_features=2 * dims[-1], **config.translation_options
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
