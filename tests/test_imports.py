"""Structure: no import circles anywhere in eurocslam, core modules that import no I/O, modules of
a readable size.

The import graph is read from the source (module-level and function-level imports alike), so a
circle hidden in a function body counts too.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import eurocslam

PKG = Path(eurocslam.__file__).parent
MAX_LINES = 500  # any module: one that grows past it holds more than one concept


def _modules() -> dict[str, Path]:
    out = {}
    for p in PKG.rglob("*.py"):
        parts = p.relative_to(PKG.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = p
    return out


def _resolve(name: str, mods: dict[str, Path]) -> str | None:
    while name and name not in mods:
        name = name.rpartition(".")[0]
    return name or None


def _imports(path: Path, mods: dict[str, Path]) -> set[str]:
    """eurocslam modules `path` imports (anywhere in the file)."""
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f"{node.module}.{a.name}" for a in node.names]
        for n in names:
            r = _resolve(n, mods)
            if r is not None and r.startswith("eurocslam"):
                out.add(r)
    return out


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    mods = _modules()
    return {m: _imports(p, mods) - {m} for m, p in mods.items()}


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, ()):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_circles(graph: dict[str, set[str]]) -> None:
    assert not _circles(graph)


@pytest.mark.parametrize("core", ["eurocslam.timebase", "eurocslam.trajectory"])
def test_core_modules_import_no_io(graph: dict[str, set[str]], core: str) -> None:
    allowed = {"eurocslam.geometry", "eurocslam.errors", "eurocslam.timebase"}
    assert graph[core] <= allowed, sorted(graph[core] - allowed)


def test_module_sizes() -> None:
    sizes = {m: len(p.read_text().splitlines()) for m, p in _modules().items()}
    big = {m: n for m, n in sizes.items() if n > MAX_LINES}
    assert not big, big


def test_the_checks_see_a_circle(tmp_path: Path) -> None:
    mods = {"eurocslam.a": tmp_path / "a.py", "eurocslam.b": tmp_path / "b.py"}
    mods["eurocslam.a"].write_text("def f():\n    from eurocslam.b import g\n")
    mods["eurocslam.b"].write_text("from eurocslam import a\n")
    g = {m: _imports(p, mods) for m, p in mods.items()}
    assert g == {"eurocslam.a": {"eurocslam.b"}, "eurocslam.b": {"eurocslam.a"}}
    assert _circles(g) == [["eurocslam.a", "eurocslam.b"]]
    assert _circles({"eurocslam.a": {"eurocslam.b"}, "eurocslam.b": set()}) == []
