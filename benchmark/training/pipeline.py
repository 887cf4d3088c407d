"""Train, then evaluate: the one path of ``uavbench train`` and of each ``reproduce`` unit.

:func:`train_and_evaluate` trains (or resumes, or reuses the finished checkpoint) and evaluates
every requested split twice: with each pair's true satellite image, and with the satellite image of
another place (the satellite-swap probe, ``PairDataset(..., satellite="swap")``). Results are keyed
by :func:`eval_key`: ``standard/test`` and ``standard/test/swap``. The swap summary also holds the
paired per-frame effect of the swap on the yaw and geodesic errors with its 95% flight bootstrap
interval (``swap_dpsi_diff_deg``, ``swap_dpsi_boot_lo_deg``, ...,
``benchmark.evaluation.paired.swap_effect``), so the claims need no predictions files.

Layout of ``out_dir``::

    config.yaml                   the train config (``uavbench train --config`` reads it back)
    train/checkpoint.pt           written every epoch, resumed from (benchmark.training.loop)
    history.json                  per-epoch training and validation metrics
    eval/standard__test.csv       per-frame predictions, true satellite image
    eval/standard__test.json      its summary (written last: its presence means the split is done)
    eval/standard__test__swap.csv / .json   the same with the swapped satellite image
    eval/long__standard__sequence.csv / .json   a fused split's per-frame/filter/smoother table
    eval/long__standard__beliefs.npy   its yaw beliefs, recorded by the true image's pass; gone
                                  once the fusion is written
    eval/volume_calibration.json  a pair encoder's pose-volume temperature, fitted on the
                                  validation split before its volume is fused

Running it again costs nothing once its files are complete, so an interrupted run resumes where it
stopped: mid-training from the last epoch's checkpoint, after training from the evaluations already
written. Evaluation datasets are opened with ``cfg.data.verify`` and batches of ``eval_batch``;
the model evaluates on ``cfg.device`` in ``cfg.precision`` (``benchmark.models.device``).
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch.utils.data import Dataset

from benchmark.config import save_yaml
from benchmark.data.swap import SATELLITE_MODES
from benchmark.models.device import Placement, resolve_placement
from benchmark.training.build import run_training
from benchmark.training.config import TrainConfig
from benchmark.training.encoded import encode_for_heads, resolve_pretrained
from benchmark.training.loop import EpochCallback, TrainResult, check_finite, loader_workers

SWAP_SUFFIX = "/swap"
# The pose volume's temperatures (benchmark.evaluation.volume_beliefs.VolumeCalibration) that a
# volume's fusion is made with and records: the whole volume's, its yaw and position marginals'.
VOLUME_TEMPERATURES = ("temperature", "yaw_temperature", "position_temperature")
# ... and the calibration's keys a fused file must record to be current: the temperatures and the
# outlier weight they were fitted under (the fusion's own, FusionSettings.outlier_weight).
VOLUME_CALIBRATION_KEYS = (*VOLUME_TEMPERATURES, "outlier_weight")
EVAL_BATCH = 64  # pairs per evaluation batch (eval mode: per-sample results, any size would do)


def eval_key(split: str, satellite: str) -> str:
    """Where one evaluation's numbers live: ``split`` (true image) or ``split + "/swap"``."""
    if satellite not in SATELLITE_MODES:
        raise ValueError(f"satellite must be one of {SATELLITE_MODES}, got {satellite!r}")
    return split if satellite == "true" else split + SWAP_SUFFIX


def eval_keys(splits: list[str] | tuple[str, ...]) -> list[str]:
    """Every key :func:`train_and_evaluate` fills for ``splits``, true then swap per split."""
    return [eval_key(s, m) for s in splits for m in SATELLITE_MODES]


def split_filename(split: str) -> str:
    """``height600/test -> height600__test`` (file-system safe, reversible enough to read)."""
    return re.sub(r"[^A-Za-z0-9_.-]", "_", split.replace("/", "__"))


def eval_paths(out_dir: str | Path, key: str) -> tuple[Path, Path]:
    """``(csv, json)`` of one :func:`eval_key` under ``out_dir/eval``."""
    stem = Path(out_dir) / "eval" / split_filename(key)
    return stem.with_suffix(".csv"), stem.with_suffix(".json")


@dataclass
class TrainEvalResult:
    """What :func:`train_and_evaluate` produced."""

    trained: TrainResult
    metrics: dict[str, dict[str, float]] = field(default_factory=dict)  # eval_key -> summary
    predictions: dict[str, Path] = field(default_factory=dict)  # eval_key -> CSV
    # split -> (summary, CSV) of the flight fusion (``eval/<split>.sequence.*``, issue 39)
    sequences: dict[str, tuple[dict[str, float], Path]] = field(default_factory=dict)
    # split -> (summary, CSV) of the pose volume's fusion (``eval/<split>__volume_sequence.*``)
    volume_sequences: dict[str, tuple[dict[str, float], Path]] = field(default_factory=dict)
    # split -> (summary, CSV) of the pose volume fused jointly over (heading, E, N)
    # (``eval/<split>__volume_joint_sequence.*``)
    joint_sequences: dict[str, tuple[dict[str, float], Path]] = field(default_factory=dict)

    @property
    def history(self) -> list[dict[str, float]]:
        return self.trained.history


def train_and_evaluate(
    cfg: TrainConfig,
    out_dir: str | Path,
    eval_splits: list[str] | tuple[str, ...],
    *,
    on_epoch_end: EpochCallback | None = None,
    progress: bool = False,
    datasets: tuple[Dataset, Dataset | None] | None = None,
    eval_batch: int = EVAL_BATCH,
    placement: Placement | None = None,
    fuse_splits: list[str] | tuple[str, ...] = (),
    volume_splits: list[str] | tuple[str, ...] = (),
    joint_splits: list[str] | tuple[str, ...] = (),
) -> TrainEvalResult:
    """Train ``cfg`` into ``out_dir/train`` (resuming), then evaluate each split of
    ``cfg.data.root`` in ``eval_splits`` with the true and the swapped satellite image (files
    already written are read back, not recomputed), all on ``placement`` (``cfg.device`` and
    ``cfg.precision`` resolved and checked once by the caller; None: here). See the module doc
    for the layout. ``fuse_splits`` (each also in ``eval_splits``) are fused along their flights
    afterwards (:func:`benchmark.evaluation.sequence_eval.evaluate_sequence`), calibrated on
    ``cfg.data.val_split``, which is then evaluated first. ``volume_splits`` (each also in
    ``eval_splits``) are fused with the pair encoder's own pose volume as the belief
    (:func:`benchmark.evaluation.sequence_eval.fuse_volume`; a pass over the images);
    ``joint_splits`` (each also in ``eval_splits``) jointly over (heading, E, N) as well
    (:func:`benchmark.evaluation.sequence_eval.fuse_volume_joint`; the same pass)."""
    calibrated = [*fuse_splits, *volume_splits, *joint_splits]
    if calibrated and cfg.data.val_split is None:
        raise ValueError(
            f"fused splits {calibrated} need a validation split to calibrate the beliefs "
            f"on; the config trained on {cfg.data.train_split!r} has none"
        )
    if calibrated:  # calibration reads the validation predictions: evaluate them first
        eval_splits = [cfg.data.val_split, *(s for s in eval_splits if s != cfg.data.val_split)]
    if placement is None:
        placement = resolve_placement(cfg.device, cfg.precision)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cfg = resolve_pretrained(cfg)  # a frozen encoder named by its checkpoint's digest
    save_yaml(cfg, out_dir / "config.yaml", header="uavbench train config")
    trained = run_training(
        cfg,
        out_dir / "train",
        on_epoch_end=on_epoch_end,
        progress=progress,
        datasets=datasets,
        placement=placement,
    )
    (out_dir / "history.json").write_text(json.dumps(trained.history, indent=1) + "\n")
    model = trained.model.eval()
    result = TrainEvalResult(trained)
    for split in eval_splits:
        for satellite in SATELLITE_MODES:  # true first: the swap summary compares with it
            key = eval_key(split, satellite)
            # A split to fuse records its beliefs in the true image's pass (the calibration
            # reads the validation predictions, evaluated first), so fusion needs no second pass.
            beliefs = satellite == "true" and split in fuse_splits and split != cfg.data.val_split
            result.metrics[key], result.predictions[key] = _evaluate_split(
                cfg, model, out_dir, split, satellite, eval_batch, progress, placement, beliefs
            )
    for split in fuse_splits:
        result.sequences[split] = _sequence_split(
            cfg, model, out_dir, split, eval_batch, progress, placement
        )
    volumes = list(dict.fromkeys([*volume_splits, *joint_splits]))
    if volumes:  # one calibration for every split the volume is fused on
        calibration = _volume_calibration(cfg, model, out_dir, eval_batch, progress, placement)
    for split in volumes:
        marginal, joint = _volume_split(
            cfg,
            model,
            out_dir,
            split,
            eval_batch,
            progress,
            placement,
            split in joint_splits,
            calibration,
        )
        if split in volume_splits:
            result.volume_sequences[split] = marginal
        if joint is not None:
            result.joint_sequences[split] = joint
    return result


def volume_sequence_paths(out_dir: str | Path, split: str) -> tuple[Path, Path]:
    """``(csv, json)`` of one split's fusion of the pose volume under ``out_dir/eval``."""
    stem = Path(out_dir) / "eval" / f"{split_filename(split)}__volume_sequence"
    return stem.with_suffix(".csv"), stem.with_suffix(".json")


def joint_sequence_paths(out_dir: str | Path, split: str) -> tuple[Path, Path]:
    """``(csv, json)`` of one split's joint (heading, E, N) fusion of the pose volume."""
    stem = Path(out_dir) / "eval" / f"{split_filename(split)}__volume_joint_sequence"
    return stem.with_suffix(".csv"), stem.with_suffix(".json")


def volume_calibration_path(out_dir: str | Path) -> Path:
    """The pose volume's temperature fitted on the unit's validation split
    (``eval/volume_calibration.json``;
    :func:`benchmark.evaluation.volume_beliefs.fit_volume_temperature`)."""
    return Path(out_dir) / "eval" / "volume_calibration.json"


def fusion_done(paths: Callable[[str | Path, str], tuple[Path, Path]], out_dir: str | Path,
                split: str) -> bool:  # fmt: skip
    """Whether one split's fused files under ``out_dir`` are complete and current: the summary
    JSON written (last), and for a pose volume's fusion, made with the calibrated volume (its
    summary holds every ``volume_<key>`` of :data:`VOLUME_CALIBRATION_KEYS`, the outlier weight
    the fusion's own; files of an older version are fused again)."""
    csv_path, json_path = paths(out_dir, split)
    if not (json_path.is_file() and csv_path.is_file()):
        return False
    if paths in (volume_sequence_paths, joint_sequence_paths):
        summary = json.loads(json_path.read_text())
        return _current_calibration(summary, "volume_")
    return True


def fusion_paths(beliefs: str) -> Callable[[str | Path, str], tuple[Path, Path]]:
    """Where a sequence row's fused files are, by what it fuses (``RowSpec.beliefs``): a head's
    beliefs, the pose volume's marginals, or the pose volume jointly."""
    paths = {"head": sequence_paths, "volume": volume_sequence_paths,
             "volume_joint": joint_sequence_paths}  # fmt: skip
    if beliefs not in paths:
        raise ValueError(f"beliefs must be one of {tuple(paths)}, got {beliefs!r}")
    return paths[beliefs]


def _current_calibration(record: dict[str, Any], prefix: str = "") -> bool:
    """Whether ``record`` (a calibration file, or a fused summary with ``prefix`` "volume_") holds
    every key of :data:`VOLUME_CALIBRATION_KEYS`, fitted under the fusion's outlier weight."""
    from benchmark.evaluation.sequence import FusionSettings

    if not all(f"{prefix}{k}" in record for k in VOLUME_CALIBRATION_KEYS):
        return False
    return float(record[f"{prefix}outlier_weight"]) == FusionSettings().outlier_weight


def _volume_calibration(
    cfg: TrainConfig,
    model: torch.nn.Module,
    out_dir: Path,
    batch_size: int,
    progress: bool,
    placement: Placement,
) -> dict[str, float]:
    """The pose volume's temperatures on ``cfg.data.val_split`` (read back if written): one
    encoder pass over the validation images, the true poses from its evaluation table (evaluated
    first), :func:`~benchmark.evaluation.volume_beliefs.fit_volume_temperature` under the
    fusion's own outlier weight (``FusionSettings.outlier_weight``: the likelihood the fusion
    reads is ``(1 - w) q + w u``, so its temperature is fitted for that, not for ``q`` alone)."""
    import pandas as pd

    from benchmark.data import PairDataset
    from benchmark.evaluation.sequence import FusionSettings
    from benchmark.evaluation.volume_beliefs import fit_volume_temperature, volume_marginals

    path = volume_calibration_path(out_dir)
    if path.is_file():
        written = json.loads(path.read_text())
        if _current_calibration(written):  # else: an older version's, fit again
            return written
    val_split = str(cfg.data.val_split)
    base = PairDataset(cfg.data.root, val_split, verify=cfg.data.verify)
    marginals = volume_marginals(
        model, base, batch_size=batch_size, shared_satellite=cfg.model.shared_satellite,
        precision=placement.precision, num_workers=loader_workers(cfg, placement.device),
        progress=progress, desc=f"volume {val_split} (calibration)", keep_volume=True,
    )  # fmt: skip
    val_csv, _ = eval_paths(out_dir, eval_key(val_split, "true"))
    truth = pd.read_csv(val_csv).set_index("index").loc[marginals.index.numpy()]
    assert marginals.log_volume is not None  # kept
    fitted = fit_volume_temperature(
        marginals.log_volume, (marginals.yaw, marginals.north, marginals.east), marginals.cell_m,
        torch.tensor(truth["yaw_deg"].to_numpy(float)).deg2rad(),
        torch.tensor(truth["E_m"].to_numpy(float)), torch.tensor(truth["N_m"].to_numpy(float)),
        outlier_weight=FusionSettings().outlier_weight,
    )  # fmt: skip
    calibration = {"split": val_split, **fitted.to_dict()}
    _write_json(calibration, path)
    return calibration


def _volume_split(
    cfg: TrainConfig,
    model: torch.nn.Module,
    out_dir: Path,
    split: str,
    batch_size: int,
    progress: bool,
    placement: Placement,
    joint: bool,
    calibration: dict[str, Any],
) -> tuple[tuple[dict[str, float], Path], tuple[dict[str, float], Path] | None]:
    """Fuse the pose volume of one split along its flights (its marginals and, if ``joint``,
    jointly over heading and position), or read what a previous run wrote: one encoder pass
    over the split's images, the volume tempered by ``calibration`` (:func:`_volume_calibration`),
    the heads' pitch and roll from the true image's evaluation table. Returns ``(marginal,
    joint or None)``, each ``(summary, csv)``; each summary holds the temperatures it was made
    with (``volume_temperature``, ``volume_yaw_temperature``, ``volume_position_temperature``)
    and the outlier weight they were fitted under (``volume_outlier_weight``)."""
    import pandas as pd

    from benchmark.data import PairDataset, odometry_noise
    from benchmark.evaluation.sequence_eval import STRESS_SCALE, fuse_volume, fuse_volume_joint
    from benchmark.evaluation.volume_beliefs import volume_marginals

    csv_path, json_path = volume_sequence_paths(out_dir, split)
    joint_csv, joint_json = joint_sequence_paths(out_dir, split)
    have = fusion_done(volume_sequence_paths, out_dir, split)
    have_joint = not joint or fusion_done(joint_sequence_paths, out_dir, split)
    if have and have_joint:
        return (json.loads(json_path.read_text()), csv_path), (
            (json.loads(joint_json.read_text()), joint_csv) if joint else None
        )
    tempers = {k: float(calibration[k]) for k in VOLUME_TEMPERATURES}
    recorded = {f"volume_{k}": float(calibration[k]) for k in VOLUME_CALIBRATION_KEYS}
    base = PairDataset(cfg.data.root, split, verify=cfg.data.verify)
    marginals = volume_marginals(
        model, base, batch_size=batch_size, shared_satellite=cfg.model.shared_satellite,
        precision=placement.precision, num_workers=loader_workers(cfg, placement.device),
        progress=progress, desc=f"volume {split}", keep_volume=joint and not have_joint,
        **tempers,
    )  # fmt: skip
    true_csv, _ = eval_paths(out_dir, eval_key(split, "true"))
    frame = pd.read_csv(true_csv)
    noise = odometry_noise(base.manifest["profile"])
    seed = int(base.manifest["seed"])
    stress = STRESS_SCALE if split.startswith("long/") else None
    if not have:
        summary, table = fuse_volume(
            frame, marginals, base.poses, base.sat_table, noise, split=split, seed=seed,
            stress_scale=stress,
        )  # fmt: skip
        _write_fusion(table, {**summary, **recorded}, csv_path, json_path)
    marginal = (json.loads(json_path.read_text()), csv_path)
    if not joint:
        return marginal, None
    if not have_joint:
        summary, table = fuse_volume_joint(
            frame, marginals, base.poses, base.sat_table, noise, split=split, seed=seed,
            stress_scale=stress, progress=progress,
        )  # fmt: skip
        _write_fusion(table, {**summary, **recorded}, joint_csv, joint_json)
    return marginal, (json.loads(joint_json.read_text()), joint_csv)


def _write_fusion(table: Any, summary: dict[str, float], csv_path: Path, json_path: Path) -> None:
    """A fused split's table, then its summary: the JSON written last (atomically) means done."""
    from benchmark.evaluation.metrics import write_predictions_csv

    write_predictions_csv(table, csv_path)
    _write_json(summary, json_path)


def _write_json(obj: Any, path: Path) -> None:
    """``obj`` as JSON at ``path``, atomically (a temporary file, then a rename): a reader sees
    the whole file or none."""
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(obj, indent=2))
    tmp.replace(path)


def sequence_paths(out_dir: str | Path, split: str) -> tuple[Path, Path]:
    """``(csv, json)`` of one split's flight fusion under ``out_dir/eval``."""
    # "__sequence" joined to the name: a ".sequence" suffix would be replaced by with_suffix
    stem = Path(out_dir) / "eval" / f"{split_filename(split)}__sequence"
    return stem.with_suffix(".csv"), stem.with_suffix(".json")


def beliefs_path(out_dir: str | Path, split: str) -> Path:
    """The yaw beliefs the true image's evaluation pass of ``split`` recorded for its fusion
    (``eval/<split>__beliefs.npy``; deleted once the fusion is written)."""
    return Path(out_dir) / "eval" / f"{split_filename(split)}__beliefs.npy"


def _calibration(cfg: TrainConfig, out_dir: Path, manifest: dict) -> tuple[Any, Any]:
    """The unit's belief calibration, from its validation predictions only."""
    import pandas as pd

    from benchmark.evaluation.beliefs import calibrate_from_predictions

    val_split = str(cfg.data.val_split)
    val_csv, _ = eval_paths(out_dir, eval_key(val_split, "true"))
    footprint = manifest["profile"]["sat_footprint_m"]
    return calibrate_from_predictions(
        pd.read_csv(val_csv), val_split, float(footprint[0]) * float(footprint[1])
    )


def _sequence_split(
    cfg: TrainConfig,
    model: torch.nn.Module,
    out_dir: Path,
    split: str,
    batch_size: int,
    progress: bool,
    placement: Placement,
) -> tuple[dict[str, float], Path]:
    """Fuse one split along its flights, or read what a previous run wrote. The beliefs come
    from the split's evaluation pass (:func:`beliefs_path`) when it recorded them, else from a
    pass of their own (a unit evaluated before fusion existed)."""
    import pandas as pd

    from benchmark.data import PairDataset, odometry_noise
    from benchmark.evaluation.evaluate import load_beliefs
    from benchmark.evaluation.sequence_eval import (
        POSITION_FROM_HEAD,
        STRESS_SCALE,
        evaluate_sequence,
        fuse_predictions,
        gives_position_density,
        head_position_belief,
    )

    csv_path, json_path = sequence_paths(out_dir, split)
    own_density = gives_position_density(model.translation_head)
    if json_path.is_file() and csv_path.is_file():
        summary = json.loads(json_path.read_text())
        # a fusion written before a head's own position density was used is done again
        if not own_density or summary.get(POSITION_FROM_HEAD) == 1.0:
            return summary, csv_path
    base = PairDataset(cfg.data.root, split, verify=cfg.data.verify)
    profile = base.manifest["profile"]
    calibration = _calibration(cfg, out_dir, base.manifest)
    passes: dict[str, Any] = {
        "batch_size": batch_size,
        "shared_satellite": cfg.model.shared_satellite,
        "precision": placement.precision,
        "num_workers": loader_workers(cfg, placement.device),
    }
    common: dict[str, Any] = {
        "split": split,
        "seed": int(base.manifest["seed"]),
        # the stress odometry (4x its noise) only where the figure draws it: the long flights
        "stress_scale": STRESS_SCALE if split.startswith("long/") else None,
    }
    dataset = (
        encode_for_heads(model, cfg, base, progress=progress, precision=placement.precision)
        if cfg.pretrained.enabled
        else base
    )
    stored = beliefs_path(out_dir, split)
    true_csv, _ = eval_paths(out_dir, eval_key(split, "true"))
    if stored.is_file() and true_csv.is_file():
        frame = pd.read_csv(true_csv)
        position = head_position_belief(model, dataset, frame, **passes) if own_density else None
        summary, table = fuse_predictions(
            frame,
            load_beliefs(stored, len(frame)),
            base.poses,
            base.sat_table,
            calibration,
            odometry_noise(profile),
            position_belief=position,
            **common,
        )
        summary[POSITION_FROM_HEAD] = float(own_density)
    else:
        summary, table = evaluate_sequence(
            model, dataset, base.poses, base.sat_table, calibration, odometry_noise(profile),
            progress=progress, **passes, **common,
        )  # fmt: skip
    _write_fusion(table, summary, csv_path, json_path)
    stored.unlink(missing_ok=True)  # an intermediate: the fusion table holds what it gave
    return summary, csv_path


def _evaluate_split(
    cfg: TrainConfig,
    model: torch.nn.Module,
    out_dir: Path,
    split: str,
    satellite: str,
    batch_size: int,
    progress: bool,
    placement: Placement,
    beliefs: bool = False,
) -> tuple[dict[str, float], Path]:
    """Evaluate one split in one satellite mode, or read the files a previous run wrote. With
    ``beliefs`` (the true image of a split to fuse), the same pass records the yaw beliefs
    for :func:`_sequence_split` unless that split's fusion is already written."""
    import pandas as pd

    from benchmark.data import PairDataset
    from benchmark.evaluation.evaluate import evaluate, finite_keys
    from benchmark.evaluation.paired import swap_effect
    from benchmark.evaluation.sequence_eval import sequence_belief_fn

    csv_path, json_path = eval_paths(out_dir, eval_key(split, satellite))
    if json_path.is_file() and csv_path.is_file():
        return json.loads(json_path.read_text()), csv_path
    dataset = PairDataset(cfg.data.root, split, verify=cfg.data.verify, satellite=satellite)
    record: dict[str, Any] = {}
    if beliefs and not all(p.is_file() for p in sequence_paths(out_dir, split)):
        attitude, _ = _calibration(cfg, out_dir, dataset.manifest)
        record = {
            "beliefs": sequence_belief_fn(attitude),
            "out_beliefs": beliefs_path(out_dir, split),
        }
    if cfg.pretrained.enabled:  # the heads on the frozen encoder's cached features
        dataset = encode_for_heads(
            model, cfg, dataset, progress=progress, precision=placement.precision
        )
    summary, _ = evaluate(
        model,
        dataset,
        out_csv=csv_path,
        batch_size=batch_size,
        shared_satellite=cfg.model.shared_satellite,
        progress=progress,
        desc=f"eval {eval_key(split, satellite)}",
        precision=placement.precision,
        num_workers=loader_workers(cfg, placement.device),
        **record,
    )
    # A diverged model (finite weights, overflowing outputs) fails here, before its summary is
    # written, so a rerun evaluates again instead of reading back non-finite numbers.
    check_finite("evaluation metric", f"evaluation of {eval_key(split, satellite)}", summary,
                 cfg.optim.lr, keys=finite_keys(summary))  # fmt: skip
    if satellite == "swap":
        # Both frames as written (10 significant digits): identical predictions give a zero
        # difference, not the rounding error of one of them.
        true_csv, _ = eval_paths(out_dir, eval_key(split, "true"))
        summary.update(swap_effect(pd.read_csv(true_csv), pd.read_csv(csv_path)))
    tmp = json_path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(summary, indent=2))
    tmp.replace(json_path)  # written last: its presence means the split is done
    return summary, csv_path
