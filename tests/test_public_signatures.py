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
    found = untyped_public_functions(path.read_text())
    untyped = [f"{fn} (line {line}: {', '.join(miss)})" for fn, line, miss in found]
    assert not untyped, f"{name}: public signatures without types: {'; '.join(untyped)}"


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
