"""Claims beside tables kept from an earlier run (``--only`` with ``--stale keep``, planned by
:func:`benchmark.runner.plan.partial.plan_merge`): a claim that needs such a table's per-frame
values is not decided on one run's tables alone or on two runs mixed; it reads
:data:`~benchmark.runner.plan.partial.EARLIER`.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from pathlib import Path

from benchmark.runner.claims.frame_errors import FrameErrors, FrameStore
from benchmark.runner.plan.partial import EARLIER, NOT_REDECIDED, EarlierTable, MergePlan
from benchmark.runner.plan.specs import TableSpec
from benchmark.runner.plan.units import Unit


class EarlierTableError(FileNotFoundError):
    """A claim asked for per-frame values of a table from an earlier run. A ``FileNotFoundError``
    so that ``benchmark.runner.claims.evidence.safe_claim`` turns the claim into one that is not
    decided, with this message as its evidence."""

    def __init__(self, table: EarlierTable):
        self.table = table
        super().__init__(
            f"{NOT_REDECIDED}: `{table.name}` is from an earlier run {table.at} ({table.why}); "
            "its numbers are kept as written then and not mixed with this run's"
        )


class MergedFrameStore(FrameStore):
    """A :class:`FrameStore` that knows the kept earlier tables' models (from their specs, so the
    claims see what they would compare) but refuses their per-frame values: a claim that needs
    one is not decided (:class:`EarlierTableError`) rather than decided on one run's tables
    alone or on two runs mixed."""

    def __init__(
        self,
        workdir: str | Path,
        data_root: str | Path,
        units: Sequence[Unit],
        earlier: Sequence[EarlierTable],
        specs: Mapping[str, TableSpec],
    ):
        from benchmark.training.config import TrainConfig

        self.earlier = {t.name: t for t in earlier}
        # One placeholder unit per job: FrameStore reads only the jobs and the seed of a unit.
        placeholders = [
            Unit(f"earlier-{t.name}-{i}", TrainConfig(), [job])
            for t in earlier
            if t.name in specs
            for i, job in enumerate(specs[t.name].jobs())
        ]
        super().__init__(workdir, data_root, [*units, *placeholders])

    def _refuse(self, table: str) -> None:
        if table in self.earlier:
            raise EarlierTableError(self.earlier[table])

    def errors(self, table: str, label: str, split: str, metric: str, x: object = None,
               satellite: str = "true") -> FrameErrors:  # fmt: skip
        self._refuse(table)
        return super().errors(table, label, split, metric, x, satellite)

    def train_split(self, table: str, label: str, x: object = None) -> str:
        self._refuse(table)  # the constant predictor a model is compared with
        return super().train_split(table, label, x)

    def has_sequence(self, table: str, label: str, split: str) -> bool:
        # refused, not False: a kept sequence table's fusion claims read "from an earlier run",
        # never "not run" (their files belong to that run's work directory)
        self._refuse(table)
        return super().has_sequence(table, label, split)

    def sequence_errors(self, table: str, label: str, split: str, metric: str, mode: str,
                        odometry: str = "data") -> FrameErrors:  # fmt: skip
        self._refuse(table)
        return super().sequence_errors(table, label, split, metric, mode, odometry)


_EARLIER_CLAIM = re.compile(rf"^{NOT_REDECIDED}: `([^`]+)` is from an earlier run at `([^`]+)`")


def mark_earlier_claims(claims: list, plan: MergePlan) -> None:
    """Claims refused by :class:`MergedFrameStore` get the verdict :data:`EARLIER` and
    ``facts["earlier"] = (table, commit)`` (the first earlier table the claim needed)."""
    commits = {t.name: t.commit for t in plan.kept}
    for c in claims:
        m = _EARLIER_CLAIM.match(c.evidence or "")
        if m and m[1] in commits:
            c.verdict = EARLIER
            c.facts = {**c.facts, "earlier": (m[1], commits[m[1]])}
