"""The experiment links ``uavbench ui`` prints and the screenshots visit: one classic Runs-view
URL per experiment of a tracking store, with the first line of its description.

Why the links carry ``?workflowType=machine_learning``: MLflow 3's UI keeps a workspace-wide mode
(``genai`` by default, kept in the browser's local storage) and in that mode opens every
experiment on the GenAI overview (traces, token usage), whatever the experiment's
``mlflow.experimentKind`` tag says. The URL parameter overrides the stored mode (MLflow 3.17's
``WorkflowTypeProvider`` reads it before local storage) and the UI keeps it on its own links, so a
link opens the classic Runs view with the experiment's description on top.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

ML_VIEW = "workflowType=machine_learning"
DESCRIPTION_TAG = "mlflow.note.content"  # what the UI shows as an experiment's description


@dataclass(frozen=True)
class ExperimentLink:
    """One experiment as printed by ``uavbench ui``: its id, name, the first line of its
    description (``""`` without one) and the URL of its Runs view."""

    experiment_id: str
    name: str
    description: str
    url: str


def experiment_url(base_url: str, experiment_id: str) -> str:
    """``http://127.0.0.1:5000/#/experiments/3?workflowType=machine_learning``: the classic Runs
    view of one experiment."""
    return f"{base_url.rstrip('/')}/#/experiments/{experiment_id}?{ML_VIEW}"


def run_url(base_url: str, experiment_id: str, run_id: str) -> str:
    """The page of one run (overview, parameters, metrics), in the classic view."""
    return f"{base_url.rstrip('/')}/#/experiments/{experiment_id}/runs/{run_id}?{ML_VIEW}"


def experiments_url(base_url: str) -> str:
    """The list of experiments, in the classic view (its links keep the view)."""
    return f"{base_url.rstrip('/')}/#/experiments?{ML_VIEW}"


def first_line(text: str | None, limit: int = 80) -> str:
    """The first non-empty line of ``text`` without Markdown emphasis, cut to ``limit``
    characters with an ellipsis; ``""`` for None or blank text."""
    for line in (text or "").splitlines():
        line = line.strip().lstrip("#").strip().replace("**", "")
        if line:
            return line if len(line) <= limit else line[: limit - 1].rstrip() + "…"
    return ""


def _natural_key(name: str) -> list[object]:
    """``table2`` before ``table10``: digit runs compare as numbers."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def experiment_links(
    base_url: str, experiments: Iterable[tuple[str, str, Mapping[str, str]]]
) -> list[ExperimentLink]:
    """Links for ``(experiment id, name, tags)`` triples, in natural name order (``fig5`` ...,
    ``table1``, ``table2`` ..., ``table10``); the description is the first line of the tag
    ``mlflow.note.content``."""
    links = [
        ExperimentLink(
            str(eid), name, first_line(tags.get(DESCRIPTION_TAG)), experiment_url(base_url, eid)
        )
        for eid, name, tags in experiments
    ]
    return sorted(links, key=lambda link: _natural_key(link.name))


def format_links(links: list[ExperimentLink], base_url: str) -> str:
    """The text ``uavbench ui`` prints under the server's URL: the experiment list, then per
    experiment its name and Runs-view URL and, indented below, its description's first line."""
    if not links:
        return (
            "no experiments in this store yet (run `uavbench reproduce` or `uavbench train`); "
            f"experiments: {experiments_url(base_url)}"
        )
    width = max(len(x.name) for x in links)
    lines = [f"experiments (classic Runs view): {experiments_url(base_url)}"]
    for x in links:
        lines.append(f"  {x.name:<{width}}  {x.url}")
        if x.description:
            lines.append(f"  {'':<{width}}  {x.description}")
    return "\n".join(lines)


def list_experiments(tracking_uri: str) -> list[tuple[str, str, dict[str, str]]]:
    """``(id, name, tags)`` of every active experiment of the store; MLflow's ``Default``
    experiment only when it holds runs (every new store has it, empty)."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=tracking_uri)
    out = []
    for exp in client.search_experiments():
        if exp.name == "Default" and not client.search_runs([exp.experiment_id], max_results=1):
            continue
        out.append((exp.experiment_id, exp.name, dict(exp.tags)))
    return out
