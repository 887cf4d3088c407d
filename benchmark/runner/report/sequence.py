"""The ``sequence`` table and figure (issue 39): every head fused along its flights.

A ``kind: sequence`` spec's units write, per fused split, ``eval/<split>.sequence.csv``
(``benchmark.evaluation.sequence_eval``): one row per (odometry, mode, pair). Here, per split and
head, on the dataset's odometry:

- per frame / causal filter / smoother: mean and median δψ, mean δφ, acc@10° (the fraction of
  frames with δφ <= 10°) and the median horizontal error, each the mean over seeds;
- the paired gain of fusion on δφ, smoothed minus per-frame and filtered minus per-frame, on the
  same frames, with the 95 % flight x seed bootstrap interval (seeds paired: one seed's run gives
  all three modes).

The figure: mean δψ of the causal filter against seconds of flight fused, a line per head on each
long split, with the dataset's odometry (solid) and the stress odometry (dashed).
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
from benchmark.runner.execute.worker import (
    eval_key,
    eval_paths,
    sequence_paths,
    volume_sequence_paths,
)
from benchmark.runner.plan.specs import TableSpec
from benchmark.runner.plan.units import Unit
from benchmark.runner.report.tables import CONSTANT_LABEL

MODES = ("frame", "filter", "smooth")
MODE_NAMES = {"frame": "per frame", "filter": "filtered", "smooth": "smoothed"}
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


def load_sequences(spec: TableSpec, units: list[Unit], workdir: Path) -> list[SequenceErrors]:
    """Every (row, split) of ``spec`` whose units' sequence files exist, seeds stacked."""
    out = []
    for job in spec.jobs():
        mine = sorted(
            (u for u in units if any(j.table == spec.name and j.label == job.label
                                     for j in u.jobs)),
            key=lambda u: u.cfg.seed,
        )  # fmt: skip
        where = volume_sequence_paths if job.beliefs == "volume" else sequence_paths
        label, attitude_from = job.label, {u.key: u for u in mine}
        if getattr(job, "pitch_roll", "own") == "best_on_val":
            chosen = best_pitch_roll_head(spec, units, workdir, mine)
            if chosen is None:
                continue  # no head row on the same encoder has validation numbers for every seed
            label, attitude_from = f"{job.label} ({chosen[0]})", chosen[1]
        for split in job.eval_splits:
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


def best_pitch_roll_head(
    spec: TableSpec, units: list[Unit], workdir: Path, volume_units: list[Unit]
) -> tuple[str, dict[str, Unit]] | None:
    """The head row of ``spec`` whose pitch and roll a ``pitch_roll: best_on_val`` volume row
    takes: among the rows that fuse a head's beliefs with the satellite image, on the shared
    encoder and with the protocol of ``volume_units`` (one per seed), the one with the lowest
    mean δθ + δγ on its units' validation split, averaged over the seeds (spec order breaks a
    tie). Chosen on the validation split only: no test number enters. ``(label, {volume unit
    key: that seed's head unit})``, or None when no row has validation numbers for every seed."""
    seeds = {int(u.cfg.seed): u for u in volume_units}
    best: tuple[float, str, dict[str, Unit]] | None = None
    for job in spec.jobs():
        if job.beliefs != "head" or job.row.get("satellite_input") == "blank":
            continue
        by_seed: dict[str, Unit] = {}
        scores = []
        for u in units:
            volume = seeds.get(int(u.cfg.seed))
            if (
                volume is None
                or volume.key in by_seed
                or not any(j.table == spec.name and j.label == job.label for j in u.jobs)
            ):
                continue
            key = u.cfg.pretrained.key if u.cfg.pretrained.enabled else None
            if key is None or key != volume.cfg.pretrained.key or _protocol(u) != _protocol(volume):
                continue
            path = eval_paths(workdir / "units" / u.key, eval_key(str(u.val_split), "true"))[0]
            if u.val_split is None or not path.is_file():
                continue
            val = pd.read_csv(path, usecols=["dtheta_deg", "dgamma_deg"])
            by_seed[volume.key] = u
            scores.append(float(val["dtheta_deg"].mean() + val["dgamma_deg"].mean()))
        if len(by_seed) == len(seeds) and (best is None or float(np.mean(scores)) < best[0]):
            best = (float(np.mean(scores)), job.label, by_seed)
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


def _fmt(x: float, digits: int = 1) -> str:
    return "–" if not math.isfinite(x) else f"{x:.{digits}f}"


def _interval(point: float, lo: float, hi: float) -> str:
    return f"{point:+.2f} [{lo:+.2f}, {hi:+.2f}]"


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


def sequence_markdown(spec: TableSpec, table: pd.DataFrame, figure: str | None) -> str:
    """The rendered table: a section per split, a row per (head, mode)."""
    lines = [f"# {spec.title}", ""]
    if spec.note:
        lines += [spec.note.strip(), ""]
    if not len(table):
        return "\n".join([*lines, "No sequence results yet (no unit wrote its fusion files).", ""])
    head = ("| head | estimate | mean δψ (°) | median δψ (°) | mean δφ (°) | acc@10° (δφ) | "
            "acc@10° (δφ) with the true yaw | median horizontal (m) [95 %] | "
            "Δ mean δφ vs per frame (°) [95 %] |")  # fmt: skip
    for split, part in table.groupby("split", sort=False):
        flights, seeds = int(part["flights"].iloc[0]), int(part["seeds"].max())
        lines += [f"## {split}", "", f"{flights} flights, {seeds} seed(s).", "", head,
                  "|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for _, r in part.iterrows():
            gain = (
                _interval(r["gain_dphi_deg"], r["gain_dphi_deg_lo"], r["gain_dphi_deg_hi"])
                if r["mode"] != "frame" and math.isfinite(r.get("gain_dphi_deg", math.nan))
                else "–"
            )
            horizontal = (f"{_fmt(r['median_horizontal_m'])} [{_fmt(r['median_horizontal_lo'])}, "
                          f"{_fmt(r['median_horizontal_hi'])}]")  # fmt: skip
            if bool(r.get("position_given", False)):
                horizontal = "given (true position)"
            exact = r.get("acc10_exact_yaw", math.nan)  # the same for every mode: shown once
            shown = r["mode"] == "frame" and math.isfinite(exact)
            ceiling = f"{100 * exact:.0f} %" if shown else "–"
            lines.append(
                f"| {r['label']} | {MODE_NAMES[r['mode']]} | {_fmt(r['mean_dpsi_deg'])} | "
                f"{_fmt(r['median_dpsi_deg'])} | {_fmt(r['mean_dphi_deg'])} | "
                f"{100 * r['acc10']:.0f} % | {ceiling} | {horizontal} | {gain} |"
            )
        lines.append("")
        distance = oracle_distance(part)
        if distance:
            lines += [distance, ""]
    if figure:
        lines += [f"![{spec.name}]({figure})", ""]
    return "\n".join(lines)


ORACLE_PREFIX = "Geometry oracle"


def oracle_distance(part: pd.DataFrame, mode: str = "smooth") -> str:
    """One sentence per split: how far the best fused learned row (mean δψ, ``mode``; a head's
    or the pose volume's, the UAV-only control left out) is from the fused geometry oracle
    (given the true position, pitch and roll: what the pixels allow at this heading search), ""
    without either."""
    fused = part[part["mode"] == mode]
    keep = fused["learned"].astype(bool) if "learned" in fused else fused["label"].isna()
    if "control" in fused:
        keep &= ~fused["control"].astype("boolean").fillna(False).astype(bool)
    learned = fused[keep]
    oracle = fused[fused["label"].str.startswith(ORACLE_PREFIX)]
    if not len(learned) or not len(oracle):
        return ""
    best = learned.loc[learned["mean_dpsi_deg"].idxmin()]
    ref = float(oracle["mean_dpsi_deg"].iloc[0])
    gap = float(best["mean_dpsi_deg"]) - ref
    return (
        f"Distance to the fused geometry oracle ({MODE_NAMES[mode]}, mean δψ): the best learned "
        f"row, {best['label']}, {_fmt(float(best['mean_dpsi_deg']))}° against the oracle's "
        f"{_fmt(ref)}°, {gap:+.1f}° ({'above' if gap > 0 else 'at or below'} it)."
    )


def sequence_figure(items: list[SequenceErrors], path: Path) -> bool:
    """Mean δψ of the causal filter against seconds fused, per head, on each long split (or every
    split when there is none): solid the dataset's odometry, dashed the stress odometry. False
    when there is nothing to draw."""
    long = [i for i in items if i.split.startswith("long/")] or items
    splits = list(dict.fromkeys(i.split for i in long))
    if not splits:
        return False
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(splits), figsize=(4.6 * len(splits), 3.6), squeeze=False)
    colours: dict[str, str] = {}
    cycle = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, split in zip(axes.flat, splits, strict=True):
        for item in (i for i in long if i.split == split):
            colour = colours.setdefault(item.label, cycle[len(colours) % len(cycle)])
            t = np.round(item.t_s, 6)
            for odo, style in (("data", "-"), *((o, "--") for o in item.errors if o != "data")):
                e = item.errors.get(odo, {}).get("filter")
                if e is None:
                    continue
                err = e["dpsi_deg"].mean(axis=0)
                times = np.unique(t)
                curve = [err[t == x].mean() for x in times]
                ax.plot(times, curve, style, color=colour, lw=1.2,
                        label=item.label if odo == "data" else None)  # fmt: skip
        ax.set_title(split)
        ax.set_xlabel("seconds of flight fused (causal filter)")
        ax.set_ylabel("mean δψ (°)")
        ax.grid(alpha=0.3)
    axes.flat[0].legend(fontsize=6, ncol=2)
    fig.suptitle("solid: the dataset's odometry; dashed: 4x its noise", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True


def sequence_report(
    spec: TableSpec,
    units: list[Unit],
    workdir: Path | None,
    out: Path,
    non_learned: list[NonLearnedFusion] | None = None,
) -> tuple[str, list[Path], pd.DataFrame]:
    """``(markdown, [figure path], table rows)`` of a ``kind: sequence`` spec; with
    ``non_learned`` (the constant predictor and the spec's references fused before the report),
    those rows beside the heads (:func:`non_learned_sequences`), in the table and not in the
    figure."""
    items = load_sequences(spec, units, workdir) if workdir is not None else []
    if items and non_learned:
        items += non_learned_sequences(non_learned)
    table = sequence_rows(items)
    png = out / f"{spec.name}.png"
    learned = [i for i in items if i.learned]
    drawn = sequence_figure(learned, png) if learned else False
    text = sequence_markdown(spec, table, png.name if drawn else None)
    return text, [png] if drawn else [], table
