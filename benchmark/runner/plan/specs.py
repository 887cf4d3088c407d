"""Table and figure specs: ``reports/configs/*.yaml``, one file per paper table or figure.

Each file's first line cites what it reproduces (``# Paper Table 1: ...`` or ``# Paper Fig. 7:
...``), or says it goes beyond the paper (``# Beyond the paper: ...``, e.g. the leakage audit);
the loader checks that. A spec names its rows (one model each: heads, encoder and its variant),
the split they train on and the splits they are evaluated on. Sweep specs (figures) repeat the rows
for every ``sweep_values`` entry, substituting ``{x}`` in split names and row fields.

Per row: ``label``, ``paper_model`` and ``attitude`` (a registered attitude head) are required;
the other fields are ``benchmark.models.ModelConfig``'s, by its names (the profile sets the width,
the dataset the input size), or say where the row trains:

- ``translation`` (default ``regression``), ``encoder`` (default: the profile's,
  ``benchmark.runner.plan.repro_profiles.ReproProfile.encoder``: the matching encoder in ``quick``,
  the paper's GoogLeNet in ``smoke`` and ``paper``; a row that names one keeps it, e.g. Fig. 9's
  ``googlenet``), ``variant`` (GoogLeNet's: ``/``, ``a``, ``f``, ``a-f``; a row's default is
  ``/``, not ModelConfig's ``a-f``: :data:`ROW_DEFAULTS`; a row on a profile encoder other than
  GoogLeNet runs it plain, ``/``; the field was ``encoder_variant`` before issue 22),
  ``aux_weight`` (default 0.3).
- ``attitude_options``, ``translation_options``, ``encoder_options``: mappings of constructor
  options of that head / encoder, any of them, e.g. ``attitude_options: {kappa: 5, hidden: 512}``,
  ``attitude_options: {direction_weight: 0}`` (with ``attitude: pd_net_e``),
  ``encoder_options: {norm: batch}``. Each value is converted to the type of the constructor
  parameter; an option the head does not take is an error naming the file, the row, the head and
  the options it accepts. A value equal to the constructor's default is the same model as no value
  (Fig. 7's kappa 10 is Table 1's Pd/Re-Net). The old row field ``kappa:`` is refused with a
  message pointing to ``attitude_options: {kappa: ...}``.
- Sweeps: ``{x}`` may appear in any string field and inside option values, e.g.
  ``attitude_options: {kappa: "{x}"}``; after substitution an option value is read as a YAML
  scalar (``"5"`` -> 5, ``"1e-3"`` -> 0.001, ``"true"`` -> True), then typed as above.
- ``satellite_input: blank``: the UAV-only control (the model sees grey instead of the satellite
  image, ``benchmark.models.pair``); default ``image``.
- ``train_split`` / ``eval_splits``: override the table's, for tables whose rows train on different
  splits (the leakage audit trains on ``standard/train`` and on ``frames/train``). The table's
  ``eval_splits`` may then be omitted; a rendered table lists every split some row evaluates on,
  each with the rows that evaluate on it.

``swap_metrics`` (table level): metrics shown a second time, measured with each pair's satellite
image swapped for another place's (the satellite-swap probe, ``benchmark.data.swap``), beside the
true ones. Every trained model is evaluated both ways whatever the spec says.

``references`` (table level, ``kind: table`` and ``kind: sequence``): non-learned rows shown
beside the models, by registry name (``benchmark.references.list_references()``:
``geometry_oracle``, ``gravity_template``, ``feature_pnp``), each evaluated once per test split of
the table (``benchmark.runner.execute.reference_rows``): a table's with the true and the swapped
satellite image; a sequence's with the true one, and also on the training split's validation
split, where their fusion density is calibrated as a regression head's is. They take part in no
claim about heads.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from benchmark.models.model_config import SATELLITE_INPUTS, ModelConfig, parse_scalar

KINDS = ("table", "sweep", "cost", "sequence")
# What a ``kind: sequence`` row fuses (``RowSpec.beliefs``).
# "volume": the pair encoder's pose volume, its two marginals fused apart; "volume_joint": the
# same volume fused jointly over (heading, E, N) (``benchmark.evaluation.fusion_joint``).
BELIEF_SOURCES = ("head", "volume", "volume_joint")
VOLUME_BELIEFS = ("volume", "volume_joint")
# Where a ``beliefs: volume`` (or ``volume_joint``) row takes its pitch and roll
# (``RowSpec.pitch_roll``): "own" the head of its own unit; "best_on_val" the spec's head row
# with the lowest validation error.
PITCH_ROLL_SOURCES = ("own", "best_on_val")
_FIRST_LINE = re.compile(r"^# (Paper (Table|Fig\.) (\d+)|Beyond the paper): .+")


class SpecError(ValueError):
    """A spec file is malformed; the message names the file and the field."""


OPTION_FIELDS = ("attitude_options", "translation_options", "encoder_options")


# The ModelConfig fields a row may set. The others are not a row's: the profile's encoder width,
# the dataset's input size and the speed switches (channels_last, shared_satellite), which do not
# change what a model computes.
ROW_MODEL_FIELDS = (
    *("attitude", "attitude_options", "translation", "translation_options"),
    *("encoder", "encoder_options", "variant", "aux_weight", "satellite_input"),
)
# Where a row's default is not ModelConfig's. A row trains the plain encoder (``variant "/"``)
# unless it names a variant; ModelConfig's own default is the paper's AGTFM (``"a-f"``). A row
# without ``encoder`` trains the profile's (None here; see ``RowSpec.model_config``).
ROW_DEFAULTS: dict[str, Any] = {"variant": "/", "encoder": None}
# Row fields of earlier spec files and what they are now.
MOVED_ROW_FIELDS = {
    "encoder_variant": "variant",  # ModelConfig's name for GoogLeNet's variant
}


@dataclass(frozen=True)
class RowSpec:
    """One row of a table (a model): its label, the ``ModelConfig`` fields it sets (``model``:
    a subset of :data:`ROW_MODEL_FIELDS`, as written, ``{x}`` not yet filled in) and where it
    trains. :meth:`model_config` turns it into the ``benchmark.models.ModelConfig`` it trains."""

    label: str
    paper_model: str
    model: dict[str, Any]
    train_split: str | None = None  # None: the table's
    eval_splits: tuple[str, ...] | None = None  # None: the table's
    # What a sequence row fuses: "head" (the heads' beliefs), "volume" (the pair encoder's own
    # pose volume, its marginals; its heads give only pitch and roll) or "volume_joint" (the
    # same volume fused jointly over heading and position). Not part of the model: a volume row and
    # a head row of the same model share their unit.
    beliefs: str = "head"
    # Where a volume row's pitch and roll come from (:data:`PITCH_ROLL_SOURCES`): "own" (its
    # unit's head) or "best_on_val" (the spec's head row, on the same shared encoder and
    # protocol, with the lowest mean δθ + δγ on the validation split; chosen there, never on a
    # test split). Not part of the model either.
    pitch_roll: str = "own"

    def __hash__(self) -> int:  # the model dict is not hashable; its repr is
        return hash(repr(self))

    def get(self, name: str) -> Any:
        """The row's model field ``name``: as written, else :data:`ROW_DEFAULTS`, else
        ``ModelConfig``'s default."""
        if name in self.model:
            return self.model[name]
        if name in ROW_DEFAULTS:
            return ROW_DEFAULTS[name]
        default = _MODEL_DEFAULTS[name]
        return dict(default) if isinstance(default, dict) else default

    def model_config(
        self,
        width: float = 1.0,
        encoder: str = "googlenet",
        encoder_options: dict[str, Any] | None = None,
    ) -> ModelConfig:
        """The row's model at encoder ``width`` (the profile's), input size from the dataset.
        A row without ``encoder`` takes ``encoder`` with ``encoder_options`` (the profile's),
        updated by the row's own ``encoder_options``. Raises ValueError naming the head and its
        options when an option does not fit."""
        fields = {name: self.get(name) for name in ROW_MODEL_FIELDS}
        if fields["encoder"] is None:
            fields["encoder"] = encoder
            fields["encoder_options"] = {**(encoder_options or {}), **fields["encoder_options"]}
            if encoder != "googlenet":
                # The variants (SE attention, triple fusion) are GoogLeNet's: a row written for
                # the paper's encoder (Table 5's "with AGTFM") runs the profile's encoder plain.
                fields["variant"] = "/"
        return ModelConfig(width=width, **fields)


def _model_defaults() -> dict[str, Any]:
    defaults = {}
    for f in dataclasses.fields(ModelConfig):
        if f.default is not dataclasses.MISSING:
            defaults[f.name] = f.default
        elif f.default_factory is not dataclasses.MISSING:
            defaults[f.name] = f.default_factory()
    return defaults


_MODEL_DEFAULTS = _model_defaults()


@dataclass(frozen=True)
class Job:
    """One (table, row, sweep value): train on ``train_split``, evaluate on ``eval_splits``."""

    table: str
    label: str
    paper_model: str
    x: str | None  # the sweep value as written in the spec (None for plain tables)
    row: RowSpec  # {x} filled in
    train_split: str
    eval_splits: tuple[str, ...]
    fuse: bool = False  # a ``kind: sequence`` job: its splits are fused along their flights
    beliefs: str = "head"  # what it fuses (``RowSpec.beliefs``)
    pitch_roll: str = "own"  # a volume row's pitch and roll (``RowSpec.pitch_roll``)


@dataclass(frozen=True)
class TableSpec:
    name: str
    title: str
    kind: str
    source: Path
    rows: tuple[RowSpec, ...]
    paper_table: int | None = None
    paper_figure: int | None = None
    paper_split: str | None = None
    paper_splits: tuple[str, ...] = ()
    train_split: str = "standard/train"
    eval_splits: tuple[str, ...] = ()
    metrics: tuple[str, ...] = ()
    sweep: str | None = None
    sweep_values: tuple[str, ...] = ()
    swap_metrics: tuple[str, ...] = ()  # also shown with the swapped satellite image
    note: str = ""  # printed under the rendered table
    references: tuple[str, ...] = ()  # non-learned rows (benchmark.references names)

    def jobs(self) -> list[Job]:
        """Concrete jobs; a sweep yields one per (value, row). Cost specs train nothing."""
        if self.kind == "cost":
            return []
        values: tuple[str | None, ...] = self.sweep_values if self.kind == "sweep" else (None,)
        out = []
        for x in values:
            for row in self.rows:
                out.append(
                    Job(
                        table=self.name,
                        label=row.label,
                        paper_model=row.paper_model,
                        x=x,
                        row=_substitute_row(row, x, self.source),
                        train_split=_fill(row.train_split or self.train_split, x),
                        eval_splits=tuple(
                            _fill(s, x)
                            for s in (
                                self.eval_splits if row.eval_splits is None else row.eval_splits
                            )
                        ),
                        fuse=self.kind == "sequence",
                        beliefs=row.beliefs,
                        pitch_roll=row.pitch_roll,
                    )
                )
        return out

    def all_eval_splits(self) -> list[str]:
        """Every split some job evaluates on, in order of first appearance."""
        seen: dict[str, None] = {}
        for job in self.jobs():
            for split in job.eval_splits:
                seen[split] = None
        return list(seen)

    def train_split_for(self, eval_split: str) -> str:
        """The split the rows evaluated on ``eval_split`` train on (the constant predictor's
        training set for that split); the table's own when rows disagree or none evaluates."""
        found = {j.train_split for j in self.jobs() if eval_split in j.eval_splits}
        return found.pop() if len(found) == 1 else self.train_split

    def train_splits(self) -> list[str]:
        return list(dict.fromkeys(j.train_split for j in self.jobs()))


def _fill(text: str, x: str | None) -> str:
    return text if x is None else text.replace("{x}", x)


def _outside_sweep(row: RowSpec, name: str, source: Path) -> SpecError:
    return SpecError(f"{source}: row {row.label!r} field {name!r} uses {{x}} outside a sweep")


def _substitute(value: Any, name: str, row: RowSpec, x: str | None, source: Path) -> Any:
    """``value`` (of field ``name``) with ``{x}`` filled in: in a string, in each string of a
    tuple, in the option values of a mapping (then read as YAML scalars: ``"5"`` -> 5)."""
    if isinstance(value, tuple) and any("{x}" in s for s in value):
        if x is None:
            raise _outside_sweep(row, name, source)
        return tuple(_fill(s, x) for s in value)
    if isinstance(value, str) and "{x}" in value:
        if x is None:
            raise _outside_sweep(row, name, source)
        return _fill(value, x)
    if name in OPTION_FIELDS:
        swept = [k for k, o in value.items() if isinstance(o, str) and "{x}" in o]
        if swept and x is None:
            raise _outside_sweep(row, f"{name}.{swept[0]}", source)
        if swept:
            return {k: parse_scalar(_fill(o, x)) if k in swept else o for k, o in value.items()}
    return value


def _substitute_row(row: RowSpec, x: str | None, source: Path) -> RowSpec:
    """``row`` with ``{x}`` replaced in its strings, split lists and model fields."""
    changes: dict[str, Any] = {
        f.name: _substitute(getattr(row, f.name), f.name, row, x, source)
        for f in dataclasses.fields(row)
        if f.name != "model"
    }
    model = {k: _substitute(v, k, row, x, source) for k, v in row.model.items()}
    return dataclasses.replace(row, model=model, **changes)


def _row_from(raw: Any, source: Path, index: int) -> RowSpec:
    where = f"{source}: rows[{index}]"
    if not isinstance(raw, dict):
        raise SpecError(f"{where} must be a mapping, got {type(raw).__name__}")
    own = {f.name for f in dataclasses.fields(RowSpec)} - {"model"}
    fields = own | set(ROW_MODEL_FIELDS)
    if "kappa" in raw:
        raise SpecError(
            f"{where}: field 'kappa' has moved: write attitude_options: {{kappa: {raw['kappa']}}} "
            "(any option of the head can be set there)"
        )
    for old, new in MOVED_ROW_FIELDS.items():
        if old in raw:
            raise SpecError(f"{where}: field {old!r} is now {new!r}: write {new}: {raw[old]!r}")
    unknown = sorted(set(raw) - fields)
    if unknown:
        raise SpecError(f"{where}: unknown fields {unknown}; expected some of {sorted(fields)}")
    for required in ("label", "paper_model", "attitude"):
        if required not in raw:
            raise SpecError(f"{where}: missing field {required!r}")
    if raw.get("beliefs", "head") not in BELIEF_SOURCES:
        raise SpecError(f"{where}: beliefs must be one of {BELIEF_SOURCES}, got {raw['beliefs']!r}")
    if raw.get("pitch_roll", "own") not in PITCH_ROLL_SOURCES:
        raise SpecError(
            f"{where}: pitch_roll must be one of {PITCH_ROLL_SOURCES}, got {raw['pitch_roll']!r}"
        )
    if raw.get("satellite_input", "image") not in SATELLITE_INPUTS:
        raise SpecError(
            f"{where}: satellite_input must be one of {SATELLITE_INPUTS}, "
            f"got {raw['satellite_input']!r}"
        )
    values: dict[str, Any] = {}
    for key, value in raw.items():
        if key in OPTION_FIELDS:
            if not isinstance(value, dict):
                raise SpecError(
                    f"{where}: {key} must be a mapping, e.g. {{kappa: 5}}, got {value!r}"
                )
            values[key] = {str(k): v for k, v in value.items()}
        elif key == "eval_splits":
            if not isinstance(value, list) or not value:
                raise SpecError(f"{where}: eval_splits must be a non-empty list, got {value!r}")
            values[key] = tuple(str(s) for s in value)
        elif key == "aux_weight":
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise SpecError(f"{where}: aux_weight must be a number, got {value!r}")
            values[key] = float(value)
        else:
            values[key] = str(value)
    model = {k: v for k, v in values.items() if k not in own}
    return RowSpec(model=model, **{k: v for k, v in values.items() if k in own})


def _check_models(spec: TableSpec) -> None:
    """Build every row's ``ModelConfig`` (per sweep value) now: an unknown head or a head option
    the head does not take is reported with the file and the row before anything trains."""
    values: tuple[str | None, ...] = spec.sweep_values if spec.kind == "sweep" else (None,)
    for index, row in enumerate(spec.rows):
        for x in values:
            try:
                _substitute_row(row, x, spec.source).model_config()
            except SpecError:
                raise
            except (TypeError, ValueError) as err:
                at = f" (sweep value {x})" if x is not None else ""
                raise SpecError(
                    f"{spec.source}: rows[{index}] ({row.label!r}){at}: {err}"
                ) from None


def _references_from(raw: Any, kind: str, path: Path) -> tuple[str, ...]:
    """The table-level ``references`` field checked: a list of distinct registered reference
    names, on a ``kind: table`` or ``kind: sequence`` spec; SpecError naming the file, the field
    and the known names."""
    from benchmark.references import list_references

    known = list_references()
    if not isinstance(raw, list):
        raise SpecError(f"{path}: references must be a list of {known}, got {raw!r}")
    if kind not in ("table", "sequence"):
        raise SpecError(
            f"{path}: references are rows of a table or a sequence; kind {kind!r} has none"
        )
    for index, name in enumerate(raw):
        if name not in known:
            raise SpecError(
                f"{path}: references[{index}] {name!r} is not a reference; known: {known}"
            )
    if len(set(raw)) != len(raw):
        raise SpecError(f"{path}: references lists a name twice: {raw}")
    return tuple(raw)


def load_spec(path: str | Path) -> TableSpec:
    """Parse and validate one spec file; SpecError names the file and the field on any problem."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise SpecError(f"{path}: cannot read spec ({err.strerror})") from err
    first = text.splitlines()[0] if text else ""
    if not _FIRST_LINE.match(first):
        raise SpecError(
            f"{path}: the first line must cite the paper ('# Paper Table 1: ...'), got {first!r}"
        )
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise SpecError(f"{path}: invalid YAML: {err}") from err
    if not isinstance(raw, dict):
        raise SpecError(f"{path}: expected a mapping at the top level")
    if "variants" in raw:
        raise SpecError(f"{path}: field 'variants' is now 'rows' (one model per row)")
    fields = {f.name for f in dataclasses.fields(TableSpec)} - {"source"}
    unknown = sorted(set(raw) - fields)
    if unknown:
        raise SpecError(f"{path}: unknown fields {unknown}; expected some of {sorted(fields)}")
    for required in ("name", "title", "kind", "rows"):
        if required not in raw:
            raise SpecError(f"{path}: missing field {required!r}")
    if raw["kind"] not in KINDS:
        raise SpecError(f"{path}: kind must be one of {KINDS}, got {raw['kind']!r}")
    if raw["name"] != path.stem:
        raise SpecError(f"{path}: name {raw['name']!r} must equal the file name {path.stem!r}")
    if not isinstance(raw["rows"], list) or not raw["rows"]:
        raise SpecError(f"{path}: rows must be a non-empty list")
    rows = tuple(_row_from(r, path, i) for i, r in enumerate(raw["rows"]))
    for index, row in enumerate(rows):
        if row.beliefs != "head" and raw["kind"] != "sequence":
            raise SpecError(
                f"{path}: rows[{index}] ({row.label!r}): beliefs: {row.beliefs} is for a "
                f"kind: sequence spec (what its rows fuse); kind {raw['kind']!r} fuses nothing"
            )
        if row.pitch_roll != "own" and row.beliefs not in VOLUME_BELIEFS:
            raise SpecError(
                f"{path}: rows[{index}] ({row.label!r}): pitch_roll: {row.pitch_roll} is for a "
                f"beliefs: volume row (a head row's pitch and roll are its own)"
            )
        if row.beliefs in VOLUME_BELIEFS and row.model.get("encoder") is None:
            raise SpecError(
                f"{path}: rows[{index}] ({row.label!r}): a beliefs: volume row names the pair "
                f"encoder whose pose volume it fuses (encoder: matching); the profile's encoder "
                f"may have none"
            )
    tuples = ("paper_splits", "eval_splits", "metrics", "sweep_values", "swap_metrics")
    values = {
        k: tuple(str(x) for x in raw[k]) if k in tuples else raw[k] for k in raw if k != "rows"
    }
    if "references" in raw:
        values["references"] = _references_from(raw["references"], raw["kind"], path)
    spec = TableSpec(source=path, rows=rows, **values)
    if spec.kind == "sweep" and not (spec.sweep and spec.sweep_values):
        raise SpecError(f"{path}: a sweep needs 'sweep' and 'sweep_values'")
    if spec.kind != "cost" and any(r.eval_splits is None for r in rows):
        if not spec.eval_splits:
            raise SpecError(f"{path}: eval_splits must list at least one split")
    if spec.paper_splits and len(spec.paper_splits) != len(spec.eval_splits):
        raise SpecError(f"{path}: paper_splits must have one entry per eval_splits entry")
    spec.jobs()  # surfaces substitution errors now, not mid-run
    _check_models(spec)  # and unknown heads or head options
    return spec


def default_spec_dir() -> Path:
    """``reports/configs`` of the working tree this package was loaded from."""
    return Path(__file__).resolve().parents[3] / "reports" / "configs"


# Names ``--only`` accepts besides table names: the paper's own tables and figures (specs with
# ``paper_table`` or ``paper_figure``), and everything beyond the paper. The whole quick
# reproduction measured over 2 hours on 2 cores (issue 13), so each group runs on its own.
GROUPS = ("paper", "extras")


def spec_group(spec: TableSpec) -> str:
    """``"paper"`` for a spec that reproduces a table or figure of the paper, else ``"extras"``."""
    return "paper" if spec.paper_table is not None or spec.paper_figure is not None else "extras"


def load_specs(
    directory: str | Path | None = None, only: list[str] | None = None
) -> list[TableSpec]:
    """All specs in ``directory`` (sorted by name), or just those named in ``only``: table names
    and group names (:data:`GROUPS`), in the order given, each spec once."""
    directory = Path(directory) if directory is not None else default_spec_dir()
    paths = sorted(directory.glob("*.yaml"))
    if not paths:
        raise SpecError(f"{directory}: no *.yaml table specs found")
    specs = {p.stem: load_spec(p) for p in paths}
    if not only:
        return list(specs.values())
    unknown = [n for n in only if n not in specs and n not in GROUPS]
    if unknown:
        raise SpecError(
            f"unknown table(s) {unknown}; known: {sorted(specs)} and the groups {list(GROUPS)}"
        )
    chosen: dict[str, TableSpec] = {}
    for name in only:
        members = [s for s in specs.values() if spec_group(s) == name] if name in GROUPS else []
        for spec in members or [specs[name]]:
            chosen.setdefault(spec.name, spec)
    return list(chosen.values())
