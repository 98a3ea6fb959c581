"""The kinds of a record's fields read back from a file, checked against their annotations."""

from __future__ import annotations

import dataclasses
import types
import typing
from typing import Any

from sb3_hddpg.artifacts.limits import LimitError, brief
from sb3_hddpg.artifacts.values import is_finite_number


def check_field_types(record: Any, what: str) -> None:
    """
    The fields of a dataclass instance read back from a file have the kinds their annotations name (``int``,
    ``float``: finite, never a bool, ``str``, ``bool``, ``None``, ``list[...]``, a ``TypedDict`` or ``dict``,
    and unions of them), so that a bad one is refused in one line naming the field.

    :param record: a dataclass instance.
    :param what: where it comes from, for the :class:`LimitError` naming the first field of another kind.
    """
    hints = typing.get_type_hints(type(record))
    for field in dataclasses.fields(record):
        value, hint = getattr(record, field.name), hints[field.name]
        if not _is_kind(value, hint):
            raise LimitError(f"{what}: {field.name}: expected {_kind_text(hint)}, got {brief(value)}")


def _is_kind(value: object, hint: Any) -> bool:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_is_kind(value, arg) for arg in args)
    if origin is list:
        return isinstance(value, list) and all(_is_kind(item, args[0]) for item in value)
    if hint is type(None):
        return value is None
    if hint in (bool, str):
        return isinstance(value, hint)
    if hint in (int, float):
        return is_finite_number(value) and (hint is float or isinstance(value, int))
    if typing.is_typeddict(hint) or hint is dict or origin is dict:
        return isinstance(value, dict)
    raise TypeError(f"check_field_types cannot check the annotation {hint!r}")


def _kind_text(hint: Any) -> str:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_kind_text(arg) for arg in args)
    if origin is list:
        plurals = {int: "integers", float: "finite numbers", str: "strings", bool: "booleans"}
        return f"a list of {plurals.get(args[0], 'objects')}"
    names = {int: "an integer", float: "a finite number", str: "a string", bool: "true or false"}
    return "null" if hint is type(None) else names.get(hint, "an object")
