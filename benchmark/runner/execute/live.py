"""A unit's training run, logged live from the worker process that trains it.

The parent process describes the run (:class:`UnitTracking`, picklable: the tracker's
``TrackerSpec``, experiment, name, tags, description, dataset); the worker rebuilds the tracker
(``benchmark.tracking.tracker_from_spec``, once per process) and:

1. :func:`open_unit_run` when training starts: reuses a FINISHED run of the unit (nothing is
   logged again), continues the latest unfinished one (KILLED, FAILED or left RUNNING by a killed
   process: same run, its start time kept, epochs already logged not repeated; never a RUNNING
   run whose owning invocation still lives, see ``invocations.owner_lives``), or creates one;
2. :func:`track_unit`: logs each epoch's metrics as the epoch ends (``train_loss_*``, ``val_*``,
   ``lr``, ``pairs_per_s``, ``epoch_time_s``; step = epoch; sent at once, so the UI draws curves
   during the reproduction), CPU and memory while training, then every evaluation
   (``<split>/<metric>``), the predictions, config and history as artifacts and the trained model
   (``benchmark.tracking.models.PosePredictor``), and the run ends when evaluation ends.

Several workers write to one store at once: over HTTP the server serialises them; on the embedded
sqlite store each write is a short transaction and sqlite's busy timeout makes a writer wait for
the other (tests/tracking/test_live.py runs two workers on one sqlite store).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmark.models.device import Placement
from benchmark.runner.plan.invocations import OWNER_TAGS, owner_lives
from benchmark.tracking import (
    RUN_KEY_TAG,
    DatasetRef,
    Run,
    RunInfo,
    RunStatus,
    TrackerSpec,
    tracker_from_spec,
)
from benchmark.training.config import TrainConfig
from benchmark.training.identity import device_tags, placement_of
from benchmark.training.loop import EpochCallback
from benchmark.training.pipeline import TrainEvalResult, train_and_evaluate

EPOCH_METRIC = "epoch"  # logged every epoch: a continued run knows which epochs it already has
EXAMPLE_PAIRS = 2  # pairs in a logged model's input example


@dataclass(frozen=True)
class UnitTracking:
    """How a worker logs one unit's training run (built by ``Logbook.unit_tracking``)."""

    spec: TrackerSpec
    experiment: str
    run_name: str
    unit_key: str  # a rerun finds this unit's run by it (stored as the tag RUN_KEY_TAG)
    tags: dict[str, str] = field(default_factory=dict)
    description: str = ""
    dataset: DatasetRef | None = None
    system_metrics_s: float = 2.0  # sampling interval of CPU / memory (a sample per interval)
    log_model: bool = True  # False: --no-models (the checkpoint stays in the unit directory)


def open_unit_run(t: UnitTracking) -> tuple[Run | None, RunInfo | None]:
    """``(run, None)`` to log into (new or continued), or ``(None, info)`` of the unit's
    FINISHED run, which is reused as it is."""
    tracker = tracker_from_spec(t.spec)
    found = tracker.find_runs(t.experiment, t.unit_key)
    finished = [info for info in found if info.status == RunStatus.FINISHED.value]
    if finished:
        return None, finished[0]
    # A RUNNING run of a live invocation (another work directory on this store) is that
    # invocation's to write: never log into it from here.
    found = [i for i in found if i.status != RunStatus.RUNNING.value or not owner_lives(i.tags)]
    if found:  # interrupted earlier: continue that run, now owned by this invocation
        run = tracker.attach(found[0], reopen=True)
        owner = {k: t.tags[k] for k in OWNER_TAGS if k in t.tags}
        if owner:
            run.set_tags(owner)
        run.tags["_logged_epochs"] = str(int(found[0].metrics.get(EPOCH_METRIC, 0)))
        return run, None
    run = tracker.start_run(
        t.experiment,
        t.run_name,
        tags={**t.tags, RUN_KEY_TAG: t.unit_key},
        description=t.description,
    )
    if t.dataset is not None:
        run.log_input(t.dataset)
    return run, None


def track_unit(
    run: Run,
    t: UnitTracking,
    cfg: TrainConfig,
    unit_dir: Path,
    eval_splits: list[str],
    eval_batch: int,
    heartbeat: EpochCallback | None = None,
    fuse_splits: list[str] | tuple[str, ...] = (),
    volume_splits: list[str] | tuple[str, ...] = (),
    joint_splits: list[str] | tuple[str, ...] = (),
    placement: Placement | None = None,
) -> tuple[TrainEvalResult, str]:
    """Train and evaluate the unit into ``unit_dir``, logging to ``run`` as it goes; returns the
    results and the logged model's URI (``""`` if the backend keeps none). ``run`` is ended by
    the caller. ``heartbeat(epoch, record)`` is called at every epoch end too (replayed ones
    included). ``placement``: ``cfg``'s device and precision as this worker resolved them (None:
    resolved here); the run's ``device``/``precision``/``accelerator`` tags are written from it,
    here, where the model computes."""
    if placement is None:
        placement = placement_of(cfg)
    run.set_tags(device_tags(cfg, placement))
    logged = int(run.tags.pop("_logged_epochs", "0"))

    def on_epoch_end(epoch: int, record: dict[str, float]) -> None:
        if heartbeat is not None:
            heartbeat(epoch, record)
        if epoch <= logged:  # a continued run already has it (the loop replays its history)
            return
        values = {k: v for k, v in record.items() if k != "epoch" and _finite(v)}
        run.log_metrics({**values, EPOCH_METRIC: epoch}, step=epoch)
        run.flush()  # now, not at the end of a batch: the UI draws the curve as it grows

    with run.system_metrics(t.system_metrics_s):
        done = train_and_evaluate(
            cfg,
            unit_dir,
            eval_splits,
            on_epoch_end=on_epoch_end,
            eval_batch=eval_batch,
            fuse_splits=fuse_splits,
            volume_splits=volume_splits,
            joint_splits=joint_splits,
            placement=placement,
        )
    for key, summary in done.metrics.items():
        finite = {f"{key}/{k}": v for k, v in summary.items() if _finite(v)}
        run.log_metrics(finite, step=cfg.optim.epochs)
    for split, (summary, _) in done.sequences.items():  # the flight fusion (issue 39)
        finite = {f"{split}/{k}": v for k, v in summary.items() if _finite(v)}
        run.log_metrics(finite, step=cfg.optim.epochs)
    for split, (summary, _) in done.volume_sequences.items():  # the pose volume, fused
        finite = {f"{split}/volume_{k}": v for k, v in summary.items() if _finite(v)}
        run.log_metrics(finite, step=cfg.optim.epochs)
    for split, (summary, _) in done.joint_sequences.items():  # ... and jointly
        finite = {f"{split}/volume_joint_{k}": v for k, v in summary.items() if _finite(v)}
        run.log_metrics(finite, step=cfg.optim.epochs)
    for name in ("config.yaml", "history.json"):
        if (unit_dir / name).is_file():
            run.log_artifact(unit_dir / name)
    if (unit_dir / "eval").is_dir():
        run.log_artifact(unit_dir / "eval")  # predictions: once per unit, not per table row
    model_uri = run.log_model(_predictor(done), _input_example(cfg)) if t.log_model else ""
    if model_uri:
        run.set_tags({"model_uri": model_uri})
    return done, model_uri


def _predictor(done: TrainEvalResult):
    from benchmark.tracking.models import PosePredictor

    return PosePredictor(done.trained.model.eval())


def _input_example(cfg: TrainConfig) -> np.ndarray:
    """The first :data:`EXAMPLE_PAIRS` training pairs with their context: the model's
    ``(b, 13, H, W)`` input (``benchmark.training.tracked_run.model_input_example``)."""
    from benchmark.training.tracked_run import model_input_example

    return model_input_example(cfg, EXAMPLE_PAIRS)


def _finite(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
