"""The lineage part of :class:`~benchmark.tracking.mlflow_tracker.MlflowTracker`: dataset
inputs, logged models and system metrics (a mixin; it uses the tracker's client, guard and
fallback). mlflow is imported inside the methods only."""

from __future__ import annotations

import contextlib
import logging
import warnings
from collections.abc import Iterator
from typing import Any

from benchmark.tracking.base import DatasetRef, Run

# A dataset input's digest is at most 36 characters (mlflow.utils.validation): the first 32 hex
# digits of the manifest sha256 (128 bits); the full hash is the run tag dataset_manifest_sha256.
_MAX_DIGEST = 32


def dataset_inputs(datasets: list[DatasetRef]) -> list[Any]:
    """MLflow ``DatasetInput`` entities of ``datasets`` (for ``MlflowClient.log_inputs``): a
    MetaDataset per dataset (name, digest cut to MLflow's 36-character limit, source path) with
    the split read as its ``mlflow.data.context`` tag."""
    from mlflow.data.meta_dataset import MetaDataset
    from mlflow.data.sources import LocalArtifactDatasetSource
    from mlflow.entities import DatasetInput, InputTag
    from mlflow.utils.mlflow_tags import MLFLOW_DATASET_CONTEXT

    return [
        DatasetInput(
            MetaDataset(
                LocalArtifactDatasetSource(d.source), name=d.name, digest=d.digest[:_MAX_DIGEST]
            )._to_mlflow_entity(),
            tags=[InputTag(MLFLOW_DATASET_CONTEXT, d.context)],
        )
        for d in datasets
    ]


class LineageMixin:
    """Needs ``self._fallback`` (a LocalTracker or None), ``self._client``, ``self._guard`` and
    ``self.uri`` (see MlflowTracker)."""

    _fallback: Any
    _client: Any
    uri: str

    def _log_inputs(self, run: Run, datasets: list[DatasetRef]) -> None:
        if self._fallback is not None:
            self._fallback._log_inputs(run, datasets)
            return
        inputs = dataset_inputs(datasets)
        self._guard("log_inputs", self._client.log_inputs, run.run_id, inputs)

    def _log_model(self, run: Run, model: object, input_example: object, name: str) -> str:
        if self._fallback is not None:
            return self._fallback._log_model(run, model, input_example, name)
        from benchmark.tracking.models import log_pytorch_model

        try:
            return log_pytorch_model(model, input_example, run.run_id, self.uri, name)
        except Exception as err:  # a model that cannot be logged must not stop the work
            warnings.warn(f"could not log the model of run {run.run_name!r}: {err!r}", stacklevel=3)
            return ""

    @contextlib.contextmanager
    def _system_metrics(self, run: Run, interval_s: float) -> Iterator[None]:
        monitor = None
        if self._fallback is None:
            try:
                from mlflow.system_metrics.system_metrics_monitor import SystemMetricsMonitor

                # Its INFO lines (started / stopped) would print twice per unit.
                logging.getLogger("mlflow.system_metrics").setLevel(logging.WARNING)
                monitor = SystemMetricsMonitor(
                    run.run_id, sampling_interval=interval_s, tracking_uri=self.uri
                )
                monitor.start()
            except Exception as err:  # psutil missing, ...: train anyway
                warnings.warn(f"no system metrics for run {run.run_name!r}: {err!r}", stacklevel=3)
                monitor = None
        try:
            yield
        finally:
            if monitor is not None:
                monitor.finish()
