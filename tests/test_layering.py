"""
The floors of both packages (docs/DESIGN.md): each module imports only from its own floor or below, and no
cycles. The library (``sb3_hddpg``) never imports the harness (``hddpg_zoo``), whose floors all lie above the
library's, and the harness imports no private module or name of the library.
"""

from __future__ import annotations

import ast
import importlib.util
import pkgutil
from pathlib import Path

import hddpg_zoo
import sb3_hddpg

ROOT = Path(sb3_hddpg.__file__).parent
#: Each package's folder.
ROOTS = {"sb3_hddpg": ROOT, "hddpg_zoo": Path(hddpg_zoo.__file__).parent}

#: Floor of each top-level part of the package, ground floor first. ``sb3_hddpg`` itself only registers the
#: env ids and re-exports lazily, so everything may import it.
FLOORS = {
    "sb3_hddpg": 0,
    "sb3_hddpg.envs": 0,
    "sb3_hddpg.names": 0,
    "sb3_hddpg.lazy": 0,
    "sb3_hddpg.policy_loaders": 0,
    "sb3_hddpg.extras": 0,
    "sb3_hddpg.policy": 1,
    "sb3_hddpg.algorithms": 1,
    "sb3_hddpg.episode_sets": 1,
    "sb3_hddpg.metric_labels": 1,
    "sb3_hddpg.threads": 1,
    "sb3_hddpg.relabeling": 1,
    "sb3_hddpg.artifacts": 2,
    "sb3_hddpg.episode_metrics": 3,
    "sb3_hddpg.evaluation": 3,
    "sb3_hddpg.callbacks": 3,
    "sb3_hddpg.goal_relabeling": 3,
    "sb3_hddpg.media": 3,
    "sb3_hddpg.baselines": 3,
    "sb3_hddpg.hierarchy": 4,
    "sb3_hddpg.training": 5,
    "sb3_hddpg.cli": 7,
    "sb3_hddpg.__main__": 7,
    # The harness, above the whole library: it may import any public module of it, the library none of its.
    "hddpg_zoo": 8,
    "hddpg_zoo.records": 8,
    "hddpg_zoo.provenance": 8,
    "hddpg_zoo.agent_settings": 8,
    "hddpg_zoo.runner": 8,
    "hddpg_zoo.study_storage": 8,
    "hddpg_zoo.hyperparams_opt": 8,
    "hddpg_zoo.baselines": 9,
    "hddpg_zoo.media": 9,
    "hddpg_zoo.stats": 9,
    "hddpg_zoo.ray_executor": 9,
    "hddpg_zoo.study_export": 9,
    "hddpg_zoo.executors": 10,
    "hddpg_zoo.packaging": 10,
    "hddpg_zoo.tuning": 11,
    "hddpg_zoo.quickstart_jobs": 11,
    "hddpg_zoo.benchmark": 11,
    "hddpg_zoo.model_export": 12,
    "hddpg_zoo.quickstart_figures": 12,
    "hddpg_zoo.snapshot": 13,
    "hddpg_zoo.quickstart": 13,
    "hddpg_zoo.quickstart_media": 14,
    "hddpg_zoo.cli": 15,
}
#: The first floor of the harness.
HARNESS_FLOOR = 8


def modules() -> list[str]:
    names = []
    for package, root in ROOTS.items():
        names.append(package)
        names += [info.name for info in pkgutil.walk_packages([str(root)], prefix=f"{package}.")]
    return sorted(names)


def source_path(module: str) -> Path:
    top, *parts = module.split(".")
    root = ROOTS[top]
    package = root.joinpath(*parts, "__init__.py")
    return package if package.is_file() else root.joinpath(*parts[:-1], parts[-1] + ".py") if parts else root


def source_file(module: str) -> Path:
    """The file of ``module`` (a package's ``__init__.py``)."""
    path = source_path(module)
    return path / "__init__.py" if path.is_dir() else path


def imports_of(module: str, annotations: bool = False) -> set[str]:
    """
    Every module of ours that ``module`` imports, at module level or inside functions; with
    ``annotations``, also those imported under ``if TYPE_CHECKING:`` (for annotations only).
    """
    path = source_file(module)
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
    return {name for name in found if name.split(".")[0] in ROOTS}


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
        if prefix in FLOORS and (length > 1 or module in ROOTS):
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


def test_the_library_never_imports_the_harness():
    # Not even for annotations: `pip install sb3-hddpg` without the bench extra must import every module.
    found = [
        f"{module} imports {imported}"
        for module in modules()
        if module.startswith("sb3_hddpg")
        for imported in imports_of(module, annotations=True)
        if imported.startswith("hddpg_zoo")
    ]
    assert not found, "\n".join(found)
    assert all(FLOORS[name] >= HARNESS_FLOOR for name in FLOORS if name.startswith("hddpg_zoo"))
    assert all(FLOORS[name] < HARNESS_FLOOR for name in FLOORS if name.startswith("sb3_hddpg"))


def private_imports(tree: ast.AST) -> list[str]:
    """The private modules (a ``_x`` part) and names (``_x``) of the library a parsed module imports."""

    def private(name: str) -> bool:
        return any(part.startswith("_") and not part.startswith("__") for part in name.split("."))

    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [a.name for a in node.names if a.name.startswith("sb3_hddpg") and private(a.name)]
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("sb3_hddpg"):
            found += [f"{node.module}.{a.name}" for a in node.names if private(f"{node.module}.{a.name}")]
    return found


def test_the_harness_imports_only_public_names_of_the_library():
    found = [
        f"{module}: {name}"
        for module in modules()
        if module.startswith("hddpg_zoo")
        for name in private_imports(
            ast.parse(
                source_path(module).read_text()
                if not source_path(module).is_dir()
                else (source_path(module) / "__init__.py").read_text()
            )
        )
    ]
    assert not found, "\n".join(found)
    sample = "from sb3_hddpg.artifacts.io import _UMASK, atomic_write_bytes\nimport sb3_hddpg._x\nimport numpy._core\n"
    assert private_imports(ast.parse(sample)) == ["sb3_hddpg.artifacts.io._UMASK", "sb3_hddpg._x"]
