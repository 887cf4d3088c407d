"""The import layering of DEVELOPERS.md, checked on the source (every import, lazy ones included).

simulate -> dataset -> encoder/heads -> loss/metrics -> training -> runner -> tables/tracking:
imports only point down. ``benchmark.cli`` is the command table at the top; nothing below imports
it (``UsageError`` lives in the leaf module ``benchmark.errors``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Package -> the packages of ours it may import (besides itself).
ALLOWED: dict[str, set[str]] = {
    "errors": set(),
    "geometry": set(),
    "progress": set(),
    "config": set(),
    "locks": set(),  # the one-writer lock file (simulate, reproduce)
    "sim": {"geometry", "progress"},
    "data": {"geometry", "sim", "progress", "errors", "locks"},
    # baselines: the registry's plugin discovery; config: YAML scalars of head options
    "models": {"geometry", "errors", "baselines", "config"},
    "baselines": {"geometry", "models"},
    "analysis": {"geometry", "data", "errors"},  # heading_cue reads datasets (PairDataset)
    "evaluation": {"geometry", "data", "models", "progress", "errors"},
    "tracking": {"errors", "locks"},
    # the non-learned references (issue 21): evaluated like models, never imported by them
    "references": {"geometry", "data", "sim", "evaluation", "progress", "errors"},
    "training": {
        *("geometry", "data", "models", "evaluation", "config", "progress", "errors"),
        "tracking",  # command.py only (see TRACKING_CLIENTS)
        "locks",  # encoded.py: one unit encodes a split for a frozen encoder, the others wait
    },
}
# Modules that may reach the tracking interface: the runner, the CLI and `uavbench train`.
TRACKING_CLIENTS = ("benchmark/runner/", "benchmark/cli.py", "benchmark/training/command.py")
# What baselines may import: the head contract, its building blocks and geometry.
BASELINE_IMPORTS = {
    "benchmark.geometry",
    "benchmark.models",
    "benchmark.models.heads",
    "benchmark.models.spherical",
}


def package_of(module: str) -> str | None:
    """``benchmark.sim.render`` -> ``sim``; ``baselines.x`` -> ``baselines``; others None."""
    parts = module.split(".")
    if parts[0] == "baselines":
        return "baselines"
    if parts[0] == "benchmark" and len(parts) > 1:
        return parts[1]
    return None


def source_files() -> list[Path]:
    return sorted([*ROOT.glob("benchmark/**/*.py"), *ROOT.glob("baselines/*.py")])


def imports_of(path: Path) -> list[str]:
    """Absolute module names imported anywhere in ``path`` (inside functions too)."""
    names = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
    return [n for n in names if package_of(n) is not None or n == "benchmark"]


def rel(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def own_package(path: Path) -> str:
    package = package_of(rel(path).removesuffix(".py").replace("/", "."))
    assert package is not None, path
    return package


FILES = source_files()


@pytest.mark.parametrize("path", FILES, ids=rel)
def test_imports_point_down(path):
    package = own_package(path)
    if package not in ALLOWED:
        return  # runner, cli, bench, __main__: the top, may import anything below
    bad = [
        name
        for name in imports_of(path)
        if (target := package_of(name)) not in (None, package) and target not in ALLOWED[package]
    ]
    assert not bad, (
        f"{rel(path)} ({package}) imports {bad}; {package} may import {ALLOWED[package]}"
    )


@pytest.mark.parametrize("path", FILES, ids=rel)
def test_only_runner_cli_and_train_command_reach_tracking(path):
    if rel(path).startswith(("benchmark/tracking/", *TRACKING_CLIENTS)):
        return
    bad = [n for n in imports_of(path) if package_of(n) == "tracking"]
    assert not bad, f"{rel(path)} imports {bad}; only {TRACKING_CLIENTS} may"


@pytest.mark.parametrize("path", sorted(ROOT.glob("baselines/*.py")), ids=rel)
def test_baselines_use_only_the_head_contract_and_geometry(path):
    bad = set(imports_of(path)) - BASELINE_IMPORTS
    assert not bad, f"{rel(path)} imports {sorted(bad)}; baselines may import {BASELINE_IMPORTS}"


# references (issue 21) reach sim and data through their public API too
SIM_DATA_MODELS = [p for p in FILES if own_package(p) in ("sim", "data", "models", "references")]


@pytest.mark.parametrize("path", SIM_DATA_MODELS, ids=rel)
def test_sim_data_models_use_each_others_public_api(path):
    # benchmark.sim (the package), never benchmark.sim.splits etc.; the same for data and models.
    package = own_package(path)
    bad = [
        n
        for n in imports_of(path)
        if package_of(n) in ("sim", "data", "models")
        and package_of(n) != package
        and n.count(".") > 1
    ]
    assert not bad, f"{rel(path)} imports the internals {bad}"


def test_no_import_cycles_between_packages():
    # The registry's discovery of baselines is excluded: it is a plugin load, not a dependency.
    graph: dict[str, set[str]] = {}
    for path in FILES:
        package = own_package(path)
        for name in imports_of(path):
            target = package_of(name)
            if target in (None, package) or (package, target) == ("models", "baselines"):
                continue
            graph.setdefault(package, set()).add(target)
    state: dict[str, str] = {}

    def visit(node: str, trail: list[str]) -> None:
        state[node] = "open"
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == "open":
                raise AssertionError(f"import cycle: {' -> '.join([*trail, node, nxt])}")
            if nxt not in state:
                visit(nxt, [*trail, node])
        state[node] = "done"

    for node in sorted(graph):
        if node not in state:
            visit(node, [])
