"""The house's size limits (CONTRIBUTING.md, "Style"): no module over 500 lines outside tests, no
function over 80 lines, no function with more than 12 parameters, and every docstring opening with
a one-line summary."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MAX_MODULE_LINES = 500
MAX_FUNCTION_LINES = 80
MAX_PARAMETERS = 12
MAX_MODULE_DOCSTRING_LINES = 15


def _modules() -> list[Path]:
    return sorted(p for package in ("companion", "sim_vehicles") for p in (ROOT / package).rglob("*.py"))


def _functions(tree: ast.AST) -> list[ast.FunctionDef | ast.AsyncFunctionDef]:
    return [n for n in ast.walk(tree) if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef)]


def _parameters(f: ast.FunctionDef | ast.AsyncFunctionDef) -> int:
    a = f.args
    bound = bool(a.args) and a.args[0].arg in ("self", "cls")
    return len(a.posonlyargs) + len(a.args) + len(a.kwonlyargs) - bound


def test_the_package_is_found() -> None:
    assert len(_modules()) > 100


def test_no_module_is_over_500_lines() -> None:
    sizes = {str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in _modules()}
    assert not {name: n for name, n in sizes.items() if n > MAX_MODULE_LINES}


def test_no_function_is_over_80_lines_or_12_parameters() -> None:
    found = []
    for p in _modules():
        for f in _functions(ast.parse(p.read_text())):
            lines = (f.end_lineno or f.lineno) - f.lineno + 1
            if lines > MAX_FUNCTION_LINES or _parameters(f) > MAX_PARAMETERS:
                where = f"{p.relative_to(ROOT)}:{f.lineno} {f.name}"
                found.append(f"{where}: {lines} lines, {_parameters(f)} parameters")
    assert not found


def test_docstrings_open_with_one_line() -> None:
    """A module's docstring is short, and every docstring's first sentence ends on its first line or
    is followed by a blank line (a summary a reader takes in at a glance)."""
    found = []
    for p in _modules():
        tree = ast.parse(p.read_text())
        doc = ast.get_docstring(tree, clean=False)
        if doc and len(doc.splitlines()) > MAX_MODULE_DOCSTRING_LINES:
            found.append(f"{p.relative_to(ROOT)}: module docstring of {len(doc.splitlines())} lines")
        for node in [tree, *ast.walk(tree)]:
            if not isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
                continue
            lines = (ast.get_docstring(node, clean=False) or "").splitlines()
            if len(lines) > 1 and lines[1].strip():
                where = f"{p.relative_to(ROOT)}:{getattr(node, 'lineno', 1)}"
                found.append(f"{where} summary runs on: {lines[0]!r}")
    assert not found
