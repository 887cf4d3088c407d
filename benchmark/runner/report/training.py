"""What a table's rows trained, in words generated from the planned units (issue 38: the report
says only what its numbers say): how and on which split each row trained (:func:`table_protocol`)
and the label a row is shown under when its spec label names a model it did not train
(:func:`shown_labels`).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence

from benchmark.models.matching_options import MatchingOptions
from benchmark.models.model_config import ModelConfig
from benchmark.runner.plan.units import Unit
from benchmark.runner.report.sweeps import VARIANT_NAMES


def trained_label(model: ModelConfig) -> str:
    """A row label from what it trains: the attitude head's paper name (and a translation head
    other than the regression one), the encoder and its variant, e.g. ``Pd/Re-Net · matching
    encoder, plain``."""
    from benchmark.models import get_head_class

    head = get_head_class(model.attitude).paper_name or model.attitude
    if model.translation != "regression":
        translation = get_head_class(model.translation).paper_name or model.translation
        head += f" + {translation}"
    variant = VARIANT_NAMES.get(model.variant, model.variant)
    return f"{head} · {model.encoder} encoder, {variant}"


def shown_labels(table: str, units: Iterable[Unit]) -> dict[str, str]:
    """``spec label -> label shown`` for the rows of ``table`` whose trained model lacks the
    encoder variant their spec row asks for (a GoogLeNet variant on a profile encoder that has
    none, e.g. Table 5's "Pd/Re-Net with AGTFM" in quick runs the matching encoder plain): shown
    under :func:`trained_label`. Rows that trained what they ask for are not in it."""
    out: dict[str, str] = {}
    for unit in units:
        for job in unit.jobs:
            if job.table == table and job.row.get("variant") != unit.cfg.model.variant:
                out[job.label] = trained_label(unit.cfg.model)
    return out


def relabel_note(table: str, units: Iterable[Unit]) -> str:
    """The sentence under a table with relabelled rows (``""`` without): what each spec row asked
    for and what it trained, and that the paper's number beside it is the paper's model's."""
    seen: dict[str, tuple[str, str, str]] = {}
    for unit in units:
        for job in unit.jobs:
            model = unit.cfg.model
            asked = job.row.get("variant")
            if job.table == table and asked != model.variant and job.label not in seen:
                seen[job.label] = (trained_label(model), asked, model.encoder)
    if not seen:
        return ""
    parts = [
        f"the row `{label}` asks for the encoder variant `{asked}` "
        f"({VARIANT_NAMES.get(asked, asked)}), which the {encoder} encoder does not have: it "
        f"trained {shown} and is shown so"
        for label, (shown, asked, encoder) in seen.items()
    ]
    return (
        "Rows shown by what they trained: "
        + "; ".join(parts)
        + ". The paper's numbers beside such a row are the paper's model's (column *paper's "
        "row*), not this one's."
    )


def _how(unit: Unit, by_key: Mapping[str, Unit]) -> str:
    """How ``unit`` trained, with its training split and, for heads on a frozen shared encoder,
    that encoder's training split (when its unit is among ``by_key``)."""
    m, split = unit.cfg.model, unit.cfg.data.train_split
    if unit.cfg.pretrained.enabled:
        encoder = by_key.get(unit.cfg.pretrained.key)
        on = f" on `{encoder.cfg.data.train_split}`" if encoder is not None else ""
        return (f"heads only, trained on `{split}`, on the frozen shared {m.encoder} encoder "
                f"(trained once per seed end to end with its own loss{on}; the README's Profile "
                "line)")  # fmt: skip
    if (
        m.encoder == "matching"
        and MatchingOptions.from_flat(m.encoder_options).loss.volume_nll_weight != 0
    ):
        return f"end to end on `{split}` with the matching encoder's own loss beside the heads'"
    return f"end to end on `{split}` ({m.encoder}) by the heads' loss only, the paper's protocol"


def table_protocol(
    table: str, units: Sequence[Unit], shown: Mapping[str, str] | None = None
) -> str:
    """One sentence on how a table's rows were trained (issue 21: every table says it), generated
    from the units: heads on a frozen shared encoder or end to end (by the heads' loss only, or
    with the encoder's own loss), each with the split it trained on (issue 38), naming the rows
    (under their ``shown`` labels) when a table mixes them. ``""`` when no unit of it was
    planned."""
    shown = shown or {}
    by_key = {u.key: u for u in units}
    groups: dict[str, dict[str, None]] = {}
    for unit in units:
        labels = [shown.get(j.label, j.label) for j in unit.jobs if j.table == table]
        if labels:
            groups.setdefault(_how(unit, by_key), {}).update(dict.fromkeys(labels))
    if not groups:
        return ""
    if len(groups) == 1:
        return f"Training protocol: {next(iter(groups))}."
    parts = [f"{how}: {', '.join(labels)}" for how, labels in groups.items()]
    return "Training protocol: " + "; ".join(parts) + "."
