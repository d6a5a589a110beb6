"""The core's import structure: no package or module imports one that imports it back (also
through others, also for types only), and the core never imports the built-in plug-ins."""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "wholehand"


def _modules() -> dict[str, Path]:
    out = {}
    for path in ROOT.rglob("*.py"):
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def _imports(path: Path, modules: dict[str, Path]) -> set[str]:
    """Every wholehand module ``path`` imports, at any depth of the file (functions and
    ``TYPE_CHECKING`` blocks included); ``from wholehand.x import y`` counts ``wholehand.x.y``
    when that is a module."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name.startswith("wholehand")}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            if node.module.split(".")[0] not in ("wholehand", "wholehand_plugins"):
                continue
            for alias in node.names:
                sub = f"{node.module}.{alias.name}"
                found.add(sub if sub in modules else node.module)
    return found


def _graph(package_level: bool) -> dict[str, set[str]]:
    """Import edges between the core's modules, or between its packages (``wholehand.x``); the
    package ``wholehand`` itself, whose names are loaded lazily on first use, is left out."""
    modules = _modules()

    def node(name: str) -> str:
        return ".".join(name.split(".")[:2]) if package_level else name

    graph: dict[str, set[str]] = defaultdict(set)
    for name, path in modules.items():
        if name == "wholehand":
            continue
        for target in _imports(path, modules):
            if target in modules and target != "wholehand" and node(target) != node(name):
                graph[node(name)].add(node(target))
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one node (Kosaraju)."""
    nodes = sorted(set(graph) | {t for ts in graph.values() for t in ts})
    order: list[str] = []
    seen: set[str] = set()
    for start in nodes:
        if start in seen:
            continue
        seen.add(start)
        stack = [(start, iter(sorted(graph.get(start, ()))))]
        while stack:
            v, children = stack[-1]
            child = next((c for c in children if c not in seen), None)
            if child is None:
                order.append(v)
                stack.pop()
            else:
                seen.add(child)
                stack.append((child, iter(sorted(graph.get(child, ())))))
    reverse: dict[str, set[str]] = defaultdict(set)
    for v, targets in graph.items():
        for t in targets:
            reverse[t].add(v)
    assigned: set[str] = set()
    components = []
    for v in reversed(order):
        if v in assigned:
            continue
        component, todo = [], [v]
        assigned.add(v)
        while todo:
            u = todo.pop()
            component.append(u)
            for w in reverse.get(u, ()):
                if w not in assigned:
                    assigned.add(w)
                    todo.append(w)
        if len(component) > 1:
            components.append(sorted(component))
    return components


def test_the_cycle_finder_finds_a_cycle_through_three_nodes_and_nothing_in_a_chain():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": {"c"}}) == []


@pytest.mark.parametrize("package_level", [True, False], ids=["packages", "modules"])
def test_no_import_cycles_in_the_core(package_level):
    assert _cycles(_graph(package_level)) == []


def test_the_core_never_imports_the_built_in_plug_ins():
    modules = _modules()
    offenders = {
        name: sorted(t for t in _imports(path, modules) if t.startswith("wholehand_plugins"))
        for name, path in modules.items()
    }
    assert {name: found for name, found in offenders.items() if found} == {}
