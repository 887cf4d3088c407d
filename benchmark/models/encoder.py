"""The encoder contract and the ablation variants of the paper (Sec. 2.2.3, Fig. 9).

An encoder maps one normalised image ``(B, 3, H, W)`` to a list of embeddings, one per level, the
final level last. Levels other than the final one exist only for the fusion variants and are
computed only when asked (``with_aux=True``, i.e. in training), since they feed the auxiliary
attitude estimates that the paper uses in training only.

Variants (paper Fig. 9):

====== ======================================== =================================
name   channel attention (SE)                   attitude estimates
====== ======================================== =================================
``/``  none                                     final embedding only
``a``  final branch only                        final embedding only
``f``  none                                     aux 1, aux 2 (training) and final
``a-f`` aux 1, aux 2 and final branch (AGTFM)   aux 1, aux 2 (training) and final
====== ======================================== =================================
"""

from __future__ import annotations

from dataclasses import dataclass

from torch import Tensor, nn


@dataclass(frozen=True)
class VariantSpec:
    """``attention``: which branches get SE (subset of ``{'aux1', 'aux2', 'final'}``);
    ``fusion``: whether the two auxiliary embeddings are built and supervised."""

    name: str
    attention: frozenset[str]
    fusion: bool


VARIANTS: dict[str, VariantSpec] = {
    "/": VariantSpec("/", frozenset(), False),
    "a": VariantSpec("a", frozenset({"final"}), False),
    "f": VariantSpec("f", frozenset(), True),
    "a-f": VariantSpec("a-f", frozenset({"aux1", "aux2", "final"}), True),
}


def parse_variant(variant: str) -> VariantSpec:
    """The spec of a variant name; unknown names raise listing the known ones."""
    spec = VARIANTS.get(variant)
    if spec is None:
        raise ValueError(f"unknown encoder variant {variant!r}; known: {', '.join(VARIANTS)}")
    return spec


class Encoder(nn.Module):
    """Base class of encoders.

    Subclasses set ``embedding_dims`` (one int per level, final last; a single entry when the
    variant has no fusion), ``min_input_size`` (pixels) and implement ``forward``.
    """

    embedding_dims: tuple[int, ...] = ()
    min_input_size: int = 1

    @property
    def num_levels(self) -> int:
        return len(self.embedding_dims)

    def forward(self, x: Tensor, with_aux: bool = False) -> list[Tensor]:
        """``x (B, 3, H, W)`` normalised -> ``[aux1 (B, D1), aux2 (B, D2),] final (B, D3)``.

        With ``with_aux=False`` only ``[final]`` is returned (and the aux branches are not run).
        """
        raise NotImplementedError

    def check_input(self, x: Tensor, name: str = "image") -> None:
        if x.dim() != 4 or x.shape[1] != 3:
            raise ValueError(f"{name} must have shape (B, 3, H, W), got {tuple(x.shape)}")
        if min(x.shape[-2:]) < self.min_input_size:
            raise ValueError(
                f"{name} is {x.shape[-2]}x{x.shape[-1]} px; {type(self).__name__} needs at least "
                f"{self.min_input_size} px per side"
            )
