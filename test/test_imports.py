"""The package's import graph, read from its source with `ast` (issue 49, item 3).

Every import of one of the package's own modules is an edge, those inside functions
included: an import deferred into a function still ties the two modules together, it
only hides the tie from the reader. Imports under `if TYPE_CHECKING:` are left out:
they name types for annotations and never run. The graph may hold 2-module cycles (a package's
__init__ and a module it re-exports) but no longer one, and no import inside a
function may close a cycle.

Run as a script to print the figures: `python test/test_imports.py [ROOT]`, ROOT
being a directory holding a `train_localization/` tree (default: this repository).
"""
from __future__ import annotations

import ast
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

PACKAGE = "train_localization"


@dataclass(frozen=True)
class Import:
    """One import of a package module: importer, imported module, source line, deferred."""

    source: str
    target: str
    line: int
    in_function: bool


def module_names(root: Path) -> dict[str, Path]:
    """Dotted module name -> file, for every .py file of the package under root."""
    names = {}
    for path in sorted((root / PACKAGE).rglob("*.py")):
        parts = list(path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        names[".".join(parts)] = path
    return names


def _resolve(module: str, node: ast.ImportFrom, is_package: bool) -> str:
    """The absolute name of a `from ... import` statement's module."""
    if not node.level:
        return node.module or ""
    base = module.split(".")
    if not is_package:
        base.pop()
    if node.level > 1:
        base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _targets(name: str, imported: list[str], modules: dict[str, Path]) -> list[str]:
    """The package modules one import statement loads: `from a import b` loads a.b if
    that is a module, else a's __init__."""
    if name not in modules and not any(f"{name}.{i}" in modules for i in imported):
        return []
    out = []
    for item in imported:
        sub = f"{name}.{item}"
        target = sub if sub in modules else name
        if target in modules and target not in out:
            out.append(target)
    return out


def _is_type_checking(node: ast.If) -> bool:
    """True for `if TYPE_CHECKING:` (or `typing.TYPE_CHECKING`)."""
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def _inside(tree: ast.AST, kinds: tuple, accept=lambda node: True) -> set[int]:
    """The ids of the import statements nested in a node of one of kinds (that accept takes)."""
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, kinds) and accept(node):
            found.update(id(inner) for inner in ast.walk(node)
                         if isinstance(inner, (ast.Import, ast.ImportFrom)))
    return found


def imports(root: Path) -> list[Import]:
    """Every import of a package module in the package under root, in file order."""
    modules = module_names(root)
    found = []
    for module, path in modules.items():
        tree = ast.parse(path.read_text(), filename=str(path))
        is_package = path.name == "__init__.py"
        deferred = _inside(tree, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
        typing_only = _inside(tree, (ast.If,), _is_type_checking)
        for node in ast.walk(tree):
            if id(node) in typing_only:
                continue
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names if a.name in modules]
            elif isinstance(node, ast.ImportFrom):
                name = _resolve(module, node, is_package)
                targets = _targets(name, [a.name for a in node.names], modules)
            else:
                continue
            for target in targets:
                if target != module:
                    found.append(Import(module, target, node.lineno, id(node) in deferred))
    return found


def components(edges: list[Import]) -> list[set[str]]:
    """The strongly connected components of the graph (Tarjan, iterative), largest first."""
    graph: dict[str, set[str]] = {}
    for e in edges:
        graph.setdefault(e.source, set()).add(e.target)
        graph.setdefault(e.target, set())
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[set[str]] = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph[start])))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is None:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    component = set()
                    while True:
                        member = stack.pop()
                        on_stack.discard(member)
                        component.add(member)
                        if member == node:
                            break
                    found.append(component)
            elif child not in index:
                index[child] = low[child] = len(index)
                stack.append(child)
                on_stack.add(child)
                work.append((child, iter(sorted(graph[child]))))
            elif child in on_stack:
                low[node] = min(low[node], index[child])
    return sorted(found, key=len, reverse=True)


def cycle_closers(edges: list[Import]) -> list[Import]:
    """Imports inside functions whose two modules lie on one cycle."""
    where = {m: i for i, c in enumerate(components(edges)) for m in c}
    return [e for e in edges if e.in_function and where[e.source] == where[e.target]]


ROOT = Path(__file__).resolve().parent.parent
# 2-module cycles closed by an import inside a function, each with its reason; a new one fails
# the test. track.py checks a track's ``etcs`` block through etcs/track_data.py, which raises
# track.py's TrackError.
KNOWN_CLOSERS = {("train_localization.core.track", "train_localization.core.etcs.track_data")}


@pytest.fixture(scope="module")
def package_imports() -> list[Import]:
    return imports(ROOT)


def test_the_graph_holds_top_level_deferred_and_relative_imports_and_no_typing_only_ones(package_imports):
    edges = {(e.source, e.target): e for e in package_imports}
    core = f"{PACKAGE}.core"
    assert not edges[(f"{core}.scenario", f"{core}.control")].in_function
    assert edges[(f"{core}.fusion.config", f"{core}.scenario")].in_function
    assert (f"{core}.offline", f"{core}.offline.simulate") in edges     # `from .simulate import`
    assert (f"{core}.fusion.component", f"{core}.fusion.filter") not in edges   # under TYPE_CHECKING


def test_components_finds_a_three_module_cycle_and_leaves_a_chain_apart():
    chain = [Import(a, b, 1, False) for a, b in [("a", "b"), ("b", "c"), ("c", "a"), ("c", "d")]]
    assert components(chain) == [{"a", "b", "c"}, {"d"}]
    assert cycle_closers(chain + [Import("d", "a", 9, True)]) == [Import("d", "a", 9, True)]


def test_no_import_cycle_of_more_than_two_modules(package_imports):
    large = [sorted(c) for c in components(package_imports) if len(c) > 2]
    assert large == []


def test_no_import_inside_a_function_closes_a_cycle_but_the_known_ones(package_imports):
    closing = {(e.source, e.target) for e in cycle_closers(package_imports)}
    assert closing <= KNOWN_CLOSERS, sorted(closing - KNOWN_CLOSERS)


def main(argv: list[str]) -> None:
    """Print the figures of the import graph of the tree under argv[0] (default ROOT)."""
    root = Path(argv[0]) if argv else ROOT
    edges = imports(root)
    deferred = [e for e in edges if e.in_function]
    closing = cycle_closers(edges)
    cycles = [c for c in components(edges) if len(c) > 1]
    print(f"modules {len(module_names(root))}, imports of package modules {len(edges)}")
    print(f"inside functions {len(deferred)}, closing a cycle {len(closing)}")
    print(f"cycles (strongly connected components) by size: {[len(c) for c in cycles]}")
    for c in cycles:
        if len(c) > 2:
            print("  " + " ".join(sorted(m.removeprefix(PACKAGE + ".") for m in c)))
    for e in closing:
        print(f"  closes: {e.source}:{e.line} -> {e.target}")


if __name__ == "__main__":
    main(sys.argv[1:])
