"""What the MLflow UI shows on top of an experiment or a run (``mlflow.note.content``, Markdown).

Each text says what the experiment or run IS in the reproduction: which table or figure of the
paper, compared with which of its numbers, which row, split, seed and model.
"""

from __future__ import annotations

import json
from collections.abc import Iterable

from benchmark.runner.plan.specs import Job, TableSpec
from benchmark.runner.plan.units import Unit

UNITS_TABLE = "training"  # experiment uavbench-<profile>/training: one run per trained model

# A logged model's interface (benchmark.tracking.models.PosePredictor), said once per unit run.
MODEL_IO = (
    "input `(B, 6, H, W)` float32 in [0, 1] (UAV RGB, then satellite RGB); output `(B, 12)`: "
    "R_uav^sat row-major, then dE, dN, dU in metres"
)


def paper_reference(spec: TableSpec) -> str:
    """``"paper Table 1 (standard)"``, ``"paper Fig. 7"`` or ``"beyond the paper"``."""
    split = f" ({spec.paper_split})" if spec.paper_split else ""
    if spec.paper_table is not None:
        return f"paper Table {spec.paper_table}{split}"
    if spec.paper_figure is not None:
        return f"paper Fig. {spec.paper_figure}{split}"
    return "beyond the paper"


def table_experiment(spec: TableSpec, profile: str) -> str:
    ref = paper_reference(spec)
    if spec.kind == "cost":
        return (
            f"**{spec.title}** ({ref}), `{profile}` reproduction: one run per model and "
            "configuration (parameters, size in MB, MFLOPs, CPU latency per pair), under one "
            f"parent run `reproduce {profile}`; re-logged only when a measurement changes."
        )
    compared = (
        f"Compared with {ref} on {', '.join(f'`{m}`' for m in spec.metrics)}."
        if ref != "beyond the paper"
        else "Beyond the paper: no paper numbers to compare with."
    )
    sweep = f", sweep value of `{spec.sweep}`" if spec.kind == "sweep" and spec.sweep else ""
    return (
        f"**{spec.title}**, `{profile}` reproduction. {compared}{not_learned(spec)}\n\n"
        f"One parent run `reproduce {profile}` per reproduction; under it one run per table row"
        f"{sweep} and training seed. Headline metrics `test_*` are on the row's (first) test "
        "split, `val_*` on the validation split of the training family; every split's numbers "
        "are beside them as `<split>/<metric>` (`<split>/swap/...`: with another place's "
        "satellite image). Curves, dataset, predictions and the trained model are on the row's "
        f"training run in `uavbench-{profile}/{UNITS_TABLE}` (tag `training_run_id`). The "
        f"Markdown table is `{spec.name}.md` in the reproduction's reports."
    )


def not_learned(spec: TableSpec) -> str:
    """The sentences on a table's non-learned reference rows (``""`` for a table without):
    each is not learned, and which true values it is given."""
    if spec.kind != "table" or not spec.references:
        return ""
    from benchmark.runner.execute.reference_rows import describe_references

    return (
        " Beside the trained rows, non-learned rows with no run here (their numbers are in the "
        "table file; part of no claim about the heads): the constant predictor (the training "
        "split's mean pose) and the references: "
        + "; ".join(describe_references(spec.references))
        + "."
    )


def units_experiment(profile: str) -> str:
    return (
        f"**Training runs** of the `{profile}` reproduction: one run per trained model (train "
        "config and seed), shared by every table row that reads it. Each run is open while its "
        "model trains and evaluates (real duration): per-epoch curves (`train_loss_*`, `val_*`, "
        "`lr`, `pairs_per_s`), CPU and memory (`system/*`), the training dataset (Datasets), "
        f"the final numbers per split (`<split>/<metric>`), the predictions and the trained model "
        f"(Models; `mlflow.pytorch.load_model`, {MODEL_IO}). The rows of the tables are in the "
        f"experiments `uavbench-{profile}/<table>`."
    )


def model_line(unit: Unit) -> str:
    m = unit.cfg.model
    options = {"attitude": m.attitude_options, "translation": m.translation_options}
    opts = json.dumps({k: v for k, v in options.items() if v}, sort_keys=True)
    blank = ", satellite input blanked (UAV-only control)" if m.satellite_input == "blank" else ""
    return (
        f"attitude head `{m.attitude}`, translation head `{m.translation}`"
        f"{f', options {opts}' if opts != '{}' else ''}; encoder {m.encoder} `{m.variant}` "
        f"width {m.width:g}{blank}"
    )


def unit_run(unit: Unit, readers: Iterable[str]) -> str:
    o = unit.cfg.optim
    read_by = "; ".join(readers) or (
        "no table directly: the units whose heads sit on its frozen encoder (their "
        "`pretrained.key` is this unit's key)"
    )
    frozen = ""
    if unit.cfg.pretrained.enabled:
        frozen = (f" Heads only, on the frozen encoder of unit `{unit.cfg.pretrained.key}` "
                  "(features computed once per split).")  # fmt: skip
    return (
        f"Training of one model: {model_line(unit)}; seed {unit.cfg.seed}, trained on "
        f"`{unit.cfg.data.train_split}` ({o.epochs} epochs, {o.name} lr {o.lr:g}, batch "
        f"{o.batch_size}), evaluated on {', '.join(f'`{s}`' for s in unit.eval_splits)}.{frozen}"
        f"\n\nRead by: {read_by}."
    )


def job_run(
    spec: TableSpec | None, job: Job, unit: Unit, training_run_id: str, profile: str
) -> str:
    title = f"**{spec.title}** ({paper_reference(spec)})" if spec is not None else job.table
    sweep = ""
    if job.x is not None:
        sweep = f", {spec.sweep if spec is not None and spec.sweep else 'x'} = {job.x}"
    val = f", `val_*` on `{unit.val_split}`" if unit.val_split else ""
    link = (
        f"\n\nTraining run (curves, dataset, predictions, model): `{training_run_id}` in "
        f"`uavbench-{profile}/{UNITS_TABLE}`."
        if training_run_id
        else ""
    )
    return (
        f"{title}: row **{job.label}**{sweep}, training seed {unit.cfg.seed}. Trained on "
        f"`{job.train_split}`; headline metrics `test_*` on `{job.eval_splits[0]}`{val}.\n\n"
        f"Model: {model_line(unit)}.{link}"
    )
