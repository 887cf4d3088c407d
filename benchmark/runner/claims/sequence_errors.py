"""The numbers of the ``sequence`` table (issue 39): every head fused along its flights, read from
the units' fusion files, with their intervals. Functions of results, computed before the report
is written (``benchmark.runner.claims.report_numbers``); ``benchmark.runner.report.sequence``
renders them.

A ``kind: sequence`` spec's units write, per fused split, ``eval/<split>.sequence.csv``
(``benchmark.evaluation.sequence_eval``): one row per (odometry, mode, pair). Here, per split and
head, on the dataset's odometry:

- per frame / causal filter / smoother: mean and median δψ, mean δφ, acc@10° (the fraction of
  frames with δφ <= 10°) and the median horizontal error, each the mean over seeds;
- the paired gain of fusion on δφ, smoothed minus per-frame and filtered minus per-frame, on the
  same frames, with the 95 % flight x seed bootstrap interval (seeds paired: one seed's run gives
  all three modes).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from benchmark.evaluation.paired import median_bootstrap, pooled_bootstrap
from benchmark.models.matching_options import MatchingOptions
from benchmark.runner.execute.non_learned import CONSTANT, NonLearnedFusion
from benchmark.runner.execute.reference_rows import CONSTANT_LABEL
from benchmark.runner.execute.worker import (
    eval_key,
    eval_paths,
    fusion_paths,
)
from benchmark.runner.plan.specs import TableSpec
from benchmark.runner.plan.units import Unit

MODES = ("frame", "filter", "smooth")
N_BOOT = 2000


@dataclass(frozen=True)
class SequenceErrors:
    """One (head, split): ``errors[odometry][mode][column]`` ``(S, N)`` over the S seeds on the
    same N frames (rows sorted by pair index), ``flight (N,)``, ``t_s (N,)``."""

    label: str
    split: str
    errors: dict[str, dict[str, dict[str, np.ndarray]]]
    flight: np.ndarray
    t_s: np.ndarray
    learned: bool = True  # False: the constant predictor or a non-learned reference
    control: bool = False  # the UAV-only control (no satellite image)
    position_given: bool = False  # a reference given the true position: no horizontal error
    # (S, N) δφ in degrees of the same frames with the true yaw and the row's own pitch and
    # roll: what no fusion of the yaw can go below (None: not recorded, e.g. a reference)
    exact_yaw_dphi: np.ndarray | None = None


def _read(path: Path) -> pd.DataFrame:
    return pd.read_csv(path).sort_values(["odometry", "mode", "index"], kind="stable")


# Whose pitch and roll a ``best_on_val`` volume row takes: ``(label, {volume unit key: head
# unit})`` (:func:`best_pitch_roll_head`), None when no candidate has validation numbers.
PitchRollChoice = tuple[str, dict[str, Unit]] | None


def _planned(spec: TableSpec, units: list[Unit], label: str) -> list[Unit]:
    """The units of row ``label`` of ``spec``, in seed order."""
    return sorted((u for u in units if _plans(u, spec.name, label)), key=lambda u: u.cfg.seed)


def pitch_roll_choices(
    spec: TableSpec, units: list[Unit], workdir: Path
) -> dict[str, PitchRollChoice]:
    """The choice of every ``pitch_roll: best_on_val`` row of ``spec``, by label: made once per
    report (every split of the row reads the same one)."""
    return {
        job.label: best_pitch_roll_head(spec, units, workdir, _planned(spec, units, job.label))
        for job in spec.jobs()
        if job.pitch_roll == "best_on_val"
    }


def load_sequences(
    spec: TableSpec,
    units: list[Unit],
    workdir: Path,
    splits: tuple[str, ...] | None = None,
    choices: dict[str, PitchRollChoice] | None = None,
) -> list[SequenceErrors]:
    """Every (row, split) of ``spec`` whose units' sequence files exist, seeds stacked; only the
    ``splits`` given (None: all); ``choices``: :func:`pitch_roll_choices` (None: made here)."""
    if choices is None:
        choices = pitch_roll_choices(spec, units, workdir)
    out = []
    for job in spec.jobs():
        mine = _planned(spec, units, job.label)
        where = fusion_paths(job.beliefs)
        label, attitude_from = job.label, {u.key: u for u in mine}
        if job.pitch_roll == "best_on_val":
            chosen = choices.get(job.label)
            if chosen is None:
                continue  # no candidate has validation numbers for every seed
            label, attitude_from = f"{job.label} ({chosen[0]})", chosen[1]
        for split in job.eval_splits:
            if splits is not None and split not in splits:
                continue
            found = [u for u in mine if where(workdir / "units" / u.key, split)[0].is_file()]
            frames = [_read(where(workdir / "units" / u.key, split)[0]) for u in found]
            if frames and label != job.label:  # δφ with the chosen head's pitch and roll
                frames = [
                    _with_pitch_roll(f, workdir / "units" / attitude_from[u.key].key, split)
                    for u, f in zip(found, frames, strict=True)
                ]
                if any(f is None for f in frames):
                    continue
            if frames:
                blank = job.row.get("satellite_input") == "blank"
                item = _stacked(label, split, frames, control=blank)
                exact = [_exact_yaw_dphi(workdir / "units" / attitude_from[u.key].key, split, f)
                         for u, f in zip(found, frames, strict=True)]  # fmt: skip
                if all(e is not None for e in exact):
                    item = dataclasses.replace(item, exact_yaw_dphi=np.stack(exact))
                out.append(item)
    return out


def _protocol(unit: Unit) -> str:
    model = unit.cfg.model
    if model.encoder != "matching":
        return ""
    return MatchingOptions.from_flat(model.encoder_options).loss.protocol


# The label of a ``best_on_val`` volume row whose own unit's head has the best pitch and roll.
OWN_HEAD = "its own head"


def _val_pitch_roll(unit: Unit, workdir: Path) -> float | None:
    """Mean δθ + δγ of ``unit`` on its validation split (None without that evaluation)."""
    if unit.val_split is None:
        return None
    path = eval_paths(workdir / "units" / unit.key, eval_key(str(unit.val_split), "true"))[0]
    if not path.is_file():
        return None
    val = pd.read_csv(path, usecols=["dtheta_deg", "dgamma_deg"])
    return float(val["dtheta_deg"].mean() + val["dgamma_deg"].mean())


def _plans(unit: Unit, table: str, label: str) -> bool:
    return any(j.table == table and j.label == label for j in unit.jobs)


def _same_encoder(head: Unit, volume: Unit) -> bool:
    """Whether ``head`` reads the features of ``volume``'s encoder: the same unit, or heads on
    the same frozen shared encoder with the same protocol."""
    if head.key == volume.key:
        return True
    key = head.cfg.pretrained.key if head.cfg.pretrained.enabled else None
    return (
        key is not None
        and key == volume.cfg.pretrained.key
        and (_protocol(head) == _protocol(volume))
    )


def best_pitch_roll_head(
    spec: TableSpec, units: list[Unit], workdir: Path, volume_units: list[Unit]
) -> tuple[str, dict[str, Unit]] | None:
    """Whose pitch and roll a ``pitch_roll: best_on_val`` volume row takes: among the head rows
    of ``spec`` that read the satellite image, from the encoder and with the protocol of
    ``volume_units`` (one per seed), and the volume units' own head (:data:`OWN_HEAD`), the one
    with the lowest mean δθ + δγ on its units' validation split, averaged over the seeds (spec
    order breaks a tie, the own head last). Chosen on the validation split only: no test number
    enters. ``(label, {volume unit key: that seed's head unit})``, or None when no candidate has
    validation numbers for every seed."""
    seeds = {int(u.cfg.seed): u for u in volume_units}
    candidates: list[tuple[str, list[Unit]]] = []
    for job in spec.jobs():
        if job.beliefs == "head" and job.row.get("satellite_input") != "blank":
            mine = [u for u in units if _plans(u, spec.name, job.label)]
            candidates.append((job.label, mine))
    candidates.append((OWN_HEAD, list(volume_units)))
    best: tuple[float, str, dict[str, Unit]] | None = None
    for label, mine in candidates:
        by_seed: dict[str, Unit] = {}
        scores = []
        for u in mine:
            volume = seeds.get(int(u.cfg.seed))
            if volume is None or volume.key in by_seed or not _same_encoder(u, volume):
                continue
            score = _val_pitch_roll(u, workdir)
            if score is not None:
                by_seed[volume.key] = u
                scores.append(score)
        if len(by_seed) == len(seeds) and (best is None or float(np.mean(scores)) < best[0]):
            best = (float(np.mean(scores)), label, by_seed)
    return None if best is None else (best[1], best[2])


def attitude_geodesic_deg(
    yaw_hat: np.ndarray,
    pitch_hat: np.ndarray,
    roll_hat: np.ndarray,
    yaw: np.ndarray,
    pitch: np.ndarray,
    roll: np.ndarray,
) -> np.ndarray:
    """Geodesic distance (degrees) between ``Rz(yaw_hat) Rx(pitch_hat) Ry(roll_hat)`` and the
    true ``Rz(yaw) Rx(pitch) Ry(roll)`` (paper Eq. 1; radians, ``(N,)`` each -> ``(N,)``): the
    intrinsic z-x'-y'' sequence of scipy's ``from_euler("ZXY")``."""
    estimate = Rotation.from_euler("ZXY", np.stack([yaw_hat, pitch_hat, roll_hat], axis=-1))
    truth = Rotation.from_euler("ZXY", np.stack([yaw, pitch, roll], axis=-1))
    return np.degrees((estimate.inv() * truth).magnitude())


def _with_pitch_roll(fused: pd.DataFrame, unit_dir: Path, split: str) -> pd.DataFrame | None:
    """``fused`` (a volume fusion table, sorted by :func:`_read`) with ``dphi_deg`` scored
    again: its fused yaw with the pitch and roll of the head unit at ``unit_dir`` on the same
    frames (its evaluation of ``split``). None when that evaluation is absent."""
    path = eval_paths(unit_dir, eval_key(split, "true"))[0]
    if not path.is_file():
        return None
    cols = ["index", "yaw_deg", "pitch_deg", "pitch_hat_deg", "roll_deg", "roll_hat_deg"]
    at = pd.read_csv(path, usecols=cols).set_index("index").loc[fused["index"].to_numpy()]
    rad = np.radians
    out = fused.copy()
    out["dphi_deg"] = attitude_geodesic_deg(
        rad(fused["yaw_hat_deg"].to_numpy(np.float64)),
        *(rad(at[c].to_numpy(np.float64)) for c in ("pitch_hat_deg", "roll_hat_deg", "yaw_deg",
                                                     "pitch_deg", "roll_deg")),
    )  # fmt: skip
    return out


def exact_yaw_geodesic_deg(
    pitch_hat: np.ndarray, roll_hat: np.ndarray, pitch: np.ndarray, roll: np.ndarray
) -> np.ndarray:
    """Geodesic distance (degrees) between ``Rz(psi) Rx(pitch_hat) Ry(roll_hat)`` and ``Rz(psi)
    Rx(pitch) Ry(roll)`` for any common yaw ``psi``: ``Rz`` cancels in ``R1^T R2 = Ry(-roll_hat)
    Rx(pitch - pitch_hat) Ry(roll)``. Angles in radians, ``(N,)`` each -> ``(N,)``."""
    # trace(Ry(-a) Rx(d) Ry(b)) = trace(Rx(d) Ry(b - a)) = cos e + cos d + cos d cos e, with
    # d the pitch difference and e the roll difference
    cd, ce = np.cos(pitch - pitch_hat), np.cos(roll - roll_hat)
    trace = ce + cd + cd * ce
    return np.degrees(np.arccos(np.clip((trace - 1.0) / 2.0, -1.0, 1.0)))


def _exact_yaw_dphi(unit_dir: Path, split: str, fused: pd.DataFrame) -> np.ndarray | None:
    """The unit's per-frame δφ with the true yaw (:func:`exact_yaw_geodesic_deg`) on the frames
    of its fusion table ``fused`` (sorted by :func:`_read`), from its evaluation of ``split``;
    None when that file is absent."""
    path = eval_paths(unit_dir, eval_key(split, "true"))[0]
    if not path.is_file():
        return None
    cols = ["index", "pitch_deg", "pitch_hat_deg", "roll_deg", "roll_hat_deg"]
    ev = pd.read_csv(path, usecols=cols).set_index("index")
    base = fused[(fused["odometry"] == "data") & (fused["mode"] == "frame")]
    at = ev.loc[base["index"].to_numpy()]
    rad = np.radians
    return exact_yaw_geodesic_deg(rad(at["pitch_hat_deg"].to_numpy()),
                                  rad(at["roll_hat_deg"].to_numpy()),
                                  rad(at["pitch_deg"].to_numpy()),
                                  rad(at["roll_deg"].to_numpy()))  # fmt: skip


def _stacked(label: str, split: str, frames: list[pd.DataFrame], **flags: bool) -> SequenceErrors:
    """The fusion tables of one row on one split (one per seed, rows sorted by
    :func:`_read`) stacked into a :class:`SequenceErrors`."""
    errors: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    first = frames[0]
    for odo, mode in first[["odometry", "mode"]].drop_duplicates().itertuples(index=False):
        cols = {}
        for col in ("dpsi_deg", "dphi_deg", "horizontal_m"):
            stack = []
            for f in frames:
                sel = f[(f["odometry"] == odo) & (f["mode"] == mode)]
                stack.append(sel[col].to_numpy(np.float64))
            cols[col] = np.stack(stack)
        errors.setdefault(str(odo), {})[str(mode)] = cols
    base = first[(first["odometry"] == "data") & (first["mode"] == "frame")]
    return SequenceErrors(
        label, split, errors, base["flight"].to_numpy(), base["t_s"].to_numpy(np.float64),
        **flags,
    )  # fmt: skip


def non_learned_sequences(fused: list[NonLearnedFusion]) -> list[SequenceErrors]:
    """The constant predictor's and the references' fused rows
    (:func:`~benchmark.runner.execute.non_learned.fuse_non_learned`, computed before the report)
    as :class:`SequenceErrors`, one "seed" each, in their order."""
    out = []
    for item in fused:
        label = CONSTANT_LABEL if item.row == CONSTANT else str(item.label)
        table = item.table.sort_values(["odometry", "mode", "index"], kind="stable")
        out.append(
            _stacked(label, item.split, [table], learned=False,
                     position_given=item.position_given)
        )  # fmt: skip
    return out


def sequence_rows(items: list[SequenceErrors], seed: int = 0) -> pd.DataFrame:
    """One row per (split, head, mode): the cells of the table, and the paired gains."""
    rows = []
    for item in items:
        modes = item.errors.get("data", {})
        frame = modes.get("frame")
        for mode in MODES:
            if mode not in modes:
                continue
            e = modes[mode]
            row = {
                "split": item.split,
                "label": item.label,
                "learned": item.learned,
                "control": item.control,
                "position_given": item.position_given,
                "mode": mode,
                "seeds": e["dpsi_deg"].shape[0],
                "flights": len(np.unique(item.flight)),
                "mean_dpsi_deg": float(e["dpsi_deg"].mean()),
                "median_dpsi_deg": float(np.median(e["dpsi_deg"], axis=1).mean()),
                "mean_dphi_deg": float(e["dphi_deg"].mean()),
                "acc10": float((e["dphi_deg"] <= 10.0).mean()),
                # the ceiling of acc@10 for any yaw fusion: the row's pitch and roll, true yaw
                "acc10_exact_yaw": (
                    float((item.exact_yaw_dphi <= 10.0).mean())
                    if item.exact_yaw_dphi is not None
                    else math.nan
                ),
                "median_horizontal_m": float(np.median(e["horizontal_m"], axis=1).mean()),
            }
            _, lo, hi = median_bootstrap(e["horizontal_m"], item.flight, N_BOOT, seed)
            row["median_horizontal_lo"], row["median_horizontal_hi"] = lo, hi
            if mode != "frame" and frame is not None:
                for col in ("dphi_deg", "dpsi_deg"):
                    d, lo, hi = pooled_bootstrap(frame[col], e[col], item.flight, N_BOOT, seed,
                                                 paired_seeds=True)  # fmt: skip
                    row[f"gain_{col}"], row[f"gain_{col}_lo"], row[f"gain_{col}_hi"] = d, lo, hi
            rows.append(row)
    return pd.DataFrame(rows)


@dataclass(frozen=True)
class SequenceTable:
    """The numbers of one ``kind: sequence`` spec: ``items`` (a head's or a non-learned row's
    per-frame errors per split, seeds stacked) and ``rows`` (:func:`sequence_rows`: the cells and
    the paired gains with their intervals)."""

    items: list[SequenceErrors]
    rows: pd.DataFrame


def sequence_numbers(
    spec: TableSpec,
    units: list[Unit],
    workdir: Path | None,
    non_learned: list[NonLearnedFusion] | None = None,
    splits: tuple[str, ...] | None = None,
    choices: dict[str, PitchRollChoice] | None = None,
) -> SequenceTable:
    """The :class:`SequenceTable` of ``spec`` from its units' fusion files under ``workdir``
    (none without it); with ``non_learned`` (the constant predictor and the spec's references
    fused before, ``execute.non_learned``) those rows beside the heads
    (:func:`non_learned_sequences`). ``splits``: only these (a work item of its own each);
    ``choices``: :func:`pitch_roll_choices`, made once for every split (None: made here)."""
    items = load_sequences(spec, units, workdir, splits, choices) if workdir is not None else []
    if items and non_learned:
        mine = [n for n in non_learned if splits is None or n.split in splits]
        items += non_learned_sequences(mine)
    return SequenceTable(items, sequence_rows(items))
