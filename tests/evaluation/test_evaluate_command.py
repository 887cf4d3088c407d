"""``uavbench evaluate`` argument errors (the full path: tests/training/test_command.py)."""

from __future__ import annotations

from benchmark.cli import main


class TestEvaluateCommandErrors:
    def test_missing_checkpoint(self, tmp_path, capsys):
        assert main(["evaluate", "--checkpoint", str(tmp_path / "none.pt")]) == 2
        assert "none.pt: no such file" in capsys.readouterr().err

    def test_not_a_checkpoint(self, tmp_path, capsys):
        (tmp_path / "x.pt").write_bytes(b"not a checkpoint")
        assert main(["evaluate", "--checkpoint", str(tmp_path / "x.pt")]) == 2
        assert "x.pt" in capsys.readouterr().err

    def test_bad_satellite_mode(self, tmp_path, capsys):
        (tmp_path / "x.pt").write_bytes(b"")
        args = ["evaluate", "--checkpoint", str(tmp_path / "x.pt"), "--satellite", "grey"]
        try:
            main(args)
        except SystemExit as exc:  # argparse: invalid choice
            assert exc.code == 2
        assert "invalid choice: 'grey'" in capsys.readouterr().err


class TestEvaluateSwap:
    def test_true_and_swapped_satellite(self, smoke_dataset, tmp_path):
        """One tiny checkpoint evaluated with the true and the swapped satellite images: same frames
        and labels, other satellite images (per-pair sat_index), group columns for the bootstrap."""
        import json

        import pandas as pd

        from benchmark.config import apply_overrides
        from benchmark.data import PairDataset
        from benchmark.training import TrainConfig
        from benchmark.training.build import run_training

        cfg = apply_overrides(
            TrainConfig(),
            [f"data.root={smoke_dataset}", "data.val_split=None", "data.limit_train=4",
             "model.width=0.25", "model.variant=/", "optim.epochs=1", "optim.batch_size=4",
             "threads=1"],
        )  # fmt: skip
        run_training(cfg, tmp_path / "run", progress=False)
        ckpt = str(tmp_path / "run" / "checkpoint.pt")
        base = ["evaluate", "--quiet", "--checkpoint", ckpt, "--out", str(tmp_path / "ev")]
        for split in ("standard/test", "generalized/test"):
            assert main([*base, "--split", split]) == 0
            assert main([*base, "--split", split, "--satellite", "swap"]) == 0
            name = split.replace("/", "_")
            true = pd.read_csv(tmp_path / "ev" / f"{name}.csv")
            swap = pd.read_csv(tmp_path / "ev" / f"{name}__swap.csv")
            labels = ["index", "city", "centre", "flight", "yaw_deg", "pitch_deg", "E_m", "U_m"]
            pd.testing.assert_frame_equal(true[labels], swap[labels])
            poses = PairDataset(smoke_dataset, split, verify="size").poses
            assert (true.sat_index.to_numpy() == poses.sat_index.to_numpy()).all()
            assert (swap.sat_index != true.sat_index).all()
        metrics = json.loads((tmp_path / "ev" / "metrics__swap.json").read_text())
        assert set(metrics) == {"generalized/test"} and metrics["generalized/test"]["n"] > 0
