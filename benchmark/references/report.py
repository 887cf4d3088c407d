"""``uavbench reference``: evaluate a non-learned reference on a split like a model.

    uavbench reference geometry_oracle --data data/quick --split standard/test
    uavbench reference gravity_template --data data/quick --split towns/test --satellite swap \\
        --out runs/ref/towns_test__swap.csv

Prints the headline metrics (and the failure rate, the 3D position error and OrthoLoC's
(metres, degrees) accuracies), writes the per-frame CSV (the columns of ``uavbench evaluate``'s,
plus ``reference_failed`` and ``reference_score``) to ``--out`` and the summary beside it as JSON.
Failed frames get the constant predictor's pose from ``--train-split`` (default: the split the
models evaluated on ``--split`` train on). ``--set key=value`` passes a reference option.

:func:`evaluate_and_report` returns the summary (:class:`ReferenceReport`);
``benchmark.commands.reference`` prints it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class ReferenceRunConfig:
    """One reference evaluation: reference ``name`` with ``options`` on ``split`` of the dataset
    ``data`` (``satellite``: ``"true"`` or ``"swap"``), every ``stride``-th pair up to ``limit``;
    failed frames get the mean pose of ``train_split`` (None: by family); the per-frame CSV and
    the summary JSON go to ``out`` (None: not written)."""

    name: str
    data: Path
    split: str
    satellite: str = "true"
    out: Path | None = None
    train_split: str | None = None
    options: Mapping[str, object] = field(default_factory=dict)
    limit: int | None = None
    stride: int = 1
    verify: str = "sha256"
    progress: bool = True


@dataclass(frozen=True)
class ReferenceReport:
    """What one reference evaluation measured: the reference's ``label``, the ``split`` with the
    ``satellite`` images, its ``summary`` (headline metrics, failure rate, accuracies, speed) and
    the per-frame CSV ``out`` (None: not written; the summary JSON is beside it)."""

    label: str
    split: str
    satellite: str
    summary: Mapping[str, float]
    out: Path | None = None

    def lines(self) -> list[str]:
        """What ``uavbench reference`` prints: the label, then the headline metrics in one
        line."""
        s = self.summary
        keys = ("dtheta_deg", "dgamma_deg", "dpsi_deg", "median_dpsi_deg", "dphi_deg")
        return [
            self.label,
            f"{self.split} ({self.satellite} satellite): n={int(s['n'])} "
            + ", ".join(f"{k}={s[k]:.2f}" for k in keys)
            + f", dE_m={s['dE_m']:.1f}, dN_m={s['dN_m']:.1f}, dU_m={s['dU_m']:.1f}"
            + f", median_pos_err_m={s['median_pos_err_m']:.1f}"
            + "".join(f", {k}={s[k]:.3f}" for k in s if k.startswith("acc_"))
            + f", failure_rate={s['failure_rate']:.3f}"
            + f", frames_per_s={s.get('frames_per_s', float('nan')):.1f}"
            + f", cpu_ms_per_frame={s['cpu_ms_per_frame']:.0f}",
        ]


def evaluate_and_report(config: ReferenceRunConfig) -> ReferenceReport:
    """Evaluate the reference of ``config`` and write its files (when ``config.out``). Returns
    the headline metrics (:class:`ReferenceReport`). Raises :class:`~benchmark.errors.InputError`
    for an unknown reference, option or split, a damaged dataset or a disk error."""
    from benchmark.data import DatasetError, PairDataset, list_splits, os_error_message
    from benchmark.errors import InputError
    from benchmark.references import (
        create_reference,
        default_train_split,
        evaluate_reference,
        fallback_pose,
        list_references,
    )

    if config.name not in list_references():
        raise InputError(
            f"unknown reference {config.name!r}; known: {', '.join(list_references())}"
        )
    options = dict(config.options)
    try:
        reference = create_reference(config.name, **options)
    except (TypeError, ValueError) as err:
        raise InputError(f"options of {config.name}: {err}") from None
    try:
        available = list_splits(config.data)
    except (DatasetError, OSError) as err:
        raise InputError(f"data {config.data}: {err}") from None
    train_split = config.train_split or default_train_split(config.split, available)
    for field_name, split in (("split", config.split), ("train_split", train_split)):
        if split not in available:
            raise InputError(f"{field_name} {split!r} is not in {config.data}; available: "
                             + ", ".join(available))  # fmt: skip
    try:
        dataset = PairDataset(
            config.data, config.split, verify=config.verify, satellite=config.satellite
        )
        fallback = fallback_pose(PairDataset(config.data, train_split, verify=config.verify))
        rows = list(range(0, len(dataset), config.stride))[: config.limit]
        summary, _ = evaluate_reference(
            reference,
            dataset,
            fallback=fallback,
            out_csv=config.out,
            rows=rows,
            progress=config.progress,
            desc=f"{config.name} {config.split}",
        )
        if config.out is not None:
            record = {
                "reference": config.name,
                "label": reference.label,
                "given": list(reference.given),
                "options": reference.options(),
                "split": config.split,
                "satellite": config.satellite,
                "train_split": train_split,
                "stride": config.stride,
                "summary": summary,
            }
            text = json.dumps(record, indent=1, sort_keys=True) + "\n"
            config.out.with_suffix(".json").write_text(text)
    except DatasetError as err:
        raise InputError(f"{err} (`uavbench verify {config.data}` checks every file)") from None
    except OSError as err:
        message = os_error_message(err)
        if message is None:
            raise
        raise InputError(message) from None
    return ReferenceReport(reference.label, config.split, config.satellite, summary, config.out)
