"""The layer rule as a test: the package's import graph, built from the source with ``ast``.

The layers, lowest first (``drake_models/__init__.py`` states the rule, docs/design.md explains it):

    infrastructure -> drake_models -> optimization -> systems -> ballchain (the top: experiments,
    commands, cli, report, reproduce, sweep, ...)

A module may import its own layer and the layers below it, never one above (``test_no_upward_import``),
and no two modules may import each other, directly or around a loop (``test_no_import_cycle``:
the strongly connected components of the graph, imports inside functions included, since a
cycle through a function's import is still a cycle: it only fails later, and at run time).

Imports under ``if TYPE_CHECKING:`` never run: they are kept out of the cycle check (annotating
with a type from a module that imports this one is what they are for) but they still obey the
layer rule (a lower layer that names a higher layer's type depends on it all the same).

Imports inside functions are counted per layer (``pytest -s`` prints the table). In the three
library layers each one says why it is not at the module's top, in a comment on its line or on
the line above (``# lazy: pydrake is 0.5 s to import``), or it moves to the top
(``test_function_level_imports_say_why``).
"""

from __future__ import annotations

import ast
import sys
import tomllib
from collections import Counter, defaultdict
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# The layers, lowest first: a module's layer is that of the longest prefix of its name here.
LAYERS = ("infrastructure", "drake_models", "optimization", "systems", "top")
LAYER_OF_PACKAGE = {
    "ballchain.infrastructure": "infrastructure",
    "ballchain.drake_models": "drake_models",
    "ballchain.optimization": "optimization",
    "ballchain.systems": "systems",
    "ballchain": "top",
}
# The layers whose function-level imports must each say why they are not at the top.
LIBRARY_LAYERS = ("infrastructure", "drake_models", "optimization", "systems")

# Cycles being removed elsewhere, each with the issue that removes it (the edges are printed all
# the same). Remove the entry when that lands: the test then holds the rule for them too.
ALLOWED_CYCLES: set = set()  # none: a cycle is fixed at its root, not allowed here
# Function-level imports in the library layers without their reason, in files being edited by
# others at the time of writing (issue 42): module -> how many. The test fails when a module has
# more than this; lower the number (or drop the entry) as they get their reason or move up.
PENDING_REASONS: dict[str, int] = {}  # none left: every one is at the top or says why


@dataclass(frozen=True)
class Import:
    source: str  # the importing module
    target: str  # the imported module (a module of the package)
    line: int
    where: str  # "top" (runs on import), "function" (runs when called) or "type_checking" (never)
    has_reason: bool  # a comment on its line or the line above (or above a run of imports)

    def __str__(self) -> str:
        return f"{self.source} -> {self.target}  ({module_file(self.source)}:{self.line}, {self.where})"


def package_dirs() -> dict[str, Path]:
    """The installed packages and their folders, from pyproject.toml's package-dir (a package it
    does not name lies under its nearest named parent's folder, as setuptools places it: the
    data-only packages)."""
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    dirs = config["package-dir"]

    def folder(package: str) -> Path:
        parts = package.split(".")
        for k in range(len(parts), 0, -1):
            parent = ".".join(parts[:k])
            if parent in dirs:
                return ROOT / dirs[parent] / Path(*parts[k:])
        raise KeyError(f"{package}: no folder in pyproject.toml's package-dir")

    return {package: folder(package) for package in config["packages"]}


def modules() -> dict[str, Path]:
    """Every module of the package: dotted name -> file (a package's name -> its ``__init__``)."""
    found = {}
    for package, folder in package_dirs().items():
        for path in sorted(folder.glob("*.py")):
            found[package if path.stem == "__init__" else f"{package}.{path.stem}"] = path
    return found


MODULES = modules()


def module_file(name: str) -> str:
    return str(MODULES[name].relative_to(ROOT))


def layer(name: str) -> str:
    prefix = max((p for p in LAYER_OF_PACKAGE if name == p or name.startswith(p + ".")), key=len)
    return LAYER_OF_PACKAGE[prefix]


def _resolve(name: str) -> str | None:
    """The package's module that importing ``name`` names: itself, or its longest known prefix."""
    while name:
        if name in MODULES:
            return name
        name = name.rpartition(".")[0]
    return None


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _comment(line: str) -> str:
    """The comment on a source line (a '#' outside strings is good enough for import lines)."""
    return line.partition("#")[2].strip() if "#" in line else ""


def _reason(lines: list[str], node: ast.stmt, import_lines: set[int]) -> bool:
    """A comment giving a reason on the import's line, or on the line above it, or above the run of
    imports it closes (one comment for a block of imports)."""
    def says_why(comment: str) -> bool:
        words = comment.replace("noqa", "").replace("type: ignore", "")
        return len(words.strip(" :,-")) > 3

    first = node.lineno
    if says_why(_comment(lines[first - 1])) or any(
            says_why(_comment(lines[n - 1])) for n in range(first, node.end_lineno + 1)):
        return True
    above = first - 1
    while above >= 1:
        text = lines[above - 1].strip()
        if text.startswith("#"):
            return says_why(text[1:])
        if above not in import_lines:
            return False
        above -= 1
    return False


def imports_of(name: str) -> list[Import]:
    """The imports of one module that name a module of the package."""
    path = MODULES[name]
    source = path.read_text()
    lines = source.splitlines()
    tree = ast.parse(source, str(path))
    package = name if path.stem == "__init__" else name.rpartition(".")[0]
    found: list[Import] = []
    import_nodes: list[tuple[ast.stmt, str]] = []

    def visit(node: ast.AST, where: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                visit(child, "function" if where == "top" else where)
            elif isinstance(child, ast.If) and _is_type_checking(child.test):
                for statement in child.body:
                    visit_statement(statement, "type_checking")
                for statement in child.orelse:
                    visit_statement(statement, where)
            else:
                visit_statement(child, where)

    def visit_statement(node: ast.AST, where: str) -> None:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            import_nodes.append((node, where))
        else:
            visit(node, where)

    visit(tree, "top")
    import_lines = {n for node, _ in import_nodes for n in range(node.lineno, node.end_lineno + 1)}
    for node, where in import_nodes:
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        else:
            base = node.module or ""
            if node.level:
                parts = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(parts + ([base] if base else []))
            # ``from package import module`` names the module; ``from module import name`` the module
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base
                       for alias in node.names]
        reason = _reason(lines, node, import_lines)
        for target in dict.fromkeys(filter(None, map(_resolve, targets))):
            if target != name:
                found.append(Import(name, target, node.lineno, where, reason))
    return found


@pytest.fixture(scope="module")
def graph() -> list[Import]:
    return [edge for name in MODULES for edge in imports_of(name)]


def strongly_connected(nodes, edges: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's strongly connected components (iterative: the graph has ~300 modules)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    components = []
    counter = 0
    for root in nodes:
        if root in index:
            continue
        work = [(root, iter(sorted(edges.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges.get(child, ())))))
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = []
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.append(member)
                        if member == node:
                            break
                    components.append(sorted(component))
    return components


def test_every_module_has_a_layer():
    assert "ballchain.drake_models.params" in MODULES and "ballchain.cli" in MODULES
    assert {layer(name) for name in MODULES} <= set(LAYERS)
    assert layer("ballchain.drake_models.kernels.pair") == "drake_models"
    assert layer("ballchain.experiments.clinical") == "top"


def test_no_upward_import(graph):
    upward = [edge for edge in graph
              if LAYERS.index(layer(edge.target)) > LAYERS.index(layer(edge.source))]
    assert not upward, "a lower layer imports a higher one:\n  " + "\n  ".join(map(str, upward))


def test_no_import_cycle(graph):
    edges: dict[str, set[str]] = defaultdict(set)
    for edge in graph:
        if edge.where != "type_checking":
            edges[edge.source].add(edge.target)
    cycles = [c for c in strongly_connected(sorted(MODULES), edges) if len(c) > 1]
    report = []
    for component in cycles:
        members = set(component)
        inside = [edge for edge in graph if edge.where != "type_checking"
                  and edge.source in members and edge.target in members]
        allowed = frozenset(component) in ALLOWED_CYCLES
        report.append(("allowed " if allowed else "") + "cycle: " + ", ".join(component)
                      + "\n    " + "\n    ".join(map(str, inside)))
    print("\n".join(report))
    assert all(frozenset(c) in ALLOWED_CYCLES for c in cycles), "\n".join(
        r for r in report if not r.startswith("allowed"))
    gone = [sorted(c) for c in ALLOWED_CYCLES if list(sorted(c)) not in cycles]
    assert not gone, f"allowed cycles that are gone (remove them from ALLOWED_CYCLES): {gone}"


def test_function_level_imports_counted(graph):
    """The imports inside functions, per layer (``-s`` prints the table)."""
    inside = Counter(layer(edge.source) for edge in graph if edge.where == "function")
    top = Counter(layer(edge.source) for edge in graph if edge.where == "top")
    print("\nproject imports per layer:   at the top   inside functions")
    for name in LAYERS:
        print(f"  {name:<26}{top[name]:>12}{inside[name]:>19}")
    print(f"  {'all':<26}{sum(top.values()):>12}{sum(inside.values()):>19}")
    assert sum(top.values()) > 0


def test_function_level_imports_say_why(graph):
    missing = [edge for edge in graph if edge.where == "function" and not edge.has_reason
               and layer(edge.source) in LIBRARY_LAYERS]
    per_module = Counter(edge.source for edge in missing)
    over = [edge for edge in missing if per_module[edge.source] > PENDING_REASONS.get(edge.source, 0)]
    assert not over, ("imports inside functions without their reason (a comment on the line or the "
                      "line above, '# lazy: ...'), or move them to the top:\n  " + "\n  ".join(map(str, over)))
    stale = {m: n for m, n in PENDING_REASONS.items() if per_module[m] < n}
    assert not stale, f"PENDING_REASONS is higher than what is left: lower it to {dict(per_module)}"


if __name__ == "__main__":  # python tests/test_layers.py: the graph's numbers without pytest
    sys.exit(pytest.main([__file__, "-s", "-q", "-n", "0", "-p", "no:cacheprovider"]))


MAX_LINES = 600  # a module's length: one home for one thing
LONG_MODULES: dict[str, int] = {}  # modules allowed over MAX_LINES, each with its reason (none left)


def test_no_module_of_the_package_is_longer_than_600_lines():
    root = Path(__file__).resolve().parents[1]
    long = {}
    for folder in ("ballchain", "drake_models", "optimization", "systems", "infrastructure"):
        for path in (root / folder).rglob("*.py"):
            n = len(path.read_text().splitlines())
            name = path.relative_to(root).as_posix()
            if n > MAX_LINES and n > LONG_MODULES.get(name, 0):
                long[name] = n
    assert not long, f"modules over {MAX_LINES} lines: {long}"
