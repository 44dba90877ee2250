"""No function or method in ``reach/`` or ``service/`` runs over 60 lines (from ``def`` to its last
line, the docstring included), except the numeric kernels of ``reach/`` named below, each of which
says in its docstring why it is kept whole."""

from __future__ import annotations

import ast
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
MAX_LINES = 60
KERNEL_REASON = "A numeric kernel kept whole so its maths reads in one place."

#: The numeric kernels of reach/, by qualified name (module.Class.function).
KERNELS = {
    "reach.corridors._Corridors.supports",
    "reach.partition.partition_tubes",
    "reach.partition.partition_supports",
    "reach.speed_programme._corridor_gain_rows",
}


def _functions(
    node: ast.AST, prefix: str
) -> Iterator[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef]]:
    for child in ast.iter_child_nodes(node):
        if isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef):
            name = f"{prefix}.{child.name}"
            yield name, child
            yield from _functions(child, name)
        elif isinstance(child, ast.ClassDef):
            yield from _functions(child, f"{prefix}.{child.name}")
        else:
            yield from _functions(child, prefix)


def functions_in(folder: str) -> Iterator[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef]]:
    """Every function and method under ``folder`` by qualified name."""
    for path in sorted((ROOT / folder).rglob("*.py")):
        module = ".".join(path.relative_to(ROOT).with_suffix("").parts)
        yield from _functions(ast.parse(path.read_text(), filename=str(path)), module)


def _length(node: ast.AST) -> int:
    assert node.end_lineno is not None
    return node.end_lineno - node.lineno + 1


@pytest.mark.parametrize("folder", ["reach", "service"])
def test_no_function_runs_over_60_lines(folder: str) -> None:
    long = [
        f"{name} ({_length(node)} lines, {folder}:{node.lineno})"
        for name, node in functions_in(folder)
        if _length(node) > MAX_LINES and name not in KERNELS
    ]
    assert not long, "split these into well-named pieces:\n" + "\n".join(long)


def test_every_kernel_exists_and_says_why_it_is_whole() -> None:
    found = dict(functions_in("reach"))
    for name in sorted(KERNELS):
        assert name in found, f"{name} is allowed to be long but does not exist"
        docstring = " ".join((ast.get_docstring(found[name]) or "").split())
        assert KERNEL_REASON in docstring, f"{name}'s docstring does not say why it is whole"
