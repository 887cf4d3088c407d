"""Every public signature is typed (DEVELOPERS.md, style): each parameter of a public function or
method in ``benchmark/`` and ``baselines/`` has an annotation, and so has its return (``__init__``
excepted). Public = reachable by a name without a leading underscore (dunder methods count), at
module level or in a public class; functions nested in functions are private by nature.

Checked on the source with ``ast``, so nothing is imported or run.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Untyped public functions of the simulator, left as they are on purpose: any byte of
# ``benchmark/sim`` enters the dataset's generator digest (``benchmark.sim.source_digest``), so
# typing them re-renders every dataset and retrains every cached reproduction unit. They are to
# be typed with the next change of the simulator; the list may only shrink.
SIM_UNTYPED = {
    "benchmark/sim/city_blocks.py": {"pick", "fill_park"},
    "benchmark/sim/city_details.py": {"bus_lanes", "meander", "add_railway"},
    "benchmark/sim/city_districts.py": {"partition"},
    "benchmark/sim/render_core.py": {"ground_bilinear", "trace", "render_image"},
    "benchmark/sim/world_city.py": {"ground_height", "surface_height", "clearance"},
}


def _is_public(name: str) -> bool:
    return not name.startswith("_") or (name.startswith("__") and name.endswith("__"))


def untyped_public_functions(source: str) -> list[tuple[str, int, list[str]]]:
    """``(name, line, what is missing)`` for each public function of ``source`` whose signature
    lacks an annotation (``self``/``cls`` as first parameter excepted)."""
    found: list[tuple[str, int, list[str]]] = []

    def visit(node: ast.AST, public: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
                if public and _is_public(child.name):
                    a = child.args
                    params = a.posonlyargs + a.args + a.kwonlyargs
                    missing = [
                        p.arg
                        for i, p in enumerate(params)
                        if p.annotation is None and not (i == 0 and p.arg in ("self", "cls"))
                    ]
                    missing += [
                        prefix + v.arg
                        for prefix, v in (("*", a.vararg), ("**", a.kwarg))
                        if v is not None and v.annotation is None
                    ]
                    if child.returns is None and child.name != "__init__":
                        missing.append("return")
                    if missing:
                        found.append((child.name, child.lineno, missing))
                visit(child, public=False)  # nested functions are private
            elif isinstance(child, ast.ClassDef):
                visit(child, public and _is_public(child.name))
            else:
                visit(child, public)

    visit(ast.parse(source), public=True)
    return found


FILES = sorted(p for folder in ("benchmark", "baselines") for p in (ROOT / folder).rglob("*.py"))


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(ROOT)))
def test_public_signatures_are_typed(path: Path) -> None:
    name = str(path.relative_to(ROOT))
    allowed = SIM_UNTYPED.get(name, set())
    found = untyped_public_functions(path.read_text())
    untyped = [f"{fn} (line {line}: {', '.join(miss)})" for fn, line, miss in found
               if fn not in allowed]  # fmt: skip
    assert not untyped, f"{name}: public signatures without types: {'; '.join(untyped)}"


def test_the_simulator_exceptions_are_still_untyped() -> None:
    """The exception list names only what still needs it: a function typed since (or renamed)
    must leave the list, so that it cannot hide a new untyped one of the same name."""
    stale = []
    for name, functions in SIM_UNTYPED.items():
        untyped = {fn for fn, _, _ in untyped_public_functions((ROOT / name).read_text())}
        stale += [f"{name}: {fn}" for fn in sorted(functions - untyped)]
    assert not stale, f"typed now, remove from SIM_UNTYPED: {stale}"


class TestUntypedPublicFunctions:
    """The checker itself, on small sources."""

    def test_finds_a_missing_parameter_and_return(self) -> None:
        found = untyped_public_functions("def f(a, b: int):\n    return a\n")
        assert found == [("f", 1, ["a", "return"])]

    def test_skips_private_nested_and_self(self) -> None:
        source = (
            "def _p(a):\n    pass\n"
            "def g() -> None:\n    def inner(x):\n        pass\n"
            "class C:\n    def m(self, x: int) -> int:\n        return x\n"
            "    def __init__(self, y: int):\n        pass\n"
            "class _Hidden:\n    def m(self, x):\n        pass\n"
        )
        assert untyped_public_functions(source) == []

    def test_dunder_methods_and_star_arguments_count(self) -> None:
        source = "class C:\n    def __call__(self, *xs, **kw) -> None:\n        pass\n"
        assert untyped_public_functions(source) == [("__call__", 2, ["*xs", "**kw"])]
