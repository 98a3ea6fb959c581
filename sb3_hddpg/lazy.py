"""Names a package exports but imports only on first use (PEP 562's module ``__getattr__``)."""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_attributes(package: str, modules: Mapping[str, str]) -> Callable[[str], Any]:
    """
    A module ``__getattr__`` for ``package`` that imports each name of ``modules`` from its module when it is
    first asked for, so that importing the package loads none of them.

    :param package: the package's name, for the error of an unknown attribute.
    :param modules: exported name -> the module that defines it.
    """

    def attribute(name: str) -> Any:
        if name in modules:
            return getattr(importlib.import_module(modules[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return attribute
