"""One owner per fact: the snake's env ids are spelled in ``envs/ids.py`` only, input limits live in ``artifacts/limits.py``."""

from __future__ import annotations

import ast

from test_layering import ROOT, modules, source_path

from sb3_hddpg.artifacts import limits
from sb3_hddpg.envs import ids


def _tree(module: str) -> ast.Module:
    path = source_path(module)
    return ast.parse((ROOT / "__init__.py" if path == ROOT else path).read_text())


def test_the_snakes_env_ids_are_spelled_and_named_once():
    spelled = {value for name, value in vars(ids).items() if name.endswith("_ENV_ID")}
    found = []
    for module in modules():
        if module == "sb3_hddpg.envs.ids":
            continue
        for node in ast.walk(_tree(module)):
            # An id in code, not in a docstring or message: a constant that is exactly an id.
            if isinstance(node, ast.Constant) and node.value in spelled:
                found.append(f"{module}: {node.value!r}")
            # Nor another name for one of them (a second owner of "the default env").
            if (
                isinstance(node, ast.Assign)
                and isinstance(node.value, ast.Name)
                and node.value.id.endswith("_ENV_ID")
            ):
                found.append(f"{module}: {ast.unparse(node)}")
    assert not found


def test_input_limits_are_declared_in_limits_py():
    library = ("sb3_hddpg.hierarchy", "sb3_hddpg.training", "sb3_hddpg.artifacts", "sb3_hddpg.baselines")
    declared = [
        f"{module}: {target.id}"
        for module in modules()
        if module.startswith(library) and module != "sb3_hddpg.artifacts.limits"
        for node in _tree(module).body
        if isinstance(node, ast.Assign)
        for target in node.targets
        if isinstance(target, ast.Name) and target.id.startswith("MAX_")
    ]
    assert not declared
    # The ground floor enforces its own (an env's terms, a plain name); limits.py names them beside the rest.
    assert (limits.MAX_SWEEP_RATIO, limits.MAX_TERMS, limits.MAX_NAME_CHARS) == (1024, 32, 64)
