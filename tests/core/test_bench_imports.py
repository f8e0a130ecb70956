"""The benchmark package's imports point one way: no module of ``sdfserver.bench`` (with the
rendering benchmark beside the renderer, ``sdfserver.render.bench``) reaches, directly or through
others, a module that reaches back to it, and the leaves the rendering benchmark builds on import
nothing of sdfserver. Imports inside functions count, and so do the module names the command
line imports by name."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
LEAVES = ("sdfserver.bench.run", "sdfserver.bench.schedule")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules() -> dict[str, ast.Module]:
    paths = [*sorted((ROOT / "sdfserver" / "bench").rglob("*.py")), ROOT / "sdfserver" / "render" / "bench.py"]
    return {module_name(p): ast.parse(p.read_text(), str(p)) for p in paths}


def imported(tree: ast.Module) -> set[str]:
    """Every module named by an import anywhere in ``tree``, with ``from a import b`` counted as
    ``a.b`` too (it is a module when ``b`` is), and every string that could be a module's name."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.startswith("sdfserver."):
            names.add(node.value)
    return names


def test_the_leaves_import_nothing_of_sdfserver():
    trees = modules()
    for leaf in LEAVES:
        assert not {n for n in imported(trees[leaf]) if n.startswith("sdfserver")}, leaf


def test_no_benchmark_module_reaches_back_to_itself():
    trees = modules()
    edges = {name: {n for n in imported(tree) if n in trees and n != name} for name, tree in trees.items()}
    assert edges["sdfserver.bench.cli"] >= {"sdfserver.render.bench", "sdfserver.bench.sections"}  # the graph is seen
    done: set[str] = set()

    def visit(name: str, path: tuple[str, ...]) -> None:
        assert name not in path, " -> ".join((*path, name))
        if name in done:
            return
        for target in sorted(edges[name]):
            visit(target, (*path, name))
        done.add(name)

    for name in sorted(edges):
        visit(name, ())
