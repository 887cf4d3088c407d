"""FrameStore on a synthetic reproduction written in the real formats (pairs.parquet labels, unit
prediction CSVs from ``predictions_frame``), against independent numpy references.

The builders here (``Repro``) are reused by ``test_claims.py``.
"""

from __future__ import annotations

import re
import zlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from scipy.spatial.transform import Rotation

from benchmark.evaluation.metrics import predictions_frame, write_predictions_csv
from benchmark.geometry import SAT_R_N
from benchmark.runner.claims.frame_errors import FrameStore
from benchmark.runner.execute.worker import eval_key, split_filename
from benchmark.runner.plan.specs import Job, RowSpec
from benchmark.runner.plan.units import Unit
from benchmark.training.config import PretrainedConfig, TrainConfig

R_COLUMNS = [f"R{i}{j}" for i in range(3) for j in range(3)]
# split -> (flights, frames per flight)
SPLITS = {"standard/train": (10, 6), "standard/test": (12, 5), "generalized/test": (10, 5)}


def write_labels(root: Path, seed: int = 0, splits: dict = SPLITS) -> dict[str, pd.DataFrame]:
    """pairs.parquet with realistic relative attitudes (UAV pitch -5..-45 deg, any yaw, small
    roll; R_uav^sat = R_uav^n R_sat^n^T) and translations around (0, 0, -900) m."""
    rng = np.random.default_rng(seed)
    rows, flight = [], 100
    for split, (n_flights, per) in splits.items():
        for _ in range(n_flights):
            yaw0 = rng.uniform(-np.pi, np.pi)
            for k in range(per):
                yaw = yaw0 + 0.05 * k
                pitch, roll = rng.uniform(-0.8, -0.1), rng.normal(0, 0.03)
                R_n = Rotation.from_euler("ZXY", [yaw, pitch, roll]).as_matrix()
                R = R_n @ SAT_R_N.numpy().T
                T = rng.normal([0, 0, -900], [60, 60, 20])
                rows.append({"split": split, "flight": flight, "city": "x", "centre": 0,
                             **dict(zip(R_COLUMNS, R.reshape(-1), strict=True)),
                             "dE": T[0], "dN": T[1], "dU": T[2]})  # fmt: skip
            flight += 1
    pairs = pd.DataFrame(rows)
    root.mkdir(parents=True, exist_ok=True)
    pairs.to_parquet(root / "pairs.parquet")
    return {s: pairs[pairs.split == s].reset_index(drop=True) for s in splits}


def perturbed(R: np.ndarray, angles_deg: np.ndarray, rng) -> np.ndarray:
    """``R @ Rot(random axis, angle)``: geodesic error = angle exactly. (N,3,3), (N,) deg."""
    axes = rng.normal(size=(len(R), 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    return R @ Rotation.from_rotvec(axes * np.radians(angles_deg)[:, None]).as_matrix()


class Repro:
    """A synthetic reproduction: labels, units and their prediction CSVs in ``root``."""

    def __init__(self, root: Path, seed: int = 0, splits: dict = SPLITS):
        self.root, self.workdir, self.data = root, root / "runs", root / "data"
        self.labels = write_labels(self.data, seed, splits)
        self.units: list[Unit] = []
        self.rng = np.random.default_rng(seed + 1)

    def poses(self, split: str) -> tuple[np.ndarray, np.ndarray]:
        p = self.labels[split]
        return p[R_COLUMNS].to_numpy().reshape(-1, 3, 3), p[["dE", "dN", "dU"]].to_numpy()

    def mean_pose(self, train: str = "standard/train") -> tuple[np.ndarray, np.ndarray]:
        R, T = self.poses(train)
        u, _, vt = np.linalg.svd(R.mean(0))
        return u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt, T.mean(0)

    def add(self, table: str, label: str, splits: dict[str, object], seeds=(0, 1, 2),
            x: str | None = None, blank: bool = False, train: str = "standard/train",
            swap: dict[str, object] | None = None, shuffle: bool = False,
            uncertainty: float = 0.0, encoder: str | None = None) -> None:  # fmt: skip
        """One model over ``seeds``. ``splits[split]`` is its geodesic error in degrees per frame:
        a float (mean of a gamma-distributed error), a callable ``(seed, n) -> (n,)``, or
        ``"constant"`` (the training-mean pose plus 0.5 deg noise). Translation errors follow the
        same scale in metres. ``swap`` gives the errors with the swapped satellite image (default:
        the same predictions). The ``uncertainty`` column is ``uncertainty * error + N(0, 1)``.
        ``encoder``: the units train heads only, on the frozen encoder unit ``<encoder>-<seed>``
        (``cfg.pretrained``, as the quick profile's rows do)."""
        model = {"attitude": "pd_re_net", "satellite_input": "blank" if blank else "image"}
        job = Job(table, label, label, x, RowSpec(label, label, model), train, tuple(splits))
        for seed in seeds:
            where = "" if train == "standard/train" else f"-{train}"
            key = f"{table}-{label}-{x}-{seed}{where}".replace("/", "_").replace(" ", "_")
            pretrained = (
                PretrainedConfig(checkpoint=f"{encoder}-{seed}.pt", key=f"{encoder}-{seed}")
                if encoder
                else PretrainedConfig()
            )
            self.units.append(Unit(key, TrainConfig(seed=seed, pretrained=pretrained), [job]))
            for split, spec in splits.items():
                for satellite in ("true", "swap"):
                    use = spec if satellite == "true" else (swap or {}).get(split, spec)
                    same = satellite == "true" or split not in (swap or {})
                    self.write(key, split, "true" if same else satellite, use, seed, train,
                               shuffle, uncertainty, satellite)  # fmt: skip

    def write(self, key, split, draw, spec, seed, train, shuffle, unc, satellite) -> Path:
        R, T = self.poses(split)
        n = len(R)
        rng = np.random.default_rng(zlib.crc32(f"{key}|{split}|{draw}".encode()))
        if isinstance(spec, str):  # the constant predictor, slightly jittered
            R_bar, T_bar = self.mean_pose(train)
            R_hat = perturbed(np.repeat(R_bar[None], n, 0), np.full(n, 0.5), rng)
            T_hat = T_bar + rng.normal(0, 0.5, (n, 3))
            err = np.full(n, 0.5)
        else:
            err = spec(seed, n) if callable(spec) else rng.gamma(4.0, spec / 4.0, n)
            R_hat = perturbed(R, err, rng)
            T_hat = T + rng.normal(0, 1, (n, 3)) * err[:, None]
        frame = predictions_frame(
            torch.tensor(R_hat), torch.tensor(R), torch.tensor(T_hat),
            torch.tensor(T), index=np.arange(n),
            uncertainty=torch.from_numpy(unc * err + rng.normal(size=n)),
            extra={"city": ["x"] * n, "centre": [0] * n,
                   "flight": self.labels[split]["flight"].tolist(), "sat_index": [0] * n},
        )  # fmt: skip
        if shuffle:
            frame = frame.sample(frac=1.0, random_state=seed)
        path = (
            self.workdir
            / "units"
            / key
            / "eval"
            / (split_filename(eval_key(split, satellite)) + ".csv")
        )
        return write_predictions_csv(frame, path)

    def store(self) -> FrameStore:
        return FrameStore(self.workdir, self.data, self.units)


@pytest.fixture
def repro(tmp_path) -> Repro:
    r = Repro(tmp_path)
    r.add("table1", "Pd/Re-Net", {"standard/test": 5.0}, shuffle=True)
    r.add("table1", "UAV-only control", {"standard/test": "constant"}, seeds=(0,), blank=True)
    r.add("fig7", "Pd/Re-Net", {"standard/test": 6.0, "generalized/test": 9.0}, x="10")
    return r


def geodesic_deg(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    cos = (np.einsum("nij,nij->n", A, B) - 1) / 2
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


class TestErrors:
    def test_shape_order_and_values_match_the_csvs(self, repro):
        e = repro.store().errors("table1", "Pd/Re-Net", "standard/test", "dphi_deg")
        n = len(repro.labels["standard/test"])
        assert e.values.shape == (3, n) and e.seeds == (0, 1, 2)
        np.testing.assert_array_equal(e.index, np.arange(n))  # CSV rows were shuffled
        np.testing.assert_array_equal(e.flight, repro.labels["standard/test"]["flight"])
        for s in range(3):
            path = (
                repro.workdir
                / "units"
                / f"table1-Pd_Re-Net-None-{s}"
                / "eval"
                / "standard__test.csv"
            )
            ref = pd.read_csv(path).sort_values("index")["dphi_deg"].to_numpy()
            np.testing.assert_array_equal(e.values[s], ref)
        np.testing.assert_allclose(e.seed_mean, e.values.mean(0))

    def test_geodesic_column_is_the_perturbation(self, repro):
        """Independent check of the written data: dphi equals the angle to the label."""
        e = repro.store().errors("fig7", "Pd/Re-Net", "generalized/test", "dphi_deg", x=10)
        assert e.values.shape == (3, len(repro.labels["generalized/test"]))
        assert 5.0 < e.values.mean() < 13.0

    def test_swap_and_other_columns(self, repro):
        store = repro.store()
        u = store.errors("table1", "Pd/Re-Net", "standard/test", "uncertainty", satellite="swap")
        assert u.values.shape[0] == 3 and np.isfinite(u.values).all()
        with pytest.raises(ValueError, match="no column 'nope'"):
            store.errors("table1", "Pd/Re-Net", "standard/test", "nope")

    def test_missing_file_named(self, repro):
        path = repro.workdir / "units" / "table1-Pd_Re-Net-None-1" / "eval" / "standard__test.csv"
        path.unlink()
        with pytest.raises(FileNotFoundError, match=re.escape(str(path))):
            repro.store().errors("table1", "Pd/Re-Net", "standard/test", "dphi_deg")

    def test_seeds_on_different_frames_refused(self, repro):
        path = repro.workdir / "units" / "table1-Pd_Re-Net-None-2" / "eval" / "standard__test.csv"
        pd.read_csv(path).iloc[1:].to_csv(path, index=False)
        with pytest.raises(ValueError, match="hold different frames"):
            repro.store().errors("table1", "Pd/Re-Net", "standard/test", "dphi_deg")

    def test_unknown_model_and_split(self, repro):
        store = repro.store()
        with pytest.raises(KeyError, match="Re-Net-R"):
            store.errors("table1", "Re-Net-R", "standard/test", "dphi_deg")
        with pytest.raises(KeyError, match="not evaluated on 'generalized/test'"):
            store.errors("table1", "Pd/Re-Net", "generalized/test", "dphi_deg")

    def test_trained_from_names_the_frozen_encoder_or_the_unit(self, tmp_path):
        r = Repro(tmp_path)
        r.add("table1", "A", {"standard/test": 5.0}, seeds=(0, 1), encoder="enc")
        r.add("table1", "B", {"standard/test": 5.0}, seeds=(0, 1))
        store = r.store()
        a = store.errors("table1", "A", "standard/test", "dphi_deg")
        b = store.errors("table1", "B", "standard/test", "dphi_deg")
        assert a.trained_from == ("enc-0", "enc-1")
        assert b.trained_from == ("table1-B-None-0", "table1-B-None-1")
        assert store.constant("standard/test", "dphi_deg", "standard/train").trained_from == ()

    def test_a_label_trained_on_two_splits_is_refused(self, tmp_path):
        # The leakage table holds Pd/Re-Net twice (standard/train and frames/train).
        r = Repro(tmp_path)
        r.add("leakage", "Pd/Re-Net", {"standard/test": 5.0}, seeds=(0,))
        r.add("leakage", "Pd/Re-Net", {"standard/test": 7.0}, seeds=(0,), train="standard/val")
        with pytest.raises(KeyError, match=r"more than one model.*standard/train.*standard/val"):
            r.store().errors("leakage", "Pd/Re-Net", "standard/test", "dphi_deg")


class TestPlan:
    def test_labels_xs_splits_seeds(self, repro):
        store = repro.store()
        assert store.labels("table1") == ["Pd/Re-Net", "UAV-only control"]
        assert store.labels("table1", control=True) == ["UAV-only control"]
        assert store.labels("table1", "standard/test", control=False) == ["Pd/Re-Net"]
        assert store.xs("fig7", "Pd/Re-Net") == ["10"]
        assert store.splits("fig7", "Pd/Re-Net", 10) == ["standard/test", "generalized/test"]
        assert store.has("fig7", "Pd/Re-Net", "generalized/test", "10")
        assert not store.has("table1", "Pd/Re-Net", "generalized/test")
        assert store.seeds("table1", "UAV-only control") == [0]
        assert store.train_split("table1", "Pd/Re-Net") == "standard/train"


class TestConstant:
    def test_matches_numpy_reference(self, repro):
        """Chordal mean of the training rotations (SVD projection), mean translation."""
        store = repro.store()
        R_bar, T_bar = repro.mean_pose("standard/train")
        R, T = repro.poses("generalized/test")
        dphi = store.constant_errors("generalized/test", "dphi_deg", "standard/train")
        np.testing.assert_allclose(dphi, geodesic_deg(np.repeat(R_bar[None], len(R), 0), R),
                                   atol=1e-6)  # fmt: skip
        dE = store.constant_errors("generalized/test", "dE_m", "standard/train")
        np.testing.assert_allclose(dE, np.abs(T_bar[0] - T[:, 0]), rtol=1e-12)
        c = store.constant("generalized/test", "dphi_deg", "standard/train")
        assert c.values.shape == (1, len(R)) and c.seeds == (0,)
        np.testing.assert_array_equal(c.flight, repro.labels["generalized/test"]["flight"])

    def test_aligned_with_models(self, repro):
        store = repro.store()
        e = store.errors("table1", "Pd/Re-Net", "standard/test", "dphi_deg")
        c = store.constant("standard/test", "dphi_deg", "standard/train")
        np.testing.assert_array_equal(e.index, c.index)
        np.testing.assert_array_equal(e.flight, c.flight)

    def test_missing_labels_and_split_named(self, repro, tmp_path):
        store = FrameStore(repro.workdir, tmp_path / "nowhere", repro.units)
        with pytest.raises(FileNotFoundError, match=r"pairs\.parquet"):
            store.constant_errors("standard/test", "dphi_deg", "standard/train")
        with pytest.raises(ValueError, match="no split 'towns/test'"):
            repro.store().constant_errors("towns/test", "dphi_deg", "standard/train")
