"""Both packages stay readable at a glance: no module above 600 lines, no function above 80 (docs/DESIGN.md)."""

from __future__ import annotations

import ast
from pathlib import Path

import hddpg_zoo
import sb3_hddpg

#: The folder that holds both packages (the library and the harness).
ROOT = Path(sb3_hddpg.__file__).parent.parent
PACKAGES = (Path(sb3_hddpg.__file__).parent, Path(hddpg_zoo.__file__).parent)
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 80


def sources() -> list[Path]:
    return sorted(path for package in PACKAGES for path in package.rglob("*.py"))


def test_no_module_above_the_limit():
    long = {
        str(p.relative_to(ROOT)): n for p in sources() if (n := p.read_text().count("\n")) > MAX_MODULE_LINES
    }
    assert not long, f"modules above {MAX_MODULE_LINES} lines (split them along their concepts): {long}"


def test_no_function_above_the_limit():
    long = {}
    for path in sources():
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                span = node.end_lineno - node.lineno + 1
                if span > MAX_FUNCTION_LINES:
                    long[f"{path.relative_to(ROOT)}:{node.lineno} {node.name}"] = span
    assert not long, f"functions above {MAX_FUNCTION_LINES} lines, signature and docstring included: {long}"
