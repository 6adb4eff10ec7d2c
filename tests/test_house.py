"""The rules of the house style that a test can hold: every function of swat_jax is short."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "swat_jax"
MAX_FUNCTION_LINES = 60
"""The most lines a function of swat_jax spans, def to last line (nested functions count in theirs)."""


def function_spans(tree: ast.AST, prefix: str = "") -> Iterator[tuple[str, int, int]]:
    """Every function and method under ``tree`` as (qualified name, first line, lines spanned), nested
    ones included: ``end_lineno - lineno + 1`` of its ``def`` (decorators not counted)."""
    for node in ast.iter_child_nodes(tree):
        name = f"{prefix}{getattr(node, 'name', '')}"
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            yield name, node.lineno, node.end_lineno - node.lineno + 1
        scope = isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef)
        yield from function_spans(node, f"{name}." if scope else prefix)


def test_function_spans_name_nested_functions_and_methods():
    source = "class A:\n    def f(self):\n        def g():\n            pass\n\n        return g\n"
    assert list(function_spans(ast.parse(source))) == [("A.f", 2, 5), ("A.f.g", 3, 2)]


def test_every_function_of_swat_jax_is_at_most_60_lines():
    """A longer one is split into named steps with docstrings, pieces a reader finds by name and another
    function can reuse, not cut into arbitrary halves (docs/development.md)."""
    long = [
        f"{path.relative_to(PACKAGE.parent)}:{line} {name} ({lines} lines)"
        for path in sorted(PACKAGE.rglob("*.py"))
        for name, line, lines in function_spans(ast.parse(path.read_text(), str(path)))
        if lines > MAX_FUNCTION_LINES
    ]
    assert not long, f"functions longer than {MAX_FUNCTION_LINES} lines: " + "; ".join(long)
