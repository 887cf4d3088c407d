"""Per-frame errors of a reproduction, aligned over seeds and models, for paired statistics.

The claims compare two models on the *same* test frames (``benchmark.evaluation.paired``), so they
need every frame's error, not the per-table means. A :class:`FrameStore` reads them from the files
each unit wrote (``<workdir>/units/<unit.key>/eval/<split_filename(split)>[__swap].csv``, columns of
``benchmark.evaluation.metrics.predictions_frame``; see ``benchmark.runner.execute.worker``) and
computes the constant (training-mean) predictor's per-frame errors from the dataset's labels
(``pairs.parquet``) with ``benchmark.evaluation.constant.constant_predictor``, the function
behind the reported constant row.

Alignment. Rows are sorted by the frame ``index`` (the row of the pair in its split); every seed
of a model and every model evaluated on a split then holds the same frames in the same order, which
is checked (a mismatch raises ``ValueError`` naming the files). Units: the CSV columns as written
(degrees ``*_deg``, metres ``*_m``).

Files are read lazily and cached; a planned unit whose file is missing raises
``FileNotFoundError`` naming the file.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.runner.execute.worker import (
    eval_key,
    fusion_paths,
    split_filename,
)
from benchmark.runner.plan.specs import VOLUME_BELIEFS, RowSpec
from benchmark.runner.plan.units import Unit


@dataclass(frozen=True)
class FrameErrors:
    """One model's per-frame values on one split, over its seeds.

    Attributes:
        values: ``(S, N)`` float64, row ``s`` = seed ``seeds[s]``, column ``n`` = frame
            ``index[n]`` (unit of the column: degrees or metres).
        index: ``(N,)`` int64 frame index within the split, increasing.
        flight: ``(N,)`` flight id of each frame (the bootstrap's resampling unit).
        seeds: ``(S,)`` training seeds, increasing.
        trained_from: ``(S,)`` per seed, the run whose trained weights the predictions rest on:
            the frozen encoder's unit key for a heads-only unit (``cfg.pretrained.key``), else
            the unit's own key; empty for what no run trained (the constant predictor). Two
            models with the same ``trained_from`` share each seed's run, so their seeds are
            resampled together (``benchmark.evaluation.paired.pooled_replicates``,
            ``paired_seeds``).
    """

    values: np.ndarray
    index: np.ndarray
    flight: np.ndarray
    seeds: tuple[int, ...]
    trained_from: tuple[str, ...] = ()

    @property
    def seed_mean(self) -> np.ndarray:
        """``(N,)`` mean over seeds of each frame's value."""
        return self.values.mean(axis=0)


class _Poses:
    """A split's label rows in the shape ``benchmark.evaluation.constant.dataset_labels`` reads
    (``.poses``: ``R00..R22``, ``dE dN dU``; item i = row i, as in ``PairDataset``)."""

    def __init__(self, poses: pd.DataFrame):
        self.poses = poses

    def __len__(self) -> int:
        return len(self.poses)


def _norm_x(x: object) -> str | None:
    return None if x is None else str(x)


class FrameStore:
    """Per-frame errors of the planned units of one reproduction.

    Args:
        workdir: the reproduction's work directory (holds ``units/<key>/eval/*.csv``).
        data_root: the dataset directory (for the constant predictor's labels and flight ids).
        units: the planned units (``benchmark.runner.plan.units.plan_units``); a model is identified
            by ``(table, label, x)`` of its jobs, its seeds by the units' ``cfg.seed``.
    """

    def __init__(self, workdir: str | Path, data_root: str | Path, units: Sequence[Unit]):
        self.workdir = Path(workdir)
        self.data_root = Path(data_root)
        # (table, label, x) -> {seed: (unit key, job)}, in plan order
        self._models: dict[tuple[str, str, str | None], dict[int, tuple[str, object]]] = {}
        # A table may hold one label twice, trained on different splits (the leakage table's
        # Pd/Re-Net on standard/train and on frames/train): such a name does not identify one
        # model, so asking for it is an error rather than a silent pick of the last row.
        self._ambiguous: dict[tuple[str, str, str | None], set[str]] = {}
        # unit key -> the key of the frozen encoder it trained its heads on (heads-only units)
        self._trained_from: dict[str, str] = {}
        for unit in units:
            if unit.cfg.pretrained.enabled and unit.cfg.pretrained.key:
                self._trained_from[unit.key] = unit.cfg.pretrained.key
            for job in unit.jobs:
                model = (job.table, job.label, _norm_x(job.x))
                by_seed = self._models.setdefault(model, {})
                seed = int(unit.cfg.seed)
                if seed in by_seed and by_seed[seed][0] != unit.key:
                    self._ambiguous.setdefault(model, {by_seed[seed][1].train_split})
                    self._ambiguous[model].add(job.train_split)
                by_seed[seed] = (unit.key, job)
        self._csv: dict[Path, pd.DataFrame] = {}
        self._constant: dict[tuple[str, str], pd.DataFrame] = {}
        self._pairs: pd.DataFrame | None = None

    # ------------------------------------------------------------------ what was planned
    def labels(
        self,
        table: str,
        split: str | None = None,
        control: bool | None = None,
        volume: bool = False,
    ) -> list[str]:
        """Model labels of ``table`` in plan order (one per label, whatever ``x``), restricted to
        those evaluated on ``split`` if given; ``control=True`` keeps only the UAV-only controls
        (``satellite_input == "blank"``), ``False`` drops them, None keeps all. A sequence row
        that fuses the encoder's pose volume (``beliefs: volume``) is no head: only with
        ``volume``."""
        out: dict[str, None] = {}
        for (t, label, _), by_seed in self._models.items():
            job = next(iter(by_seed.values()))[1]
            if t != table or (split is not None and split not in job.eval_splits):
                continue
            if getattr(job, "beliefs", "head") in VOLUME_BELIEFS and not volume:
                continue
            blank = job.row.get("satellite_input") == "blank"
            if control is None or control == blank:
                out[label] = None
        return list(out)

    def xs(self, table: str, label: str) -> list[str]:
        """Sweep values (as strings) planned for ``(table, label)``, in plan order."""
        return [x for (t, lb, x) in self._models if t == table and lb == label and x is not None]

    def splits(self, table: str, label: str, x: object = None) -> list[str]:
        """Splits the model ``(table, label, x)`` is evaluated on ([] if not planned)."""
        by_seed = self._models.get((table, label, _norm_x(x)))
        return list(next(iter(by_seed.values()))[1].eval_splits) if by_seed else []

    def has(self, table: str, label: str, split: str, x: object = None) -> bool:
        """Whether the model is planned and evaluated on ``split``."""
        return split in self.splits(table, label, x)

    def row(self, table: str, label: str, x: object = None) -> RowSpec:
        """The spec row of the model ``(table, label, x)`` (its heads, encoder variant, satellite
        input): the claims read a head's family from the registry through ``row.get("attitude")``.
        Raises ``KeyError`` when the model is not planned."""
        _seed, (_key, job) = self._jobs(table, label, x)[0]
        return job.row

    def seeds(self, table: str, label: str, x: object = None) -> list[int]:
        return sorted(self._models.get((table, label, _norm_x(x)), {}))

    def train_split(self, table: str, label: str, x: object = None) -> str:
        """The split the model trains on (the constant predictor it is compared with trains on
        the same one)."""
        _seed, (_key, job) = self._jobs(table, label, x)[0]
        return job.train_split

    def _jobs(self, table: str, label: str, x: object) -> list[tuple[int, tuple[str, object]]]:
        ambiguous = self._ambiguous.get((table, label, _norm_x(x)))
        if ambiguous:
            raise KeyError(
                f"({table!r}, {label!r}, x={x!r}) names more than one model (trained on "
                f"{sorted(ambiguous)}); per-frame errors need one"
            )
        by_seed = self._models.get((table, label, _norm_x(x)))
        if not by_seed:
            known = sorted({lb for (t, lb, _) in self._models if t == table})
            raise KeyError(
                f"no planned model ({table!r}, {label!r}, x={x!r}); {table} has {known or 'none'}"
            )
        return sorted(by_seed.items())

    # ------------------------------------------------------------------ per-frame values
    def csv_path(self, unit_key: str, split: str, satellite: str = "true") -> Path:
        """``<workdir>/units/<key>/eval/<split_filename(eval_key(split, satellite))>.csv``."""
        name = split_filename(eval_key(split, satellite)) + ".csv"
        return self.workdir / "units" / unit_key / "eval" / name

    def _read(self, path: Path) -> pd.DataFrame:
        if path not in self._csv:
            if not path.is_file():
                raise FileNotFoundError(f"predictions file missing: {path}")
            frame = pd.read_csv(path)
            if "index" not in frame or "flight" not in frame:
                raise ValueError(f"{path}: needs columns 'index' and 'flight', has {list(frame)}")
            frame = frame.sort_values("index", kind="stable").reset_index(drop=True)
            if frame["index"].duplicated().any():
                raise ValueError(f"{path}: duplicate frame 'index' values")
            self._csv[path] = frame
        return self._csv[path]

    def errors(
        self,
        table: str,
        label: str,
        split: str,
        metric: str,
        x: object = None,
        satellite: str = "true",
    ) -> FrameErrors:
        """Per-frame ``metric`` (any numeric column of the predictions CSV: ``dphi_deg``,
        ``dE_m``, ``uncertainty``, ...) of model ``(table, label, x)`` on ``split``.

        Returns:
            :class:`FrameErrors` with ``values (S, N)`` over the model's seeds.
        Raises:
            KeyError: the model is not planned or not evaluated on ``split``.
            FileNotFoundError: a planned unit's predictions file is missing (named).
            ValueError: the column is absent, or seeds disagree on the frames.
        """
        jobs = self._jobs(table, label, x)
        if not self.has(table, label, split, x):
            raise KeyError(
                f"model ({table!r}, {label!r}, x={x!r}) is not evaluated on {split!r}; "
                f"its splits: {self.splits(table, label, x)}"
            )

        def part_of(key: str) -> tuple[pd.DataFrame, Path]:
            path = self.csv_path(key, self.evaluated(split), satellite)
            return self._read(path), path

        return self._stack(jobs, split, metric, part_of)

    def _stack(
        self,
        jobs: list[tuple[int, tuple[str, object]]],
        split: str,
        metric: str,
        part_of: Callable[[str], tuple[pd.DataFrame, Path]],
    ) -> FrameErrors:
        """Seeds of one model stacked: ``part_of(unit key)`` gives the frames (sorted by
        ``index``) and the file they come from (named in the errors)."""
        rows, index, flight, first, trained_from = [], None, None, None, []
        for _seed, (key, _job) in jobs:
            trained_from.append(self._trained_from.get(key, key))
            frame, path = part_of(key)
            if metric not in frame:
                raise ValueError(f"{path}: no column {metric!r}")
            if index is None:
                index, flight, first = frame["index"].to_numpy(np.int64), frame["flight"], path
            elif not np.array_equal(frame["index"].to_numpy(np.int64), index):
                raise ValueError(f"{path} and {first} hold different frames of {split!r}")
            rows.append(frame[metric].to_numpy(np.float64))
        return FrameErrors(
            values=np.stack(rows),
            index=index,
            flight=flight.to_numpy(),
            seeds=tuple(seed for seed, _ in jobs),
            trained_from=tuple(trained_from),
        )

    def sequence_path(self, unit_key: str, split: str, beliefs: str = "head") -> Path:
        """The unit's flight-fusion file of ``split`` (``sequence_paths``, issue 39; the pose
        volume's for ``beliefs="volume"`` or ``"volume_joint"``: ``fusion_paths``)."""
        return fusion_paths(beliefs)(self.workdir / "units" / unit_key, split)[0]

    def has_sequence(self, table: str, label: str, split: str) -> bool:
        """Whether every seed of the model fused ``split`` along its flights."""
        by_seed = self._models.get((table, label, None))
        if not by_seed or not self.has(table, label, split):
            return False
        where = self.evaluated(split)
        return all(self.sequence_path(key, where, getattr(job, "beliefs", "head")).is_file()
                   for key, job in by_seed.values())  # fmt: skip

    def sequence_errors(
        self, table: str, label: str, split: str, metric: str, mode: str, odometry: str = "data"
    ) -> FrameErrors:
        """Per-frame ``metric`` (``dpsi_deg``, ``dphi_deg``, ``horizontal_m``) of the model's
        flight fusion on ``split`` in ``mode`` (``frame``, ``filter``, ``smooth``), with the
        dataset's odometry by default: the :meth:`errors` of the fused estimates (same frames,
        same seeds). Raises ``FileNotFoundError`` naming a missing sequence file."""

        jobs = self._jobs(table, label, None)
        beliefs = {key: getattr(job, "beliefs", "head") for _, (key, job) in jobs}

        def part_of(key: str) -> tuple[pd.DataFrame, Path]:
            path = self.sequence_path(key, self.evaluated(split), beliefs[key])
            if not path.is_file():
                raise FileNotFoundError(f"sequence file missing: {path}")
            if path not in self._csv:
                self._csv[path] = pd.read_csv(path)
            frame = self._csv[path]
            part = frame[(frame["mode"] == mode) & (frame["odometry"] == odometry)]
            if part.empty:
                raise ValueError(f"{path}: no {mode!r} rows with odometry {odometry!r}")
            return part.sort_values("index", kind="stable"), path

        return self._stack(jobs, split, metric, part_of)

    def evaluated(self, split: str) -> str:
        """The split whose files hold ``split``'s frames: itself here (a
        :class:`ConfirmationStore` reads the confirmation split instead)."""
        return split

    def confirmation(self, confirms: Mapping[str, str]) -> ConfirmationStore:
        """The same models on the confirmation draw (``confirms``: test split -> confirmation
        split, ``benchmark.sim.CONFIRMS``), as a store the claims read unchanged."""
        return ConfirmationStore(self, confirms)

    def _split_poses(self, split: str) -> _Poses:
        """The split's rows of ``pairs.parquet`` (what ``PairDataset(root, split).poses`` holds),
        read without loading or verifying images: the constant predictor needs labels only."""
        if self._pairs is None:
            path = self.data_root / "pairs.parquet"
            if not path.is_file():
                raise FileNotFoundError(f"dataset labels missing: {path}")
            self._pairs = pd.read_parquet(path)
        rows = self._pairs[self._pairs["split"] == split].reset_index(drop=True)
        if rows.empty:
            known = sorted(self._pairs["split"].unique())
            raise ValueError(f"{self.data_root}: no split {split!r}; it has {known}")
        return _Poses(rows)

    def _constant_frame(self, split: str, train_split: str) -> pd.DataFrame:
        split = self.evaluated(split)  # the cache is shared with a ConfirmationStore
        if (train_split, split) not in self._constant:
            from benchmark.evaluation.constant import constant_predictor

            test = self._split_poses(split)
            _, frame = constant_predictor(self._split_poses(train_split), test)
            frame = frame.assign(flight=test.poses["flight"].to_numpy()[frame["index"]])
            frame = frame.sort_values("index", kind="stable").reset_index(drop=True)
            self._constant[train_split, split] = frame
        return self._constant[train_split, split]

    def constant_errors(self, split: str, metric: str, train_split: str) -> np.ndarray:
        """``(N,)`` per-frame ``metric`` of the constant predictor (the mean pose of
        ``train_split``) on ``split``, frames in increasing ``index`` (the order of
        :meth:`errors`)."""
        frame = self._constant_frame(split, train_split)
        if metric not in frame:
            raise ValueError(f"constant predictor has no column {metric!r}")
        return frame[metric].to_numpy(np.float64)

    def constant(self, split: str, metric: str, train_split: str) -> FrameErrors:
        """The constant predictor as a one-"seed" :class:`FrameErrors` (``values (1, N)``)."""
        frame = self._constant_frame(split, train_split)
        return FrameErrors(
            values=self.constant_errors(split, metric, train_split)[None, :],
            index=frame["index"].to_numpy(np.int64),
            flight=frame["flight"].to_numpy(),
            seeds=(0,),
        )


class ConfirmationStore(FrameStore):
    """A :class:`FrameStore` read on the confirmation draw (issue 38): every question about a
    test split (``standard/test``) is answered from the frames of its confirmation split
    (``confirm/standard``) by the same trained units, so every claim is decided again, unchanged,
    on frames nobody chose anything on. A split without a confirmation split (the heights, the
    pitch bins, the flight-test analogue, ``towns/london``) is not evaluated here: its claims read
    "not run". The constant predictor still trains on the model's training split.

    Args:
        base: the store of the main splits (its units, work directory and dataset).
        confirms: test split -> confirmation split; a split whose units lack the confirmation
            files is treated as not evaluated (a unit planned before the draw existed).
    """

    def __init__(self, base: FrameStore, confirms: Mapping[str, str]):
        self.__dict__.update(base.__dict__)  # the same models, files and caches
        self.confirms = dict(confirms)

    def evaluated(self, split: str) -> str:
        return self.confirms[split]

    def splits(self, table: str, label: str, x: object = None) -> list[str]:
        """The model's test splits that have a confirmation split it was evaluated on."""
        by_seed = self._models.get((table, label, _norm_x(x)))
        if not by_seed:
            return []
        return [
            split
            for split in next(iter(by_seed.values()))[1].eval_splits
            if split in self.confirms and self._confirmed(by_seed, split)
        ]

    def _confirmed(self, by_seed: dict[int, tuple[str, object]], split: str) -> bool:
        """Whether every seed's unit wrote the confirmation split's predictions."""
        return all(
            self.csv_path(key, self.confirms[split]).is_file() for key, _ in by_seed.values()
        )

    def labels(
        self,
        table: str,
        split: str | None = None,
        control: bool | None = None,
        volume: bool = False,
    ) -> list[str]:
        labels = super().labels(table, split, control, volume)
        if split is None:
            return labels
        return [label for label in labels if self.has(table, label, split)]
