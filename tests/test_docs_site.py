"""The docs site as a newcomer reads it: public names, docstrings Napoleon reads right, pages linked by path."""

from __future__ import annotations

import importlib
import inspect
import re
import runpy
from pathlib import Path

import pytest

import sb3_hddpg
import sb3_hddpg.training

DOCS = Path(__file__).resolve().parents[1] / "docs"
API_PAGES = sorted((DOCS / "api").glob("*.md"))
AUTODOC = re.compile(r"^\.\. auto(class|function|module):: (\S+)", flags=re.M)


def _documented() -> list[tuple[str, str]]:
    return [(m[1], m[2]) for page in API_PAGES for m in AUTODOC.finditer(page.read_text())]


def _resolve(path: str) -> object:
    module, _, name = path.rpartition(".")
    return getattr(importlib.import_module(module), name)


def test_the_api_shows_each_public_name_under_its_public_path():
    # The package's own names first: a name both export is public as sb3_hddpg.NAME.
    public = {
        id(getattr(sb3_hddpg.training, n)): f"sb3_hddpg.training.{n}" for n in sb3_hddpg.training.__all__
    }
    public.update({id(getattr(sb3_hddpg, n)): f"sb3_hddpg.{n}" for n in sb3_hddpg.__all__ if not n.isupper()})
    documented = [path for kind, path in _documented() if kind != "module"]
    wrong = [
        (path, public[id(obj)])
        for path in documented
        if id(obj := _resolve(path)) in public and path != public[id(obj)]
    ]
    assert not wrong, f"documented under a private module path: {wrong}"
    assert {"sb3_hddpg.Hierarchy", "sb3_hddpg.WorkerSelectionWrapper", "sb3_hddpg.train_manager"} <= set(
        documented
    )


def _attribute_docs(cls: type) -> list[tuple[str, list[str], str]]:
    """Every property docstring and ``#:`` comment of ``cls``'s source, as autodoc hands them to Napoleon."""
    found = [
        (name, inspect.cleandoc(member.__doc__).splitlines(), "property")
        for name, member in vars(cls).items()
        if isinstance(member, property) and member.__doc__
    ]
    try:
        lines = inspect.getsource(cls).splitlines()
    except (OSError, TypeError):
        return found
    index = 0
    while index < len(lines):
        if re.match(r"^ +#: ", lines[index]):
            block = []
            while index < len(lines) and re.match(r"^ +#:", lines[index]):
                block.append(lines[index].strip()[2:].strip())
                index += 1
            found.append((lines[index].strip()[:40] if index < len(lines) else "?", block, "attribute"))
        index += 1
    return found


def _module_data_docs(module: object) -> list[list[str]]:
    """The ``#:`` comments of a module's data, as autodoc hands them to Napoleon."""
    lines, blocks, index = inspect.getsource(module).splitlines(), [], 0
    while index < len(lines):
        block = []
        while index < len(lines) and lines[index].startswith("#:"):
            block.append(lines[index][2:].strip())
            index += 1
        blocks += [block] if block else []
        index += 0 if block else 1
    return blocks


def _swaps(lines: list[str], what: str) -> bool:
    """Whether Napoleon reads the first line as ``type: description``."""
    from sphinx.ext.napoleon import Config
    from sphinx.ext.napoleon.docstring import GoogleDocstring

    parsed = GoogleDocstring(lines, Config(), what=what, name="x").lines()
    return any(line.startswith(":type:") for line in parsed)


def test_no_member_docstring_reads_to_napoleon_as_a_type_and_a_description():
    pytest.importorskip("sphinx.ext.napoleon")
    documented = _documented()
    classes = [obj for kind, path in documented if kind == "class" and inspect.isclass(obj := _resolve(path))]
    modules = [importlib.import_module(path) for kind, path in documented if kind == "module"]
    classes += [c for m in modules for n in getattr(m, "__all__", []) if inspect.isclass(c := getattr(m, n))]
    swapped = [
        f"{m.__name__}: {lines[0][:60]}"
        for m in modules
        for lines in _module_data_docs(m)
        if _swaps(lines, "data")
    ]
    for cls in classes:
        swapped += [
            f"{cls.__name__}.{name}: {lines[0][:60]}"
            for name, lines, what in _attribute_docs(cls)
            if _swaps(lines, what)
        ]
    assert not swapped, (
        f"'X: Y' on a member's first line reads as type X (write 'X, Y' or 'X (Y)'): {swapped}"
    )
    # What the check finds: the first line Napoleon once showed as a type.
    assert _swaps(["The preferences (``None``: one preference)."], "attribute")


def test_the_landing_page_shows_the_install_line_and_a_code_example():
    text = (DOCS / "index.md").read_text()
    assert "pip install -e ." in text and "```python" in text
    assert "WorkerSelectionWrapper(" in text and "Hierarchy.load(" in text


def test_pages_named_by_their_path_become_links():
    conf = runpy.run_path(str(DOCS / "conf.py"))
    assert conf["DocsPathLinks"] in _post_transforms(conf)
    pattern = conf["DOCS_PATH"]
    assert pattern.search("see docs/MANAGER.md for the options")[1] == "MANAGER"
    assert pattern.search("`docs/getting-started/quickstart.md`")[1] == "getting-started/quickstart"
    assert pattern.search("docs/results/") is None


def _post_transforms(conf: dict[str, object]) -> list[object]:
    """The post-transforms ``conf.py``'s ``setup`` adds."""
    added: list[object] = []

    class App:
        def add_post_transform(self, transform: object) -> None:
            added.append(transform)

        def connect(self, *args: object) -> None:
            pass

    conf["setup"](App())  # type: ignore[operator]
    return added
