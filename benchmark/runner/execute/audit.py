"""The heading-cue audit's work (issue 9): render the extra datasets it pools and run the probe
on every family of splits the dataset holds. The claims and the report read its rows only
(``benchmark.runner.claims.data_audit``: the verdict's words and the Markdown); this module is
where the rendering and the image reading happen, run by the reproduction before the report is
written.

A ridge probe on image-wide UAV statistics (``benchmark.analysis.heading_cue``) is trained on a
training split, its ridge chosen on the validation split, and scored on the test splits. The
standard family is audited on the reproduction's dataset and on :data:`CUE_EXTRA_SEEDS` more
datasets of the same profile, standard splits only, at the next dataset seeds
(``<data>-cue-s<seed>``, rendered once and reused; about 2.5 min each for the quick profile on 2
cores), and pooled.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from benchmark.errors import InputError
from benchmark.progress import status
from benchmark.runner.execute.work_items import WorkItem

if TYPE_CHECKING:
    from benchmark.data import DataProfile
    from benchmark.data.writer import ConfigMismatchError

# (train, val, tests): the paper's splits, then the towns family, where present in the dataset.
AUDITS = (
    ("standard/train", "standard/val", ("standard/test", "generalized/test")),
    ("towns/train", "towns/val", ("towns/test", "towns/london")),
)
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


def _stale_cue_dataset(root: Path, err: ConfigMismatchError) -> InputError:
    if not err.differences:  # not a dataset at all: a file or a foreign directory
        return InputError(f"{root} (a heading-cue audit dataset's place): {err}")
    return InputError(
        f"{root} holds a heading-cue audit dataset of another simulator or profile "
        f"({err.summary}); move it away or delete it, and the next reproduce renders it again "
        f"(about 2.5 min for quick on 2 cores)"
    )


def check_cue_datasets(data_root: Path, n_extra: int = CUE_EXTRA_SEEDS) -> None:
    """Before any work: each audit dataset is absent, partial or complete for this code's
    config, never another's (which the report stage could not render over). InputError naming
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


def cue_dataset_roots(
    data_root: Path, n_extra: int, *, workers: int = 2, quiet: bool = False
) -> list[Path]:
    """``[data_root, extra_1, ...]``: the dataset and ``n_extra`` standard-only datasets of its
    profile at the next seeds, rendered next to it by ``workers`` processes (the same bytes with
    any number: ``benchmark.data.writer``; reused when complete, resumed when not)."""
    from benchmark.data.writer import ConfigMismatchError, simulate_dataset

    roots = [Path(data_root)]
    plan = cue_dataset_plan(data_root, n_extra)
    for k, (root, profile, seed) in enumerate(plan, start=1):
        if not quiet:
            status(
                f"heading-cue audit: dataset {k}/{n_extra} at {root} (standard splits, seed {seed})"
            )
        try:
            simulate_dataset(root, profile, seed, workers=workers, progress=not quiet)
        except ConfigMismatchError as err:
            raise _stale_cue_dataset(root, err) from None
        roots.append(root)
    return roots


def render_cue_dataset(where: tuple[str, DataProfile, int]) -> str:
    """Render (or resume, or confirm) one of the audit's extra datasets, ``(root, profile,
    seed)`` of :func:`cue_dataset_plan`, in this process (a work item: the executor runs several
    at once); its root. The same bytes as :func:`cue_dataset_roots` renders."""
    from benchmark.data.writer import ConfigMismatchError, simulate_dataset

    root, profile, seed = where
    try:
        simulate_dataset(Path(root), profile, seed, workers=1, progress=False)
    except ConfigMismatchError as err:
        raise _stale_cue_dataset(Path(root), err) from None
    return root


def cue_dataset_items(data_root: Path, n_extra: int = CUE_EXTRA_SEEDS) -> list[WorkItem]:
    """The audit's extra datasets not yet complete, each a work item (:func:`render_cue_dataset`)
    for the reproduction's executor; none when the dataset has no standard family to pool.
    InputError (before any work) when one holds another config's dataset."""
    from benchmark.data.dataset import list_splits
    from benchmark.data.writer import ConfigMismatchError, check_output_dir, dataset_config

    if not _audits_pooled(set(list_splits(data_root)), n_extra):
        return []
    items = []
    for root, profile, seed in cue_dataset_plan(data_root, n_extra):
        try:
            state = check_output_dir(root, dataset_config(profile, seed))
        except ConfigMismatchError as err:
            raise _stale_cue_dataset(root, err) from None
        if state != "complete":
            items.append(WorkItem(f"cue-dataset-s{seed}", f"heading-cue dataset seed {seed}",
                                  render_cue_dataset, (str(root), profile, seed),
                                  data_root=str(data_root)))  # fmt: skip
    return items


def _row(train: str, split: str, dataset: str, summary: dict[str, Any]) -> dict[str, Any]:
    return {"train": train, "split": split, "dataset": dataset, **summary}


def heading_cue_rows(
    data_root: Path, n_extra: int = CUE_EXTRA_SEEDS, *, workers: int = 2, quiet: bool = False
) -> list[dict[str, Any]]:
    """The heading-cue audit on every family of splits the dataset holds: rows ``{"train",
    "split", "dataset", "n", "flights", "probe_deg", "constant_deg", "ratio", "ratio_lo",
    "ratio_hi"}`` (val rows included; ``dataset`` is a directory name or ``"pooled"``). The
    standard family is also audited on ``n_extra`` more dataset seeds and pooled
    (:func:`cue_dataset_roots`, which renders them where missing with ``workers`` processes)."""
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
        roots = cue_dataset_roots(data_root, n_extra, workers=workers, quiet=quiet)
        pooled = pooled_heading_cue_audit(roots, train=train, val=val, test=list(tests))
        for root, result in zip(roots, pooled["datasets"], strict=True):
            rows += [_row(train, s, root.name, v) for s, v in result["splits"].items()]
        rows += [_row(train, s, "pooled", v) for s, v in pooled["pooled"].items()]
    return rows
