"""Sphinx configuration of the sb3-hddpg documentation (``make docs``)."""

from __future__ import annotations

import importlib
import inspect
import re
import sys
from pathlib import Path
from typing import Any

from docutils import nodes
from sphinx import addnodes
from sphinx.application import Sphinx
from sphinx.transforms.post_transforms import SphinxPostTransform

ROOT = Path(__file__).resolve().parents[1]
# The checkout's package first, so that the reference documents this tree's docstrings.
sys.path.insert(0, str(ROOT))

import sb3_hddpg  # noqa: E402

project = "sb3-hddpg"
author = "the sb3-hddpg authors"
copyright = "the sb3-hddpg authors"
version = release = sb3_hddpg.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
    "sphinx_copybutton",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
# docs/results/ holds the benchmark's records: its Markdown tables are pages (results-data.md), its data files
# downloads; _build is the output.
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

# Every Markdown heading up to level 3 gets an anchor, so that `[text](PAGE.md#a-heading)` is checked.
myst_heading_anchors = 3
myst_enable_extensions = ["colon_fence", "deflist"]
# A link to a missing page or anchor is a warning, and `-W` makes it an error.
nitpicky = False

autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "signature"
# SB3-style ``:param x:`` docstrings are reStructuredText field lists already; napoleon only adds Google style.
napoleon_google_docstring = True
napoleon_numpy_docstring = False

html_theme = "furo"
html_title = "sb3-hddpg"
html_static_path: list[str] = []
copybutton_prompt_text = r"\$ "
copybutton_prompt_is_regexp = True


class FolderLinks(SphinxPostTransform):
    """
    A Markdown link to a folder of ``docs/`` (a benchmark's models, say) shows as its path: the site holds
    pages and files, not folder listings, and a folder is not a cross-reference target worth a warning.
    """

    # Before myst's resolver (priority 9), which would report the folder as a missing target.
    default_priority = 8

    def run(self, **kwargs: Any) -> None:
        for node in list(self.document.findall(addnodes.pending_xref)):
            if node.get("reftype") != "myst" or not node.get("reftarget", "").endswith("/"):
                continue
            folder = Path(self.env.doc2path(node["refdoc"])).parent / node["reftarget"]
            if folder.is_dir():
                node.replace_self(nodes.literal(node["reftarget"], node["reftarget"]))


#: A page named by its path in the checkout, as docstrings and the README name pages (``docs/MANAGER.md``).
DOCS_PATH = re.compile(r"\bdocs/((?:[A-Za-z0-9_-]+/)*[A-Za-z0-9_.-]+)\.md\b")


class DocsPathLinks(SphinxPostTransform):
    """
    ``docs/MANAGER.md`` in running text or as inline code, in a page or a docstring, links to that page: the
    checkout's path is how the docstrings, the CLI and the README name a page, and on the site it is a link.
    """

    default_priority = 20

    def _uri(self, path: str) -> str | None:
        match = DOCS_PATH.fullmatch(path)
        if match is None or match[1] not in self.env.found_docs:
            return None
        return self.app.builder.get_relative_uri(self.env.docname, match[1])

    def run(self, **kwargs: Any) -> None:
        skip = (nodes.reference, nodes.literal_block, nodes.title, nodes.raw, addnodes.desc_signature)
        for node in list(self.document.findall(nodes.Text)):
            parent = node.parent
            if parent is None or "docs/" not in node or any(isinstance(a, skip) for a in _ancestors(parent)):
                continue
            if isinstance(parent, nodes.literal):
                uri = self._uri(str(node).strip())
                if uri is not None:
                    parent.replace_self(nodes.reference("", "", parent.deepcopy(), refuri=uri, internal=True))
                continue
            pieces: list[nodes.Node] = []
            text, last = str(node), 0
            for match in DOCS_PATH.finditer(text):
                uri = self._uri(match[0])
                if uri is None:
                    continue
                pieces += [
                    nodes.Text(text[last : match.start()]),
                    nodes.reference(match[0], match[0], refuri=uri),
                ]
                last = match.end()
            if pieces:
                parent.replace(node, [*pieces, nodes.Text(text[last:])])


def _ancestors(node: nodes.Node) -> list[nodes.Node]:
    found = []
    while node is not None:
        found.append(node)
        node = node.parent
    return found


def title_records(app: Sphinx, docname: str, source: list[str]) -> None:
    """
    A benchmark's generated table (``results/<run>/results.md``) starts with the table, not a heading: its
    page takes the run's folder as title, so that the site lists it and links to it by name.
    """
    if docname.startswith("results/") and not source[0].lstrip().startswith("# "):
        run = docname.removeprefix("results/").rpartition("/")[0] or "results"
        source[0] = f"# Benchmark record: {run}\n\n{source[0]}"


MARKDOWN_DOCSTRING = re.compile(r"^<!-- docstring: ([\w.]+) -->$", flags=re.M)


def markdown_docstrings(app: Sphinx, docname: str, source: list[str]) -> None:
    """
    ``<!-- docstring: module.Name -->`` on a Markdown page becomes that object's docstring, read as Markdown
    with its headings one level down: the environments follow gymnasium's convention, whose docstrings are
    Markdown specifications (tables of observations and actions), which reStructuredText cannot read.
    """

    def docstring(match: re.Match[str]) -> str:
        module, _, name = match[1].rpartition(".")
        text = inspect.getdoc(getattr(importlib.import_module(module), name)) or ""
        return re.sub(r"^(#+) ", r"\1# ", text, flags=re.M)

    source[0] = MARKDOWN_DOCSTRING.sub(docstring, source[0])


def setup(app: Sphinx) -> dict[str, Any]:
    app.add_post_transform(FolderLinks)
    app.add_post_transform(DocsPathLinks)
    app.connect("source-read", title_records)
    app.connect("source-read", markdown_docstrings)
    return {"parallel_read_safe": True}
