"""The import layering of DEVELOPERS.md, checked on the source (every import, lazy ones included).

simulate -> dataset -> encoder/heads -> loss/metrics -> training -> runner -> tables/tracking:
imports only point down. ``benchmark.commands`` is the command layer on the top floor: it may
import every package, and nothing but the entry points (``benchmark/cli.py``,
``benchmark/__main__.py``) imports it (``UsageError`` lives in the leaf module
``benchmark.errors``). argparse lives there and nowhere else; no two modules import each other,
directly or round a circle.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Package -> the packages of ours it may import (besides itself).
ALLOWED: dict[str, set[str]] = {
    "errors": set(),
    "machine": set(),  # facts about this machine (the CPU model): data's bench isa, models
    "geometry": set(),
    "progress": set(),
    "config": set(),
    "locks": set(),  # the one-writer lock file (simulate, reproduce)
    "sim": {"geometry", "progress"},
    "data": {"geometry", "sim", "progress", "errors", "locks", "machine"},
    # config: YAML scalars of head options. Not baselines: the registry finds the heads through
    # the entry point group uavbench.heads (pyproject.toml), so no import points up.
    "models": {"geometry", "errors", "config", "machine"},
    "baselines": {"geometry", "models"},
    "analysis": {"geometry", "data", "errors", "progress"},  # heading_cue reads datasets
    "evaluation": {"geometry", "data", "models", "progress", "errors"},
    "tracking": {"errors", "locks", "progress"},  # progress: status lines (a server, a sync)
    # the non-learned references (issue 21): evaluated like models, never imported by them
    "references": {"geometry", "data", "sim", "evaluation", "progress", "errors"},
    "training": {
        *("geometry", "data", "models", "evaluation", "config", "progress", "errors"),
        "tracking",  # tracked_run.py only (see TRACKING_CLIENTS)
        "locks",  # encoded.py: one unit encodes a split for a frozen encoder, the others wait
    },
}
# Modules that may reach the tracking interface: the runner, the commands and `uavbench train`.
TRACKING_CLIENTS = (
    "benchmark/runner/",
    "benchmark/commands/",
    "benchmark/training/tracked_run.py",
)
# The command layer's entry points: the console script's old path and `python -m benchmark`.
COMMAND_ENTRIES = ("benchmark/cli.py", "benchmark/__main__.py")
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


def imports_of_any(path: Path) -> list[str]:
    """Every absolute module name imported anywhere in ``path`` (inside functions too), ours or
    not."""
    names = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.append(node.module)
    return names


def imports_of(path: Path) -> list[str]:
    """Our absolute module names imported anywhere in ``path`` (inside functions too)."""
    return [n for n in imports_of_any(path) if package_of(n) is not None or n == "benchmark"]


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
        return  # commands, runner, cli, __main__: the top, may import anything below
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
    graph: dict[str, set[str]] = {}
    for path in FILES:
        package = own_package(path)
        for name in imports_of(path):
            target = package_of(name)
            if target in (None, package):
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


def dynamic_imports_of(path: Path) -> list[str]:
    """The leading text of every ``import_module(...)`` / ``__import__(...)`` argument in ``path``
    that is a string or an f-string (its constant head), which :func:`imports_of` cannot see."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if not (isinstance(node, ast.Call) and node.args):
            continue
        func = node.func
        called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
        if called not in ("import_module", "__import__"):
            continue
        arg = node.args[0]
        if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
            found.append(arg.value)
        elif isinstance(arg, ast.JoinedStr) and arg.values:
            head = arg.values[0]
            if isinstance(head, ast.Constant):
                found.append(str(head.value))
    return found


@pytest.mark.parametrize("path", FILES, ids=rel)
def test_no_module_loads_a_higher_package_by_name(path):
    # The head registry finds baselines/ through the entry point group uavbench.heads
    # (pyproject.toml), not by naming it: a dynamic import of a higher package is an arrow up
    # that the static check above cannot see.
    package = own_package(path)
    if package not in ALLOWED:
        return
    bad = [
        name
        for name in dynamic_imports_of(path)
        if (target := package_of(name.rstrip("."))) not in (None, package)
        and target not in ALLOWED[package]
    ]
    assert not bad, f"{rel(path)} loads {bad} by name; {package} may import {ALLOWED[package]}"


@pytest.mark.parametrize("path", FILES, ids=rel)
def test_only_the_entry_points_import_the_command_layer(path):
    if rel(path).startswith(("benchmark/commands/", *COMMAND_ENTRIES)):
        return
    bad = [n for n in imports_of(path) if package_of(n) == "commands"]
    assert not bad, f"{rel(path)} imports {bad}; only {COMMAND_ENTRIES} may"


def test_argparse_only_in_the_command_layer():
    # `grep -rl argparse benchmark baselines` lists only benchmark/commands/ files.
    found = [rel(p) for p in FILES if "argparse" in p.read_text()]
    bad = [name for name in found if not name.startswith("benchmark/commands/")]
    assert not bad, f"argparse outside benchmark/commands/: {bad}"


def module_name(path: Path) -> str:
    """``benchmark/data/__init__.py`` -> ``benchmark.data``; ``baselines/ipdf.py`` ->
    ``baselines.ipdf``."""
    name = rel(path).removesuffix(".py").replace("/", ".")
    return name.removesuffix(".__init__")


def module_graph() -> dict[str, set[str]]:
    """Module -> the modules of ours it imports (lazy imports included, as :func:`imports_of`
    finds them). ``from pkg import x`` is an import of ``pkg.x`` when ``x`` is a module, else of
    ``pkg``."""
    modules = {module_name(p): p for p in FILES}
    graph: dict[str, set[str]] = {}
    for name, path in modules.items():
        submodules: dict[str, set[str]] = {}  # pkg -> pkg.x imported as `from pkg import x`
        other_names: set[str] = set()  # pkg of a `from pkg import y` where y is no module
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                for alias in node.names:
                    full = f"{node.module}.{alias.name}"
                    if full in modules:
                        submodules.setdefault(node.module, set()).add(full)
                    else:
                        other_names.add(node.module)
            elif isinstance(node, ast.Import):
                other_names |= {alias.name for alias in node.names}
        targets = set()
        for target in imports_of(path):
            if target in submodules:
                targets |= submodules[target]
            if target in other_names or target not in submodules:
                targets.add(target)
        graph[name] = {t for t in targets if t in modules and t != name}
    return graph


def import_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    cycles: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in sorted(graph.get(node, ())):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return cycles


def test_no_import_cycles_between_modules():
    cycles = import_cycles(module_graph())
    assert not cycles, "import circles between modules: " + "; ".join(
        " <-> ".join(c) for c in cycles
    )


# The runner's rooms, in pipeline order (issue 22): a module imports only its own room or a
# lower one; the top level (reproduction, __init__) may import every room.
RUNNER_ROOMS = ("plan", "execute", "claims", "report")
RUNNER_TOP_MODULES_MAX = 8


def runner_room(module: str) -> str | None:
    """``benchmark.runner.claims.paper`` -> ``claims``; top-level runner modules -> ``top``;
    modules outside the runner -> None."""
    parts = module.split(".")
    if parts[:2] != ["benchmark", "runner"]:
        return None
    return parts[2] if len(parts) > 2 and parts[2] in RUNNER_ROOMS else "top"


RUNNER_FILES = [p for p in FILES if rel(p).startswith("benchmark/runner/")]


@pytest.mark.parametrize("path", RUNNER_FILES, ids=rel)
def test_runner_rooms_import_only_down_the_pipeline(path):
    room = runner_room(module_name(path))
    if room == "top":
        return
    floor = RUNNER_ROOMS.index(room)
    bad = [
        name
        for name in imports_of(path)
        if (target := runner_room(name)) is not None
        and (target == "top" or RUNNER_ROOMS.index(target) > floor)
    ]
    assert not bad, f"{rel(path)} ({room}) imports {bad}; rooms in order: {RUNNER_ROOMS}"


def test_runner_top_level_stays_small():
    top = sorted(p.name for p in (ROOT / "benchmark" / "runner").glob("*.py"))
    rooms = sorted(p.name for p in (ROOT / "benchmark" / "runner").iterdir() if p.is_dir()
                   and (p / "__init__.py").is_file())  # fmt: skip
    assert len(top) <= RUNNER_TOP_MODULES_MAX, top
    assert set(RUNNER_ROOMS) <= set(rooms), rooms


# ------------------------------------------------------------------ benches and the command line
# Every bench in one room (issue 41): ``benchmark/bench/``; ``benchmark/commands/bench_*.py`` are
# its command adapters (flags -> config -> library call).
BENCH_ROOM = "benchmark/bench/"


@pytest.mark.parametrize("path", FILES, ids=rel)
def test_benches_live_in_one_room(path):
    where = rel(path)
    if where.startswith((BENCH_ROOM, "benchmark/commands/")):
        return
    assert not path.stem.startswith("bench"), (
        f"{where}: a bench module outside {BENCH_ROOM} (move it there; the command adapter "
        "stays in benchmark/commands/)"
    )


@pytest.mark.parametrize("path", FILES, ids=rel)
def test_only_the_command_layer_imports_the_benches(path):
    where = rel(path)
    if where.startswith((BENCH_ROOM, "benchmark/commands/", *COMMAND_ENTRIES)):
        return
    bad = [n for n in imports_of(path) if package_of(n) == "bench"]
    assert not bad, f"{where} imports {bad}; only benchmark/commands/ may import the benches"


def launches_the_command_line(path: Path) -> list[str]:
    """Literal argument lists in ``path`` that start this package's command line: ``-m``
    followed by ``benchmark``/``benchmark.cli``/``benchmark.__main__``, or ``uavbench`` as the
    program (a list or tuple of strings, as ``subprocess`` takes)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if not isinstance(node, (ast.List, ast.Tuple)):
            continue
        # positions kept: a non-string element (sys.executable, an f-string) is None
        words = [e.value if isinstance(e, ast.Constant) and isinstance(e.value, str) else None
                 for e in node.elts]  # fmt: skip
        for i, word in enumerate(words):
            after = words[i + 1] if i + 1 < len(words) else None
            if (word == "-m" and after in ("benchmark", "benchmark.cli", "benchmark.__main__")) or (
                i == 0 and word == "uavbench"
            ):
                found.append(f"line {node.lineno}: {words[:6]}")
    return found


@pytest.mark.parametrize("path", FILES, ids=rel)
def test_no_library_module_launches_the_command_line(path):
    # A library call in a fresh interpreter (benchmark.bench.fresh_process) replaces it: the
    # library never depends on flag names.
    if rel(path).startswith("benchmark/commands/"):
        return
    found = launches_the_command_line(path)
    assert not found, f"{rel(path)} starts the uavbench command line: {found}"


def test_the_launch_check_sees_a_launch(tmp_path):
    launcher = tmp_path / "launcher.py"
    launcher.write_text(
        "import subprocess, sys\n"
        "subprocess.run([sys.executable, '-m', 'benchmark', 'simulate', '--profile', 'smoke'])\n"
        "subprocess.run(('uavbench', 'reproduce'))\n"
        "subprocess.run([sys.executable, '-m', 'pytest'])\n"
        "requirements = [f'torch=={1}', 'uavbench']\n"
    )
    assert len(launches_the_command_line(launcher)) == 2


# ------------------------------------------- the library returns values and raises typed errors
# Issue 41: printing, exit codes and flag names only in the command layer. Library code reports
# long-running work through the progress display (benchmark/progress.py: the bar and status()),
# returns its results for the commands to print, and raises typed errors (benchmark.errors:
# InputError; UsageError is the command line's, raised by the commands and config validation).
PRINTING_ALLOWED = ("benchmark/commands/", "benchmark/progress.py")
USAGE_ERROR_ALLOWED = ("benchmark/commands/", "benchmark/config.py", "benchmark/errors.py",
                       "benchmark/cli.py")  # fmt: skip
FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
LIBRARY_FILES = [p for p in FILES if not rel(p).startswith("benchmark/commands/")]


def prints_or_exits(path: Path) -> list[str]:
    """``print(...)``, ``sys.exit(...)``, ``exit(...)`` and ``quit(...)`` calls in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Name) and f.id in ("print", "exit", "quit"):
            found.append(f"line {node.lineno}: {f.id}()")
        elif (
            isinstance(f, ast.Attribute)
            and f.attr == "exit"
            and getattr(f.value, "id", "") == "sys"
        ):
            found.append(f"line {node.lineno}: sys.exit()")
    return found


def flags_in_raised_messages(path: Path) -> list[str]:
    """Command-line flags (``--name``) in the string parts of every ``raise``'s exception."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Raise) and node.exc is not None:
            for part in ast.walk(node.exc):
                if isinstance(part, ast.Constant) and isinstance(part.value, str):
                    found += [f"line {node.lineno}: {m}" for m in FLAG.findall(part.value)]
    return found


@pytest.mark.parametrize("path", LIBRARY_FILES, ids=rel)
def test_library_neither_prints_nor_exits(path):
    if rel(path).startswith(PRINTING_ALLOWED):
        return
    found = prints_or_exits(path)
    assert not found, (
        f"{rel(path)}: {found}; report through benchmark.progress (status, Progress) or return "
        "the result for the command to print"
    )


@pytest.mark.parametrize("path", LIBRARY_FILES, ids=rel)
def test_usage_error_only_in_the_command_layer(path):
    if rel(path).startswith(USAGE_ERROR_ALLOWED):
        return
    names = {
        node.id if isinstance(node, ast.Name) else node.attr
        for node in ast.walk(ast.parse(path.read_text(), str(path)))
        if isinstance(node, (ast.Name, ast.Attribute))
    } | {
        alias.name
        for node in ast.walk(ast.parse(path.read_text(), str(path)))
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
    }
    assert "UsageError" not in names, f"{rel(path)} uses UsageError; raise InputError instead"


@pytest.mark.parametrize("path", LIBRARY_FILES, ids=rel)
def test_no_flag_name_in_a_library_message(path):
    found = flags_in_raised_messages(path)
    assert not found, f"{rel(path)}: {found}; name the config field or argument, not the flag"


def test_the_library_checks_see_what_they_look_for(tmp_path):
    source = tmp_path / "library.py"
    source.write_text(
        "import sys\n"
        "print('hello')\n"
        "sys.exit(2)\n"
        "raise ValueError(f'--workers must be >= 1, got {0}')\n"
        "raise ValueError('workers must be >= 1; a negative-number -3 and x--y are no flags')\n"
    )
    assert len(prints_or_exits(source)) == 2
    assert [f.split(": ")[1] for f in flags_in_raised_messages(source)] == ["--workers"]


# ----------------------------------------------------------- claims decide, the report writes
# Issue 41 item 1: the work of a reproduction (rendering datasets, reading images, evaluating
# the references, fusing along flights, planning) happens before the claims and the report, in
# the plan and execute rooms, run by benchmark/runner/reproduction.py. The claims are functions
# of results and the report a writer: neither imports these modules, calls these functions or
# imports torch (the weights' digests: execute/provenance.py; Table 6: execute/costs.py).
WORK_MODULES = (
    "benchmark.sim",
    "benchmark.analysis",
    "benchmark.references",
    "benchmark.data.writer",
    "benchmark.data.simulate",
    "benchmark.evaluation.sequence_eval",
    "benchmark.evaluation.fusion",
    "benchmark.training.pipeline",  # training and evaluating (its configs and tags are data)
    "benchmark.training.loop",
    "benchmark.training.build",
    "benchmark.training.encoded",
)
WORK_FUNCTIONS = {
    "heading_cue_rows", "cue_dataset_roots", "simulate_dataset", "evaluate_references",
    "fuse_non_learned", "fuse_estimates", "fuse_predictions", "plan_units", "plan_merge",
    "constant_rows", "collect_provenance", "measure_costs", "cost_rows", "model_info",
}  # fmt: skip
PURE_ROOMS = ("benchmark/runner/claims/", "benchmark/runner/report/")


def imported_names(path: Path) -> set[str]:
    """The names ``from x import name`` brings into ``path`` (inside functions too)."""
    return {
        alias.name
        for node in ast.walk(ast.parse(path.read_text(), str(path)))
        if isinstance(node, ast.ImportFrom)
        for alias in node.names
    }


def work_imports(path: Path) -> list[str]:
    """What in ``path`` reaches the reproduction's work: a work module or a work function."""
    modules = [
        n for n in imports_of(path) if any(n == m or n.startswith(m + ".") for m in WORK_MODULES)
    ]
    return modules + sorted(imported_names(path) & WORK_FUNCTIONS)


@pytest.mark.parametrize("path", [p for p in FILES if rel(p).startswith(PURE_ROOMS)], ids=rel)
def test_claims_and_report_do_no_work(path):
    found = work_imports(path)
    found += [n for n in imports_of_any(path) if n == "torch" or n.startswith("torch.")]
    assert not found, (
        f"{rel(path)} reaches {found}: the work runs before the claims and the report "
        "(benchmark/runner/reproduction.py: execute room); they read its results"
    )


# The report prints numbers computed before it (claims.report_numbers): no report module reaches a
# function that computes an interval, a bootstrap or a verdict.
NUMBER_FUNCTIONS = {
    "summarize", "row_interval", "cell_interval", "frame_interval", "seed_flight_bootstrap",
    "median_bootstrap", "pooled_bootstrap", "paired_bootstrap", "spearman_bootstrap",
    "sequence_rows", "load_sequences", "sequence_numbers", "evaluate_claims", "report_numbers",
}  # fmt: skip


@pytest.mark.parametrize(
    "path", [p for p in FILES if rel(p).startswith("benchmark/runner/report/")], ids=rel
)
def test_the_report_computes_no_number(path):
    found = sorted(imported_names(path) & NUMBER_FUNCTIONS)
    assert not found, (
        f"{rel(path)} imports {found}: the report renders numbers computed before it is written "
        "(benchmark/runner/claims/report_numbers.py, run by benchmark/runner/reproduction.py)"
    )


def test_the_writer_is_called_with_its_inputs_by_the_orchestration():
    # one function strings the work together: the reproduction computes the report's inputs
    source = (ROOT / "benchmark/runner/reproduction.py").read_text()
    assert "def _report_inputs(" in source and "inputs=inputs" in source
    assert "def _report_numbers(" in source and "numbers=numbers" in source


# Issue 41 item 1: the references' evaluations and the audit's datasets are work items the
# units' executor runs (pool or Ray), not a pool of their own: in the runner only the executor
# starts processes, and the orchestration hands the report stage's work to it.
POOL_MODULES = ("benchmark/runner/execute/pool.py", "benchmark/runner/execute/work_pool.py")


def starts_processes(path: Path) -> bool:
    """Whether ``path`` makes a process pool or a multiprocessing context."""
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if name in ("ProcessPoolExecutor", "get_context", "Pool"):
                return True
    return False


@pytest.mark.parametrize(
    "path", [p for p in FILES if rel(p).startswith("benchmark/runner/")], ids=rel
)
def test_only_the_executor_starts_processes_in_the_runner(path):
    if rel(path) in POOL_MODULES:
        return
    assert not starts_processes(path), (
        f"{rel(path)} starts processes of its own: hand its work to the executor as work items "
        "(benchmark/runner/execute/work_items.py, run by pool.run_work_items: pool or Ray)"
    )


def test_the_report_stage_work_goes_through_the_executor():
    source = (ROOT / "benchmark/runner/reproduction.py").read_text()
    names = imported_names(ROOT / "benchmark/runner/reproduction.py")
    assert {"run_work_items", "plan_references", "cue_dataset_items"} <= names
    assert "evaluate_references" not in names and "evaluate_references(" not in source


def test_starts_processes_finds_a_pool(tmp_path):
    # the checker itself, on the pool the references ran in before issue 41 (it must fail there)
    probe = tmp_path / "probe.py"
    probe.write_text("ctx = multiprocessing.get_context('spawn')\n")
    assert starts_processes(probe)
    probe.write_text("pool = cf.ProcessPoolExecutor(2)\n")
    assert starts_processes(probe)
    probe.write_text("context = 'spawn'\n")
    assert not starts_processes(probe)
