"""The package's imports run one way (docs/architecture.md).

Reads every module's imports with ``ast`` (nothing is imported or run) and checks them
against the layer order below. Imports inside functions and under ``TYPE_CHECKING``
count too: a lazy import is still a dependency.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = "tactile_compliance"
PACKAGE_DIR = Path(__file__).resolve().parents[1] / "src" / PACKAGE

#: Lowest first. A part may import parts of lower layers and itself, never a part of its
#: own layer or of a higher one. The package root holds only ``__version__``.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("__init__",),
    ("progress", "outputs", "devices", "suggest"),
    ("physics",),
    ("data",),
    ("synthetic", "models", "acquisition"),
    ("config",),
    ("runs",),
    ("training", "evaluation", "inference"),
    ("demo", "sim2real"),
    ("cli",),
    ("__main__",),  # `python -m tactile_compliance`: runs the cli
)

#: Circles between modules that are harmless (each side imports the other only inside a
#: function or for type checking), each with the reason. There are none today.
ALLOWED_CYCLES: frozenset[frozenset[str]] = frozenset()


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """The package's modules that ``path`` imports (absolute and relative imports)."""
    module = _module_name(path)
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.add(target)
            # ``from pkg import sub`` may import a submodule: count it as one.
            found.update(f"{target}.{alias.name}" for alias in node.names)
    modules = _all_modules()
    return {name for name in found if name in modules and name != module}


_MODULES: dict[str, Path] = {}


def _all_modules() -> dict[str, Path]:
    if not _MODULES:
        for path in sorted(PACKAGE_DIR.rglob("*.py")):
            _MODULES[_module_name(path)] = path
    return _MODULES


def _part(module: str) -> str:
    """The top-level part of the package a module belongs to ("data", "cli", ...)."""
    parts = module.split(".")
    return "__init__" if len(parts) == 1 else parts[1]


def _layer(part: str) -> int:
    for index, layer in enumerate(LAYERS):
        if part in layer:
            return index
    raise AssertionError(f"{part!r} is in no layer: add it to LAYERS and docs/architecture.md")


def _graph() -> dict[str, set[str]]:
    return {name: _imports(path) for name, path in _all_modules().items()}


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """Every import of a part of the same or a higher layer, as readable lines."""
    wrong = []
    for module, targets in sorted(graph.items()):
        for target in sorted(targets):
            a, b = _part(module), _part(target)
            if a != b and _layer(b) >= _layer(a):
                wrong.append(f"{module} imports {target} ({a} may not import {b})")
    return wrong


def module_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for nxt in graph.get(node, ()):
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in on_stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            group = []
            while True:
                top = stack.pop()
                on_stack.discard(top)
                group.append(top)
                if top == node:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return groups


def test_every_part_of_the_package_has_a_layer() -> None:
    for module in _all_modules():
        _layer(_part(module))


def test_imports_only_go_down_the_layers() -> None:
    assert upward_imports(_graph()) == []


def test_no_import_circles_but_the_documented_ones() -> None:
    cycles = [c for c in module_cycles(_graph()) if frozenset(c) not in ALLOWED_CYCLES]
    assert cycles == []


@pytest.mark.parametrize(
    ("module", "target"),
    [
        # The back-imports this layering removed; each must be caught if it comes back.
        (f"{PACKAGE}.data.preprocess", f"{PACKAGE}.config"),
        (f"{PACKAGE}.training.train", f"{PACKAGE}.evaluation.report"),
        (f"{PACKAGE}.evaluation.tables", f"{PACKAGE}.training.train"),
        (f"{PACKAGE}.inference.estimator", f"{PACKAGE}.training.train"),
        (f"{PACKAGE}.data.store", f"{PACKAGE}.synthetic.generate"),
        (f"{PACKAGE}.runs.results", f"{PACKAGE}.training.experiment_file"),
    ],
)
def test_the_layering_check_catches_a_back_import(module: str, target: str) -> None:
    graph = _graph()
    assert upward_imports(graph) == []
    graph[module] = {*graph[module], target}
    assert any(line.startswith(f"{module} imports {target}") for line in upward_imports(graph))


def test_the_cycle_check_finds_a_circle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert module_cycles(graph) == [["a", "b", "c"]]
