"""Two reproductions of the same units compared on the same frames (``uavbench compare``).

Issue 40 asks that the verdicts not depend on the training precision: the same units trained in
fp32 and in bf16, paired differences on ``standard/val``. The same question comes up for any two
workdirs that trained the same variants another way (precision, device, CPU kind, library
version), so this module compares any two ``runs/<profile>`` directories.

**Pairing.** A unit is identified by its ``config.json``. Two units are *the same variant* when
their configs agree on everything except the fields that say how it was run
(:data:`RUN_FIELDS`: precision, device, the data directory's path) and the frozen encoder they
were built on (``pretrained.*``: a bf16 head unit sits on the bf16 encoder, whose key differs).
Seeds pair with seeds: seed s of A against seed s of B (the same initial weights and batch
order), resampled together (``paired_seeds``).

**Frames.** Both units' per-frame tables of the split (``eval/<split>.csv``) must hold the same
frames with the same truth (``index``, ``flight`` and the true yaw, pitch, roll and position);
anything else is refused, naming the files: a difference between other frames is no paired
difference.

**Statistic.** For each variant and error (δφ, δψ, δθ, δγ and the mean of |δE|, |δN|, |δU|),
``Δ = B − A``: the mean over seeds and frames, its 95 % flight x seed bootstrap interval
(:func:`benchmark.evaluation.paired.pooled_replicates`, the claims' resampling) and the issue 38
equivalence test against the claims' own margins (``EQUIVALENCE_MARGINS``): *equivalent* when
the 90 % interval lies inside ``(−m, +m)``, *different* when the 95 % interval excludes 0 (and
not equivalent), else *undecided*. With fewer than ``MIN_FLIGHTS`` flights there is no verdict.
A difference inside the margins cannot flip a claim that rests on those margins by itself; a
*different* or *undecided* row names the variant whose claims deserve a second look.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from benchmark.errors import InputError
from benchmark.evaluation.paired import percentile_interval, pooled_replicates
from benchmark.runner.claims.evidence import (
    CONFIDENCE,
    EQUIVALENCE_CONFIDENCE,
    EQUIVALENCE_MARGINS,
    MIN_FLIGHTS,
    N_BOOT,
    TRANSLATION,
)

# Config fields that say how a unit was run, not what it is.
RUN_FIELDS = ("precision", "device", "data.root")
PRETRAINED_PREFIX = "pretrained."
# Truth columns two per-frame tables must share to be the same frames.
TRUTH_COLUMNS = ("index", "flight", "yaw_deg", "pitch_deg", "roll_deg", "E_m", "N_m", "U_m")
# The compared errors: per-frame columns (degrees), and TRANSLATION, the mean of |δE|, |δN|, |δU|.
ERRORS = ("dphi_deg", "dpsi_deg", "dtheta_deg", "dgamma_deg", TRANSLATION)
ERROR_NAMES = {"dphi_deg": "δφ", "dpsi_deg": "δψ", "dtheta_deg": "δθ", "dgamma_deg": "δγ",
               TRANSLATION: "mean(|δE|, |δN|, |δU|)"}  # fmt: skip
EQUIVALENT, DIFFERENT, UNDECIDED = "equivalent", "different", "undecided"


@dataclass(frozen=True)
class Unit:
    """One trained unit of a workdir: ``key`` its directory name, ``config`` its config.json."""

    key: str
    path: Path
    config: dict

    @property
    def seed(self) -> int:
        return int(self.config.get("seed", 0))


def variant_of(config: dict) -> str:
    """The variant a config trains: the config without the seed, the run fields and the frozen
    encoder's location, as canonical JSON (equal strings, the same variant)."""
    what = {
        k: v
        for k, v in config.items()
        if k != "seed" and k not in RUN_FIELDS and not k.startswith(PRETRAINED_PREFIX)
    }
    return json.dumps(what, sort_keys=True)


def read_units(units_dir: Path) -> dict[str, dict[int, Unit]]:
    """``variant -> seed -> Unit`` for every unit directory under ``units_dir`` (a workdir's
    ``units/``). Raises :class:`InputError` when the directory has no unit, or when two units
    train the same variant and seed (a workdir mixing code versions: compare clean workdirs)."""
    if not units_dir.is_dir():
        raise InputError(f"{units_dir}: no such units directory (expected runs/<profile>/units)")
    out: dict[str, dict[int, Unit]] = {}
    for path in sorted(p for p in units_dir.iterdir() if (p / "config.json").is_file()):
        try:
            config = json.loads((path / "config.json").read_text())
        except json.JSONDecodeError as err:
            raise InputError(f"{path / 'config.json'}: not JSON ({err})") from err
        unit = Unit(path.name, path, config)
        seeds = out.setdefault(variant_of(config), {})
        if unit.seed in seeds:
            raise InputError(
                f"{units_dir}: units {seeds[unit.seed].key} and {unit.key} train the same variant "
                f"and seed {unit.seed}; expected one unit per variant and seed"
            )
        seeds[unit.seed] = unit
    if not out:
        raise InputError(f"{units_dir}: no unit (no */config.json)")
    return out


def _split_file(unit: Unit, split: str) -> Path:
    return unit.path / "eval" / f"{split.replace('/', '__')}.csv"


def _errors(frame: pd.DataFrame, path: Path) -> dict[str, np.ndarray]:
    missing = [c for c in (*ERRORS[:-1], "dE_m", "dN_m", "dU_m") if c not in frame.columns]
    if missing:
        raise InputError(f"{path}: no column(s) {missing} (a per-frame evaluation table expected)")
    out = {m: frame[m].to_numpy(np.float64) for m in ERRORS[:-1]}
    axes = frame[["dE_m", "dN_m", "dU_m"]].to_numpy(np.float64)
    out[TRANSLATION] = np.abs(axes).mean(axis=1)
    return out


def _read_pair(a: Unit, b: Unit, split: str) -> tuple[dict, dict, np.ndarray] | None:
    """Both units' errors on ``split`` (None when either has no table of it), checked to be the
    same frames."""
    pa, pb = _split_file(a, split), _split_file(b, split)
    if not (pa.is_file() and pb.is_file()):
        return None
    fa = pd.read_csv(pa).sort_values("index", kind="stable").reset_index(drop=True)
    fb = pd.read_csv(pb).sort_values("index", kind="stable").reset_index(drop=True)
    truth = [c for c in TRUTH_COLUMNS if c in fa.columns]
    if "index" not in truth or "flight" not in truth:
        raise InputError(f"{pa}: no 'index'/'flight' columns (a per-frame evaluation table)")
    if (
        len(fa) != len(fb)
        or any(c not in fb.columns for c in truth)
        or not np.allclose(
            fa[truth].to_numpy(np.float64), fb[truth].to_numpy(np.float64), rtol=0, atol=1e-4
        )
    ):
        raise InputError(
            f"{pa} and {pb}: not the same frames (rows, index, flight or truth {truth} differ); "
            f"a paired comparison needs both workdirs evaluated on the same dataset"
        )
    return _errors(fa, pa), _errors(fb, pb), fa["flight"].to_numpy()


@dataclass(frozen=True)
class Difference:
    """One variant's paired difference on one error: means of A and B, ``diff`` = B − A, its 95 %
    interval ``[lo, hi]``, its 90 % interval ``[lo90, hi90]``, the margin and the verdict."""

    variant: str
    error: str
    seeds: int
    flights: int
    mean_a: float
    mean_b: float
    diff: float
    lo: float
    hi: float
    lo90: float
    hi90: float
    margin: float
    verdict: str


def verdict_of(lo: float, hi: float, lo90: float, hi90: float, margin: float, flights: int) -> str:
    """The equivalence rule of issue 38 on one paired difference (see the module docstring)."""
    if flights < MIN_FLIGHTS or not all(map(math.isfinite, (lo, hi, lo90, hi90))):
        return UNDECIDED
    if -margin < lo90 and hi90 < margin:
        return EQUIVALENT
    if hi < 0 or lo > 0:
        return DIFFERENT
    return UNDECIDED


def compare_units(
    a_dir: Path, b_dir: Path, split: str = "standard/val", n_boot: int = N_BOOT, seed: int = 0
) -> tuple[list[Difference], dict[str, list[str]]]:
    """Paired differences B − A on ``split`` for every variant both workdirs trained with the
    same seeds (``a_dir``/``b_dir``: their ``units/`` directories). Returns the differences (one
    per variant and error, variants in A's order) and what was left out: ``{"only in A": [...],
    "only in B": [...], "seeds differ": [...], "no table": [...]}`` (variant labels). Raises
    :class:`InputError` when no variant could be compared."""
    units_a, units_b = read_units(a_dir), read_units(b_dir)
    left: dict[str, list[str]] = {"only in A": [], "only in B": [], "seeds differ": [],
                                  "no table": []}  # fmt: skip
    left["only in B"] = [v for v in units_b if v not in units_a]
    out: list[Difference] = []
    for variant, seeds_a in units_a.items():
        seeds_b = units_b.get(variant)
        if seeds_b is None:
            left["only in A"].append(variant)
            continue
        if sorted(seeds_a) != sorted(seeds_b):
            left["seeds differ"].append(variant)
            continue
        pairs = [_read_pair(seeds_a[s], seeds_b[s], split) for s in sorted(seeds_a)]
        if any(p is None for p in pairs):
            left["no table"].append(variant)
            continue
        flights = pairs[0][2]  # type: ignore[index]
        for s, pair in zip(sorted(seeds_a)[1:], pairs[1:], strict=True):
            if not np.array_equal(pair[2], flights):  # type: ignore[index]
                raise InputError(f"{variant}: seed {s}'s {split} frames differ from seed 0's")
        n_flights = len(np.unique(flights))
        for error in ERRORS:
            ea = np.stack([p[0][error] for p in pairs])  # type: ignore[index]
            eb = np.stack([p[1][error] for p in pairs])  # type: ignore[index]
            diff, reps = pooled_replicates(ea, eb, flights, n_boot=n_boot, seed=seed,
                                           paired_seeds=True)  # fmt: skip
            lo, hi = percentile_interval(reps, CONFIDENCE)
            lo90, hi90 = percentile_interval(reps, EQUIVALENCE_CONFIDENCE)
            margin = EQUIVALENCE_MARGINS[error]
            out.append(Difference(
                variant, error, len(pairs), n_flights, float(ea.mean()), float(eb.mean()), diff,
                lo, hi, lo90, hi90, margin, verdict_of(lo, hi, lo90, hi90, margin, n_flights),
            ))  # fmt: skip
    if not out:
        raise InputError(
            f"{a_dir} and {b_dir}: no variant trained in both with the same seeds and a "
            f"{split} table ({ {k: len(v) for k, v in left.items()} })"
        )
    return out, left


def variant_labels(variants: list[str]) -> dict[str, str]:
    """A short label per variant: the config fields whose values differ between the variants,
    ``field=value`` joined by ``, `` (the fields every variant shares say nothing; a field a
    variant leaves unset, None, is not named)."""
    configs = [json.loads(v) for v in variants]
    fields = sorted({k for c in configs for k in c})
    varying = [k for k in fields if len({json.dumps(c.get(k)) for c in configs}) > 1]
    return {
        v: ", ".join(f"{k.split('.')[-1]}={c[k]}" for k in varying if c.get(k) is not None)
        or "(the only variant)"
        for v, c in zip(variants, configs, strict=True)
    }


def differences_frame(differences: list[Difference]) -> pd.DataFrame:
    """The differences as a table (one row per variant and error, ``label`` added)."""
    labels = variant_labels(list(dict.fromkeys(d.variant for d in differences)))
    rows = [{"label": labels[d.variant], **d.__dict__} for d in differences]
    return pd.DataFrame(rows)


def compare_markdown(
    differences: list[Difference],
    left: dict[str, list[str]],
    *,
    a_name: str,
    b_name: str,
    split: str,
) -> str:
    """The comparison rendered: a summary, then a row per variant with every error's Δ."""
    table = differences_frame(differences)
    counts = table["verdict"].value_counts()
    total = len(table)
    lines = [
        f"# {b_name} against {a_name} on `{split}`, paired by variant and seed",
        "",
        f"Δ = {b_name} − {a_name}: mean over seeds and frames of the same units trained both "
        f"ways, 95 % flight x seed bootstrap interval (seeds paired); *equivalent* when the 90 % "
        f"interval lies inside the claims' equivalence margin (δφ, δψ ±"
        f"{EQUIVALENCE_MARGINS['dphi_deg']:g}°, δθ, δγ ±{EQUIVALENCE_MARGINS['dtheta_deg']:g}°, "
        f"translation ±{EQUIVALENCE_MARGINS[TRANSLATION]:g} m), *different* when the 95 % "
        f"interval excludes 0, else *undecided*.",
        "",
        f"{table['variant'].nunique()} variants x {len(ERRORS)} errors = {total} comparisons: "
        + ", ".join(f"{counts.get(v, 0)} {v}" for v in (EQUIVALENT, DIFFERENT, UNDECIDED))
        + ".",
        "",
    ]
    for error in ERRORS:
        part = table[table["error"] == error]["verdict"].value_counts()
        lines.append(
            f"- {ERROR_NAMES[error]}: "
            + ", ".join(f"{part.get(v, 0)} {v}" for v in (EQUIVALENT, DIFFERENT, UNDECIDED))
        )
    lines.append("")
    rows = table[table["verdict"] == DIFFERENT]
    if len(rows):
        named = "; ".join(
            f"{r.label}: {ERROR_NAMES[r.error]} {r.diff:+.2f} [{r.lo:+.2f}, {r.hi:+.2f}]"
            for r in rows.itertuples()
        )
        lines += [f"Different: {named}.", ""]
    skipped = {k: v for k, v in left.items() if v}
    if skipped:
        lines += ["Not compared: " + "; ".join(f"{len(v)} {k}" for k, v in skipped.items()) + ".",
                  ""]  # fmt: skip
    header = (
        "| variant | seeds | flights | "
        + " | ".join(f"{ERROR_NAMES[e]}: {a_name} / {b_name}, Δ [95 %]" for e in ERRORS)
        + " |"
    )
    lines += [header, "|" + "---|" * (3 + len(ERRORS))]
    symbol = {EQUIVALENT: "≈", DIFFERENT: "≠", UNDECIDED: "~"}
    for _, part in table.groupby("variant", sort=False):
        first = part.iloc[0]
        cells = []
        for error in ERRORS:
            r = part[part["error"] == error].iloc[0]
            cells.append(f"{r['mean_a']:.2f} / {r['mean_b']:.2f}, {r['diff']:+.2f} "
                         f"[{r['lo']:+.2f}, {r['hi']:+.2f}] {symbol[r['verdict']]}")  # fmt: skip
        lines.append(f"| {first['label']} | {first['seeds']} | {first['flights']} | "
                     + " | ".join(cells) + " |")  # fmt: skip
    return "\n".join([*lines, ""])


CLAIM_ROW = re.compile(r"\| (\d+) \| ")
VERDICT_CELL = re.compile(r"\*\*([^*]+)\*\*")


def claim_verdicts(readme: Path) -> dict[int, list[str]]:
    """``claim -> [verdict on the main splits, verdict on the confirmation draw, ...]`` read from
    the claims table of a report's README (``reports/<profile>/README.md``; a row per claim,
    its verdicts in bold cells). Raises :class:`InputError` when the file has no claims table."""
    if not readme.is_file():
        raise InputError(f"{readme}: no such report README (expected reports/<profile>/README.md)")
    out: dict[int, list[str]] = {}
    for line in readme.read_text().splitlines():
        match = CLAIM_ROW.match(line)
        if match:
            cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
            out[int(match.group(1))] = [m.group(1) for c in cells if (m := VERDICT_CELL.match(c))]
    if not out:
        raise InputError(f"{readme}: no claims table (rows '| <n> | ...' with bold verdicts)")
    return out


def verdict_changes_markdown(a: Path, b: Path, *, a_name: str, b_name: str) -> str:
    """The claims whose verdicts differ between two reports (``a``/``b``: their README files),
    draw by draw, and how many agree."""
    va, vb = claim_verdicts(a), claim_verdicts(b)
    claims = sorted(set(va) | set(vb))
    changed = [n for n in claims if va.get(n) != vb.get(n)]
    lines = [
        f"## Verdicts: {b_name} against {a_name}",
        "",
        f"{len(claims) - len(changed)} of {len(claims)} claims have the same verdicts on every "
        f"draw (main splits, confirmation draw) in `{a}` and `{b}`.",
        "",
    ]
    if changed:
        lines += [f"| claim | {a_name} | {b_name} |", "|---|---|---|"]
        for n in changed:
            lines.append(
                f"| {n} | {' / '.join(va.get(n, ['-']))} | {' / '.join(vb.get(n, ['-']))} |"
            )
        lines.append("")
    return "\n".join(lines)


__all__ = [
    "DIFFERENT",
    "EQUIVALENT",
    "ERRORS",
    "UNDECIDED",
    "Difference",
    "Unit",
    "claim_verdicts",
    "compare_markdown",
    "compare_units",
    "differences_frame",
    "read_units",
    "variant_labels",
    "variant_of",
    "verdict_changes_markdown",
    "verdict_of",
]
