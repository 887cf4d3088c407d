"""Non-learned references, evaluated like models (issue 21, item 5).

Each reference estimates the pose of a pair from its two images and the true values it declares
(``Reference.given_values``: the one declaration, from which its report label and ``given``
wording are derived), and is evaluated with the models' metrics, per-frame table and
satellite-swap probe (:func:`evaluate_reference`). The frames it is served hold only those true
values (:class:`Frame`, :class:`TrueValues`): a withheld value is absent, not merely unread.

- ``geometry_oracle`` (:class:`GeometryOracle`): given the true position, pitch and roll, a yaw
  sweep of the UAV pixels cast onto the ground plane against the satellite image. What the pixels
  allow.
- ``gravity_template`` (:class:`GravityTemplate`): given the true pitch, roll and altitude, a
  bird's-eye template matched over the whole satellite image at every yaw (yaw and position).
- ``feature_pnp`` (:class:`FeaturePnP`): given nothing of the pose, local features (SIFT or ORB)
  matched between the images, satellite keypoints lifted to the ground plane, and
  ``cv2.solvePnPRansac`` (OrthoLoC's protocol): the full pose.

``uavbench reference NAME --data DIR --split S [--satellite swap]`` runs one from the command line.
"""

from benchmark.references.base import (
    TRUE_POSE_COLUMNS,
    Estimate,
    Frame,
    GivenValue,
    Reference,
    TrueValues,
    WithheldError,
)
from benchmark.references.evaluate import (
    POSE_THRESHOLDS,
    default_train_split,
    evaluate_reference,
    fallback_pose,
    iter_frames,
    reference_summary,
)
from benchmark.references.ground import GroundCast, SatelliteGrid, cast_uav_pixels, rotate_offsets
from benchmark.references.oracle import GeometryOracle
from benchmark.references.pnp import FeaturePnP
from benchmark.references.registry import create_reference, get_reference_class, list_references
from benchmark.references.template import GravityTemplate

__all__ = [
    "POSE_THRESHOLDS",
    "TRUE_POSE_COLUMNS",
    "Estimate",
    "FeaturePnP",
    "Frame",
    "GeometryOracle",
    "GivenValue",
    "GravityTemplate",
    "GroundCast",
    "Reference",
    "SatelliteGrid",
    "TrueValues",
    "WithheldError",
    "cast_uav_pixels",
    "create_reference",
    "default_train_split",
    "evaluate_reference",
    "fallback_pose",
    "get_reference_class",
    "iter_frames",
    "list_references",
    "reference_summary",
    "rotate_offsets",
]
