"""The records of the tracking interface: run states, what a stored run looks like, dataset
references, metric points, tracker specs, and the tag names and limits every backend shares.
(Split from :mod:`benchmark.tracking.base`, which re-exports all of it.)"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from enum import Enum

# Tag under which the stable hash of a (variant, seed, config) is stored; find_finished_run
# looks it up so a reproduction never redoes a finished run.
RUN_KEY_TAG = "run_key"
# MLflow's own tags: the experiment kind that opens the classic (not GenAI) view, and the
# description shown on top of an experiment or a run page (Markdown).
EXPERIMENT_KIND_TAG = "mlflow.experimentKind"
EXPERIMENT_KIND = "custom_model_development"
DESCRIPTION_TAG = "mlflow.note.content"
# Why a run ended FAILED (Run.fail, or the exception that ended a ``with`` block), cut to
# MLflow's tag value limit (mlflow.utils.validation.MAX_TAG_VAL_LENGTH = 8000 characters).
FAILURE_REASON_TAG = "failure_reason"
MAX_TAG_VALUE = 8000


class RunStatus(str, Enum):
    """Terminal and live states, spelled as MLflow spells them."""

    RUNNING = "RUNNING"
    FINISHED = "FINISHED"
    FAILED = "FAILED"
    KILLED = "KILLED"


@dataclass(frozen=True)
class RunInfo:
    """What :meth:`Tracker.find_finished_run` returns about a stored run.

    ``metrics`` holds the latest value of each metric; ``backend`` is ``"mlflow"`` or ``"local"``.
    """

    run_id: str
    experiment: str
    run_name: str
    status: str
    tags: Mapping[str, str] = field(default_factory=dict)
    params: Mapping[str, str] = field(default_factory=dict)
    metrics: Mapping[str, float] = field(default_factory=dict)
    artifact_uri: str = ""
    backend: str = ""
    start_time_ms: int | None = None
    end_time_ms: int | None = None


@dataclass(frozen=True)
class DatasetRef:
    """A dataset a run read, for :meth:`Run.log_input` (MLflow's Datasets column).

    ``digest`` identifies the content (the manifest's sha256), ``name`` the dataset (its directory
    name), ``source`` where it lives (its path), ``context`` the split read (``"standard/train"``).
    """

    name: str
    digest: str
    source: str
    context: str


@dataclass(frozen=True)
class TrackerSpec:
    """What another process needs to build the same tracker (picklable):
    ``benchmark.tracking.tracker_from_spec``. ``kind`` is ``"mlflow"``, ``"local"`` or ``"null"``;
    ``uri`` the MLflow tracking URI or the local root; the two paths are an MLflow tracker's."""

    kind: str
    uri: str = ""
    artifact_root: str | None = None
    fallback_dir: str | None = None


@dataclass(frozen=True)
class MetricPoint:
    key: str
    value: float
    step: int
    timestamp_ms: int


def cut_text(text: str, limit: int) -> str:
    """``text`` cut to ``limit`` characters, an ellipsis marking the cut."""
    return text if len(text) <= limit else text[: limit - 1] + "…"


def failed_note(description: str, reason: str) -> str:
    """A run's note after it failed: its description, then the reason (Markdown), within
    MLflow's tag limit; the description is kept whole where it fits, the reason is cut first."""
    head = f"{description.rstrip()}\n\n" if description.strip() else ""
    room = MAX_TAG_VALUE - len(head) - len("**FAILED**: ")
    if room < 200:  # a description near the limit: keep the reason readable, cut the description
        head = cut_text(head, MAX_TAG_VALUE - 1200) + "\n\n"
        room = MAX_TAG_VALUE - len(head) - len("**FAILED**: ")
    return f"{head}**FAILED**: {cut_text(reason, room)}"
