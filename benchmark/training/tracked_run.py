"""``uavbench train``: train one variant from a config, evaluate it, track it in MLflow.

It connects the training loop (which knows nothing of tracking) to a tracker
through ``on_epoch_end``. Example::

    uavbench train --set data.root=data/quick-s0 --set model.attitude=re_net_r --set optim.epochs=5

Every head and encoder option is settable, e.g. ``--set model.attitude_options.hidden=512``,
``--set model.attitude=pd_net_e --set model.attitude_options.direction_weight=0``,
``--set model.encoder_options.norm=batch``.

Training and evaluation are ``benchmark.training.pipeline.train_and_evaluate``, the path every
``uavbench reproduce`` unit takes (same files: ``train/checkpoint.pt``, ``eval/<split>.csv/.json``
with the true and the swapped satellite image, ``history.json``, ``config.yaml``), and the run's
key and tags are ``benchmark.training.identity``'s, a reproduce unit's. The flattened config
becomes the run's params; per-epoch metrics are logged in batches; the evaluation CSVs, the config
and the history are artifacts. Divergence (a non-finite training loss at any step, weight,
validation or evaluation number: ``benchmark.training.loop.DivergenceError``) ends the run FAILED
with the reason (a :class:`TrainResult` with ``failure`` set: exit code 1, one line); a full disk or
a refused permission while writing the checkpoint or the outputs is an ``InputError`` naming the
path and the fix (exit 2), the previous checkpoint intact. Ctrl-C ends the run KILLED, and the same
command resumes from the last epoch's checkpoint and the evaluations already written.

:func:`train_tracked` returns what happened (:class:`TrainResult`); ``benchmark.commands.train``
prints it and picks the exit code.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from benchmark.models.device import Placement
from benchmark.training.config import TrainConfig

EXPERIMENT_TEXT = (
    "Runs of `uavbench train`: one run per trained config and seed, open while it trains and "
    "evaluates (per-epoch curves, system metrics), with its dataset, every split's numbers "
    "(`<split>/<metric>`, `/swap`: another place's satellite image) and the trained model. The "
    "tag `model_key` is the key a `uavbench reproduce` unit of the same config and data has."
)


@dataclass(frozen=True)
class TrainRunConfig:
    """One ``uavbench train``: the train config ``cfg`` (its frozen encoder resolved,
    ``data.root`` set) on ``placement`` (``cfg.device``/``cfg.precision`` resolved and checked
    once), evaluated on ``eval_splits``, outputs in ``out`` (None: ``runs/train-<run key>``),
    tracked in ``experiment`` of ``tracking_uri`` (None: ./mlflow.db) unless not ``track``;
    ``force``: train even when a finished run of this model exists."""

    cfg: TrainConfig
    placement: Placement
    eval_splits: tuple[str, ...] = ("standard/test",)
    out: Path | None = None
    experiment: str = "train"
    tracking_uri: str | None = None
    track: bool = True
    force: bool = False
    progress: bool = True


# The headline metrics of a split, in the order they are printed.
HEADLINE_KEYS = ("dtheta_deg", "dgamma_deg", "dpsi_deg", "dphi_deg", "dE_m", "dN_m", "dU_m")


@dataclass(frozen=True)
class TrainResult:
    """What one :func:`train_tracked` did. ``out``: the outputs directory; ``tracking_uri``: the
    store the run went to (``"null"`` untracked); ``metrics``: split -> its evaluation summary.
    ``finished_before``: the run (``"<id> (<backend>)"``) that already had this model and these
    splits, so nothing was trained (None: trained now). ``failure``: why the run failed (it
    diverged; marked FAILED when tracked), ``""`` when it did not."""

    out: Path
    tracking_uri: str
    metrics: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    finished_before: str | None = None
    failure: str = ""

    @property
    def ok(self) -> bool:
        """The model is trained and evaluated (now or by an earlier run)."""
        return not self.failure

    def lines(self) -> list[str]:
        """What ``uavbench train`` prints at the end: one line of headline metrics per split and
        where the outputs are, or the run that had it done already (empty after a failure: the
        command prints :attr:`failure`)."""
        if self.failure:
            return []
        if self.finished_before is not None:
            return [f"already finished: run {self.finished_before} has this model and these splits"]
        lines = []
        for split, summary in self.metrics.items():
            cells = ", ".join(f"{k}={summary[k]:.3f}" for k in HEADLINE_KEYS if k in summary)
            lines.append(f"{split}: n={int(summary['n'])} {cells}")
        return [*lines, f"outputs in {self.out}; tracked in {self.tracking_uri}"]


def train_tracked(config: TrainRunConfig) -> TrainResult:
    """Train, evaluate and track ``config``, unless a finished run has it already (and not
    ``config.force``). Returns what happened (:class:`TrainResult`: the metrics per split, the
    earlier run, or the failure of a run that diverged, marked FAILED). Raises
    :class:`~benchmark.errors.InputError` for bad data or splits and for disk errors."""
    from benchmark.config import ConfigError, flatten
    from benchmark.data import list_splits
    from benchmark.errors import InputError
    from benchmark.tracking import (
        RUN_KEY_TAG,
        DatasetRef,
        create_tracker,
        git_commit,
        manifest_sha256,
    )
    from benchmark.training.identity import run_key, run_tags
    from benchmark.training.pipeline import eval_keys

    cfg, placement = config.cfg, config.placement
    eval_splits = list(config.eval_splits)
    try:
        manifest = manifest_sha256(cfg.data.root)
    except FileNotFoundError as err:
        raise InputError(f"data.root: {err}") from None
    available = list_splits(cfg.data.root)
    wanted = {f"data.train_split {s}": s for s in cfg.data.train_split.split("+")}
    wanted["data.val_split"] = cfg.data.val_split
    wanted.update({f"eval_splits {s}": s for s in eval_splits})
    for what, split in wanted.items():
        if split is not None and split not in available:
            raise InputError(
                f"{what}={split!r} is not a split of {cfg.data.root}; available: "
                f"{', '.join(available)}"
            )
    # The trained model's identity and tags, computed as for a reproduce unit
    # (benchmark.training.identity): config without paths, dataset content, head versions.
    key = run_key(cfg, manifest, placement.precision)
    out = config.out or Path("runs") / f"train-{key}"

    tracker = create_tracker("mlflow" if config.track else "null", config.tracking_uri)
    done = tracker.find_finished_run(config.experiment, key)
    if done is not None and not config.force:
        logged = {k.rpartition("/")[0] for k in done.metrics}
        if set(eval_keys(eval_splits)) <= logged:
            return TrainResult(out, tracker.uri, finished_before=f"{done.run_id} ({done.backend})")
    tags = {
        **run_tags(cfg, manifest, placement),
        RUN_KEY_TAG: key,
        "git_commit": git_commit() or "unknown",
        "output_dir": str(out.resolve()),
    }
    variant = "plain" if cfg.model.variant == "/" else cfg.model.variant
    name = f"{cfg.model.attitude}/{variant}/seed{cfg.seed}"
    from benchmark.data import DatasetError, os_error_message
    from benchmark.training.loop import CheckpointMismatchError, DivergenceError

    tracker.describe_experiment(config.experiment, EXPERIMENT_TEXT)
    m = cfg.model
    text = (
        f"`uavbench train`: attitude head `{m.attitude}`, translation head `{m.translation}`, "
        f"encoder {m.encoder} `{m.variant}` width {m.width:g}, seed {cfg.seed}; trained on "
        f"`{cfg.data.train_split}`, evaluated on {', '.join(f'`{s}`' for s in eval_splits)}. "
        f"Outputs in `{out.resolve()}`."
    )
    root = Path(cfg.data.root).resolve()
    try:
        with tracker.start_run(config.experiment, name, tags=tags, description=text) as tracked:
            tracked.log_params(flatten(cfg, drop_none=True))
            tracked.log_input(DatasetRef(root.name, manifest, str(root), cfg.data.train_split))
            summaries = _train_and_evaluate(
                cfg, out, eval_splits, tracked, placement, progress=config.progress
            )
    except DivergenceError as err:  # a failure of the run (exit 1), recorded as its reason
        tracked_in = "" if not config.track else f"; the run is marked FAILED in {tracker.uri}"
        return TrainResult(out, tracker.uri, failure=f"{err}{tracked_in}")
    except (ConfigError, DatasetError, CheckpointMismatchError) as err:
        raise InputError(str(err)) from None
    except OSError as err:  # disk full or no permission writing the checkpoint or the outputs
        if err.filename is None:  # a bare write error (e.g. from a CSV writer): name the outputs
            err = OSError(err.errno, err.strerror, str(out))
        message = os_error_message(err)
        if message is None:
            raise
        raise InputError(message) from None
    return TrainResult(out, tracker.uri, metrics=summaries)


def _train_and_evaluate(
    cfg: TrainConfig,
    out: Path,
    eval_splits: list[str],
    tracked,
    placement: Placement,
    *,
    progress: bool,
) -> dict:
    """The one train-then-evaluate path (benchmark.training.pipeline), logged to ``tracked``."""
    from benchmark.training.pipeline import train_and_evaluate

    def on_epoch_end(epoch: int, record: dict[str, float]) -> None:
        tracked.log_metrics(record, step=epoch)
        tracked.flush()  # live: the UI draws the curve as the epochs end

    with tracked.system_metrics():
        done = train_and_evaluate(
            cfg,
            out,
            eval_splits,
            on_epoch_end=on_epoch_end,
            progress=progress,
            placement=placement,
        )
    tracked.log_artifact(out / "config.yaml")
    tracked.log_artifact(out / "history.json")
    for key, summary in done.metrics.items():
        tracked.log_metrics({f"{key}/{k}": v for k, v in summary.items()}, step=cfg.optim.epochs)
    if eval_splits:
        tracked.log_artifact(out / "eval")
    _log_model(cfg, done, tracked)
    return done.metrics


def _log_model(cfg, done, tracked) -> None:
    """The trained model, servable (``benchmark.tracking.models.PosePredictor``), with the first
    two training pairs as its input example."""
    from benchmark.tracking.models import PosePredictor

    example = model_input_example(cfg)
    model = done.trained.model.eval().to("cpu")  # logged and served on the CPU, as trained
    uri = tracked.log_model(PosePredictor(model), example)
    if uri:
        tracked.set_tags({"model_uri": uri})


def model_input_example(cfg: TrainConfig, pairs: int = 2) -> np.ndarray:
    """The first ``pairs`` pairs of the (first) training split, packed with their context: the
    ``(pairs, 13, H, W)`` float32 input example of a logged model
    (``benchmark.tracking.models.pack_items``; a gravity-aided model cannot run without the
    context's sensor priors)."""
    from benchmark.data import PairDataset
    from benchmark.tracking.models import pack_items

    first = cfg.data.train_split.split("+")[0]  # several joined training splits: the first
    data = PairDataset(cfg.data.root, first, verify=cfg.data.verify)
    return pack_items([data[i] for i in range(min(pairs, len(data)))]).numpy()
