"""The house's imports flow one way: ``core`` <- ``plugins`` <- ``sessions`` <- the facade, and no two modules
import each other (directly or through others).

Read from the source (every ``import`` statement, at module level or inside a function: a late import is still a
dependency), so a new file cannot break the rule unnoticed.
"""

from __future__ import annotations

import ast
from pathlib import Path

from helpers import ROOT

LAYERS = ("core", "plugins", "sessions", "facade")
"""Lowest first: a module may import its own layer and the ones before it."""


def package_modules() -> dict[str, Path]:
    """Every module of the package: dotted name -> file."""
    modules = {"hapticlab": ROOT / "__init__.py"}
    for top in LAYERS[:3]:
        for path in (ROOT / top).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            parts = parts[:-1] if parts[-1] == "__init__" else parts
            modules[".".join(("hapticlab", *parts))] = path
    return modules


def layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else "facade"


def imports_of(path: Path, modules: dict[str, Path]) -> set[str]:
    """The package modules a file imports (``from a.b import c`` counts ``a.b.c`` when that is a module)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f"{node.module}.{alias.name}" for alias in node.names] + [node.module]
        else:
            continue
        for name in names:
            while name and name not in modules:
                name = name.rpartition(".")[0]
            if name.startswith("hapticlab"):
                found.add(name)
    return found


def graph() -> dict[str, set[str]]:
    modules = package_modules()
    return {name: imports_of(path, modules) - {name} for name, path in modules.items()}


def test_no_relative_imports_in_the_package():
    relative = [
        f"{path.relative_to(ROOT)}:{node.lineno}"
        for path in package_modules().values()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8")))
        if isinstance(node, ast.ImportFrom) and node.level > 0
    ]
    assert not relative, f"relative imports (the house imports hapticlab.* absolutely): {relative}"


def test_no_lower_layer_imports_a_higher_one():
    wrong = sorted(
        f"{module} ({layer(module)}) imports {target} ({layer(target)})"
        for module, targets in graph().items()
        for target in targets
        if LAYERS.index(layer(target)) > LAYERS.index(layer(module))
        and not (module.count(".") == 1 and target == "hapticlab")  # a package's __init__ importing the facade
    )
    assert not wrong, "\n".join(wrong)


def test_no_two_modules_import_each_other():
    edges = graph()
    # a package's __init__ importing its own modules, which import the package's siblings, is not a circle
    edges = {m: {t for t in ts if not m.startswith(t + ".")} for m, ts in edges.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []

    def visit(node: str) -> None:  # Tarjan's strongly connected components
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in edges.get(node, ()):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                component.append(top)
                if top == node:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for node in sorted(edges):
        if node not in index:
            visit(node)
    assert not circles, "modules that import each other: " + "; ".join(" <-> ".join(c) for c in circles)


def test_the_check_sees_the_layers():
    edges = graph()
    assert "hapticlab.core.frames" in edges["hapticlab.plugins.estimators.kalman.estimator"]
    assert layer("hapticlab.sessions.live.loop") == "sessions" and layer("hapticlab") == "facade"
