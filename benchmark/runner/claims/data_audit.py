"""The reproduction's data audit: can the UAV image alone give the heading? (issue 9)

A ridge probe on image-wide UAV statistics (``benchmark.analysis.heading_cue``: orientation
histograms and colour balance, no spatial layout) is trained on a training split, its ridge chosen
on the validation split, and scored on the test splits. A ratio (probe / constant predictor yaw
error) near 1 means the simulator gives no global heading cue; the acceptance of issue 9 asks
>= 0.85 on standard/test. Written to ``heading_cue.md`` and summarised in the report's README.

One quick dataset's standard/test (150 short flights since the held-out flights were shortened;
~40 before) is too few to decide the question: the constant predictor's error alone moves by
+-5-10 deg between draws. The verdict therefore pools the
reproduction's dataset with :data:`CUE_EXTRA_SEEDS` more datasets of the same profile, standard
splits only, at the next dataset seeds (``<data>-cue-s<seed>``, rendered once and reused; about
2.5 min each for the quick profile on 2 cores; five datasets hold 750 test flights).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchmark.errors import UsageError

if TYPE_CHECKING:
    from benchmark.data import DataProfile
    from benchmark.data.writer import ConfigMismatchError

# (train, val, tests): the paper's splits, then the towns family, where present in the dataset.
AUDITS = (
    ("standard/train", "standard/val", ("standard/test", "generalized/test")),
    ("towns/train", "towns/val", ("towns/test", "towns/london")),
)
THRESHOLD = 0.85
CUE_EXTRA_SEEDS = 4  # standard-only datasets pooled with the reproduction's for the verdict


def cue_dataset_plan(data_root: Path, n_extra: int) -> list[tuple[Path, DataProfile, int]]:
    """``[(root, profile, seed), ...]`` of the ``n_extra`` standard-only datasets pooled with
    ``data_root`` (``<data_root>-cue-s<seed + k>``, next to it). Raises ValueError naming
    ``config.json`` when the dataset's own profile and seed cannot be read."""
    from benchmark.data import DataProfile

    config_path = Path(data_root) / "config.json"
    try:
        config = json.loads(config_path.read_text())
        profile, seed = (
            DataProfile.from_dict(config["profile"]).standard_only(),
            int(config["seed"]),
        )
    except (OSError, KeyError, ValueError, TypeError) as err:
        raise ValueError(
            f"{config_path}: cannot read the dataset's profile and seed ({err})"
        ) from err
    parent, name = Path(data_root).parent, Path(data_root).name
    return [(parent / f"{name}-cue-s{seed + k}", profile, seed + k) for k in range(1, n_extra + 1)]


def _audits_pooled(available: set[str], n_extra: int) -> bool:
    """Whether the standard family is audited on the pooled datasets (it is in the dataset)."""
    train, val, tests = AUDITS[0]
    return n_extra > 0 and {train, val} <= available and any(t in available for t in tests)


def _stale_cue_dataset(root: Path, err: ConfigMismatchError) -> UsageError:
    if not err.differences:  # not a dataset at all: a file or a foreign directory
        return UsageError(f"{root} (a heading-cue audit dataset's place): {err}")
    return UsageError(
        f"{root} holds a heading-cue audit dataset of another simulator or profile "
        f"({err.summary}); move it away or delete it, and the next reproduce renders it again "
        f"(about 2.5 min for quick on 2 cores)"
    )


def check_cue_datasets(data_root: Path, n_extra: int = CUE_EXTRA_SEEDS) -> None:
    """Before any work: each audit dataset is absent, partial or complete for this code's
    config, never another's (which the report stage could not render over). UsageError naming
    the directory and the fix otherwise; touches nothing."""
    from benchmark.data.dataset import list_splits
    from benchmark.data.writer import ConfigMismatchError, check_output_dir, dataset_config

    if not _audits_pooled(set(list_splits(data_root)), n_extra):
        return
    for root, profile, seed in cue_dataset_plan(data_root, n_extra):
        try:
            check_output_dir(root, dataset_config(profile, seed))
        except ConfigMismatchError as err:
            raise _stale_cue_dataset(root, err) from None


def cue_dataset_roots(data_root: Path, n_extra: int, *, quiet: bool = False) -> list[Path]:
    """``[data_root, extra_1, ...]``: the dataset and ``n_extra`` standard-only datasets of its
    profile at the next seeds, rendered next to it (reused when complete, resumed when not)."""
    from benchmark.data.writer import ConfigMismatchError, simulate_dataset

    roots = [Path(data_root)]
    plan = cue_dataset_plan(data_root, n_extra)
    for k, (root, profile, seed) in enumerate(plan, start=1):
        if not quiet:
            print(
                f"heading-cue audit: dataset {k}/{n_extra} at {root} (standard splits, seed "
                f"{seed})",
                file=sys.stderr,
                flush=True,
            )
        try:
            simulate_dataset(root, profile, seed, workers=2, progress=not quiet)
        except ConfigMismatchError as err:
            raise _stale_cue_dataset(root, err) from None
        roots.append(root)
    return roots


def _row(train: str, split: str, dataset: str, summary: dict[str, Any]) -> dict[str, Any]:
    return {"train": train, "split": split, "dataset": dataset, **summary}


def heading_cue_audit_section(
    data_root: Path, n_extra: int = CUE_EXTRA_SEEDS, *, quiet: bool = False
) -> tuple[str, list[dict[str, Any]]]:
    """Markdown of the heading-cue audit on every family of splits the dataset holds, and its
    rows ``{"train", "split", "dataset", "n", "flights", "probe_deg", "constant_deg", "ratio",
    "ratio_lo", "ratio_hi"}`` (val rows included; ``dataset`` is a directory name or
    ``"pooled"``). The standard family is also audited on ``n_extra`` more dataset seeds and
    pooled (:func:`cue_dataset_roots`)."""
    from benchmark.analysis.heading_cue import heading_cue_audit, pooled_heading_cue_audit
    from benchmark.data.dataset import list_splits

    available = set(list_splits(data_root))
    rows: list[dict[str, Any]] = []
    for index, (train, val, tests) in enumerate(AUDITS):
        tests = tuple(t for t in tests if t in available)
        if not ({train, val} <= available and tests):
            continue
        if index > 0 or not _audits_pooled(available, n_extra):
            result = heading_cue_audit(data_root, train=train, val=val, test=list(tests))
            rows += [_row(train, s, data_root.name, v) for s, v in result["splits"].items()]
            continue
        roots = cue_dataset_roots(data_root, n_extra, quiet=quiet)
        pooled = pooled_heading_cue_audit(roots, train=train, val=val, test=list(tests))
        for root, result in zip(roots, pooled["datasets"], strict=True):
            rows += [_row(train, s, root.name, v) for s, v in result["splits"].items()]
        rows += [_row(train, s, "pooled", v) for s, v in pooled["pooled"].items()]
    lines = [
        "## Data audit: heading from the UAV image alone",
        "",
        "A ridge regression from image-wide UAV statistics (gradient-orientation histograms over "
        "the full circle and modulo 180 deg, colour balance; no spatial layout) to (cos, sin) of "
        "the UAV's yaw, fitted on the training split with its ridge chosen on the validation "
        "split (`uavbench heading-cue`). Ratio = its mean yaw error / the constant predictor's; "
        f"near 1 = no global heading cue in the data (issue 9 asks >= {THRESHOLD} on "
        "standard/test). The interval is a 95% bootstrap over whole flights (frames of a flight "
        "are correlated). A probe that learns nothing scores about 90 deg; the constant "
        "predictor's error depends on how far the split's headings lie from the training mean.",
        "",
        f"The standard splits are audited on this dataset and on {n_extra} more of the same "
        "profile at the next dataset seeds (standard splits only, `<data>-cue-s<seed>`; each "
        "probe fitted on its own dataset), then pooled: one dataset's test split cannot decide "
        "the question, since the constant predictor's error alone moves by 5-10 deg between "
        "draws. The verdict reads the pooled standard/test row.",
        "",
        "| trained on | evaluated on | dataset | pairs | flights | probe yaw error (deg) "
        "| constant (deg) | ratio [95% interval] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['train']} | {r['split']} | {r['dataset']} | {r['n']} | {r['flights']} | "
            f"{r['probe_deg']:.1f} | {r['constant_deg']:.1f} | {r['ratio']:.3f} "
            f"[{r['ratio_lo']:.3f}, {r['ratio_hi']:.3f}] |"
        )
    if not rows:
        lines.append("| - | (the dataset has none of the audited splits) | | | | | | |")
    return "\n".join(lines) + "\n", rows


def heading_cue_verdict(ratio: float, lo: float, hi: float) -> str:
    """The words of the audit's verdict, from the ratio's interval ``[lo, hi]`` against 1 (no cue
    at all) and ``THRESHOLD`` (the issue's bar): "no ... cue" only when the interval includes 1
    (or lies above it), a weak cue below the threshold when it excludes 1 but lies above the
    threshold. No interval, no verdict: the rest is not resolved."""
    gain = f"the probe's yaw error {100 * (1 - ratio):.0f}% below the constant's"
    if lo > 1.0:
        return (
            "no global heading cue (the interval lies above 1: the probe reads the yaw worse "
            "than the constant predictor)"
        )
    if lo <= 1.0 <= hi and lo >= THRESHOLD:
        return "no global heading cue detected (the interval includes 1)"
    if hi < 1.0 and lo >= THRESHOLD:
        return (
            f"a weak global heading cue ({gain}: the interval excludes 1), weaker than the "
            f"{THRESHOLD} threshold (the interval lies above it)"
        )
    if hi < THRESHOLD:
        return f"a global heading cue stronger than the {THRESHOLD} threshold ({gain})"
    if hi < 1.0:
        return (
            f"a global heading cue ({gain}: the interval excludes 1) whose strength against the "
            f"{THRESHOLD} threshold is not resolved at this scale (the interval contains it)"
        )
    return (
        f"not resolved at this scale (the interval contains both 1 and the {THRESHOLD} threshold)"
    )


def heading_cue_summary(rows: list[dict[str, Any]]) -> str:
    """One sentence for the README: the (pooled, where audited) standard/test ratio against the
    threshold, and the other splits' ratios of the reproduction's own dataset."""
    std = [r for r in rows if r["split"] == "standard/test"]
    if not std:
        return "Heading-cue audit: no standard/test split in this dataset."
    r = next((o for o in std if o["dataset"] == "pooled"), std[0])
    verdict = heading_cue_verdict(r["ratio"], r["ratio_lo"], r["ratio_hi"])
    own = rows[0]["dataset"]
    others = ", ".join(
        f"{o['split']} {o['ratio']:.2f}"
        for o in rows
        if o["dataset"] == own and o["split"] != "standard/test"
    )
    where = (
        f"{r['flights']} flights pooled over {len({o['dataset'] for o in std}) - 1} datasets"
        if r["dataset"] == "pooled"
        else f"{r['flights']} flights"
    )
    return (
        f"Heading-cue audit ([heading_cue.md](heading_cue.md)): image-wide UAV statistics read "
        f"the yaw on standard/test at {r['ratio']:.2f}x [{r['ratio_lo']:.2f}, "
        f"{r['ratio_hi']:.2f}] the constant predictor's error ({r['probe_deg']:.1f} vs "
        f"{r['constant_deg']:.1f} deg; {where}; threshold {THRESHOLD}): {verdict}. Other splits "
        f"of {own}: {others}."
    )
