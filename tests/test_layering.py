"""The package's floors (docs/DESIGN.md): each module imports only from its own floor or below, and no cycles."""

from __future__ import annotations

import ast
import importlib.util
import pkgutil
from pathlib import Path

import sb3_hddpg

ROOT = Path(sb3_hddpg.__file__).parent

#: Floor of each top-level part of the package, ground floor first. ``sb3_hddpg`` itself only registers the
#: env ids and re-exports lazily, so everything may import it.
FLOORS = {
    "sb3_hddpg": 0,
    "sb3_hddpg.envs": 0,
    "sb3_hddpg.names": 0,
    "sb3_hddpg.policy_loaders": 0,
    "sb3_hddpg.policy": 1,
    "sb3_hddpg.algorithms": 1,
    "sb3_hddpg.episode_sets": 1,
    "sb3_hddpg.metric_labels": 1,
    "sb3_hddpg.threads": 1,
    "sb3_hddpg.artifacts": 2,
    "sb3_hddpg.episode_metrics": 3,
    "sb3_hddpg.evaluation": 3,
    "sb3_hddpg.callbacks": 3,
    "sb3_hddpg.goal_relabeling": 3,
    "sb3_hddpg.media": 3,
    "sb3_hddpg.baselines": 3,
    "sb3_hddpg.hierarchy": 4,
    "sb3_hddpg.training": 5,
    "sb3_hddpg.experiments": 6,
    "sb3_hddpg.cli": 7,
    "sb3_hddpg.__main__": 7,
}


def modules() -> list[str]:
    names = ["sb3_hddpg"]
    for info in pkgutil.walk_packages([str(ROOT)], prefix="sb3_hddpg."):
        names.append(info.name)
    return sorted(names)


def source_path(module: str) -> Path:
    parts = module.split(".")[1:]
    package = ROOT.joinpath(*parts, "__init__.py")
    return package if package.is_file() else ROOT.joinpath(*parts[:-1], parts[-1] + ".py") if parts else ROOT


def imports_of(module: str, annotations: bool = False) -> set[str]:
    """
    Every module of ours that ``module`` imports, at module level or inside functions; with
    ``annotations``, also those imported under ``if TYPE_CHECKING:`` (for annotations only).
    """
    path = source_path(module)
    if path == ROOT:
        path = ROOT / "__init__.py"
    tree = ast.parse(path.read_text(), str(path))
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    return imports_in(tree, package, annotations)


def imports_in(tree: ast.AST, package: str, annotations: bool = False) -> set[str]:
    """The modules of ours a parsed module in ``package`` imports (see :func:`imports_of`)."""
    found: set[str] = set()
    for node in ast.walk(tree) if annotations else runtime_nodes(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            for alias in node.names:
                candidate = f"{base}.{alias.name}"
                found.add(candidate if is_module(candidate) else base)
    return {name for name in found if name == "sb3_hddpg" or name.startswith("sb3_hddpg.")}


def runtime_nodes(tree: ast.AST) -> list[ast.AST]:
    """Every node except those under ``if TYPE_CHECKING:`` (imports for annotations only never run)."""
    nodes: list[ast.AST] = []
    pending = [tree]
    while pending:
        node = pending.pop()
        nodes.append(node)
        for child in ast.iter_child_nodes(node):
            test = child.test if isinstance(child, ast.If) else None
            if test is not None and "TYPE_CHECKING" in ast.unparse(test):
                pending.extend(child.orelse)
                continue
            pending.append(child)
    return nodes


def is_module(name: str) -> bool:
    """Whether ``name`` is an importable module (``from a.b import c``: is ``c`` a module or a name in ``b``?)."""
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):
        return False


def floor(module: str) -> int:
    parts = module.split(".")
    for length in range(len(parts), 0, -1):
        prefix = ".".join(parts[:length])
        if prefix in FLOORS and (length > 1 or module == "sb3_hddpg"):
            return FLOORS[prefix]
    raise AssertionError(f"{module} has no floor in FLOORS: add it (and to docs/DESIGN.md)")


def test_every_module_has_a_floor():
    for module in modules():
        floor(module)


def test_each_module_imports_only_from_its_floor_or_below():
    upward = []
    for module in modules():
        for imported in imports_of(module):
            if floor(imported) > floor(module):
                upward.append(
                    f"{module} (floor {floor(module)}) imports {imported} (floor {floor(imported)})"
                )
    assert not upward, "\n".join(upward)


def import_graph(annotations: bool = False) -> dict[str, set[str]]:
    """Module -> the modules of ours it imports, without the packages it sits in."""
    graph = {module: imports_of(module, annotations) - {module} for module in modules()}
    # A package's __init__ that re-exports its own modules is not a cycle with them.
    for module, targets in graph.items():
        graph[module] = {t for t in targets if not module.startswith(t + ".")}
    return graph


def package_graph(graph: dict[str, set[str]], depth: int) -> dict[str, set[str]]:
    """
    The import graph between the packages and modules ``depth`` names deep (``sb3_hddpg.envs`` at depth 2):
    an import between two of their modules is an edge between them, unless one contains the other.
    """

    def group(module: str) -> str:
        return ".".join(module.split(".")[:depth])

    packages: dict[str, set[str]] = {}
    for module, targets in graph.items():
        source = group(module)
        for target in map(group, targets):
            if (
                source != target
                and not (source + ".").startswith(target + ".")
                and not (target + ".").startswith(source + ".")
            ):
                packages.setdefault(source, set()).add(target)
    return packages


def cycles_of(graph: dict[str, set[str]]) -> list[list[str]]:
    """The cycles a depth-first search meets (at least one per strongly connected part, if any)."""
    state: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for target in sorted(graph.get(node, ())):
            if state.get(target) == 1:
                cycles.append([*stack[stack.index(target) :], target])
            elif target not in state:
                visit(target)
        stack.pop()
        state[node] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module)
    return cycles


def test_no_import_cycles():
    cycles = cycles_of(import_graph())
    assert not cycles, "\n".join(" -> ".join(cycle) for cycle in cycles)


def test_no_import_cycles_through_annotations_at_any_level():
    # An import under ``if TYPE_CHECKING:`` never runs, but it still ties two modules into one: neither can
    # be understood, tested or moved without the other.
    graph = import_graph(annotations=True)
    deepest = max(len(module.split(".")) for module in graph)
    found = []
    for depth in range(2, deepest + 1):
        found += [" -> ".join(cycle) for cycle in cycles_of(package_graph(graph, depth))]
    assert not found, "\n".join(found)


def test_the_cycle_check_sees_annotation_imports_and_packages():
    source = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from sb3_hddpg.envs import layout\n"
    tree = ast.parse(source)
    assert imports_in(tree, "sb3_hddpg.media") == set()
    assert imports_in(tree, "sb3_hddpg.media", annotations=True) == {"sb3_hddpg.envs.layout"}
    # Two packages whose modules import each other form a cycle, though no module does.
    graph = {"p.x.m": {"p.y.n"}, "p.y.n": {"p.x.k"}, "p.x.k": set()}
    assert cycles_of(graph) == []
    assert cycles_of(package_graph(graph, 2)) == [["p.x", "p.y", "p.x"]]
