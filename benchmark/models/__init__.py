"""Models: the Siamese GoogLeNet encoder, the head contract and registries, the pair model.

Public API (see DEVELOPERS.md, "Model contract")::

    from benchmark.models import create_model, create_head, list_heads, register_head
    from benchmark.models import AttitudeHead, TranslationHead, PoseModel, ModelConfig
"""

from benchmark.models.encoder import VARIANTS, Encoder, VariantSpec, parse_variant
from benchmark.models.head_bases import (
    GridDistribution,
    LatticeDirections,
    LatticeHead,
    RegressionAttitudeHead,
    RegressionTranslationHead,
)
from benchmark.models.heads import (
    AttitudeHead,
    Head,
    TranslationHead,
    distribution_loss_scale,
    mlp,
    nearest_grid_index,
    sphere_volume,
)
from benchmark.models.pair import (
    ModelConfig,
    PoseModel,
    PoseOutput,
    build_model,
    create_model,
)
from benchmark.models.pair_encoder import PairEncoder, PairEncoding
from benchmark.models.registry import (
    create_encoder,
    create_head,
    get_head_class,
    head_kind,
    head_versions,
    list_encoders,
    list_heads,
    register_encoder,
    register_head,
)

__all__ = [
    "VARIANTS",
    "AttitudeHead",
    "Encoder",
    "GridDistribution",
    "Head",
    "LatticeDirections",
    "LatticeHead",
    "ModelConfig",
    "PairEncoder",
    "PairEncoding",
    "PoseModel",
    "PoseOutput",
    "RegressionAttitudeHead",
    "RegressionTranslationHead",
    "TranslationHead",
    "VariantSpec",
    "build_model",
    "create_encoder",
    "create_head",
    "create_model",
    "distribution_loss_scale",
    "get_head_class",
    "head_kind",
    "head_versions",
    "list_encoders",
    "list_heads",
    "mlp",
    "nearest_grid_index",
    "parse_variant",
    "register_encoder",
    "register_head",
    "sphere_volume",
]
