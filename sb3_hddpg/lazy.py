"""Names a package exports but imports only on first use (PEP 562's module ``__getattr__``)."""

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_attributes(package: str, modules: Mapping[str, str]) -> Callable[[str], Any]:
    """
    A module ``__getattr__`` for ``package``: each name of ``modules`` imported from its module when asked.

    :param package: the package's name, for the message of an unknown attribute.
    :param modules: exported name -> the module that defines it.
    """

    def attribute(name: str) -> Any:
        if name in modules:
            return getattr(importlib.import_module(modules[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return attribute
