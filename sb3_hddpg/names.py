"""
The one plain-name rule: every name that becomes part of a path (a term, a worker, a method, a record, a
model file) passes :func:`check_plain_name` where it enters, from the command line or from a file.

A plain name is ASCII letters, digits, ``_`` and ``-``, starting with a letter or digit, at most 64
characters: it cannot climb out of a folder (no ``/``, no ``..``), cannot be hidden, cannot carry a
newline into a message or a file name, and fits every filesystem's name length.
"""

from __future__ import annotations

import re
from typing import Any

#: The longest plain name.
MAX_NAME_CHARS = 64
#: A plain name (``\A``/``\Z``, not ``^``/``$``: ``$`` would accept a trailing newline).
PLAIN_NAME = re.compile(rf"\A[A-Za-z0-9][A-Za-z0-9_-]{{0,{MAX_NAME_CHARS - 1}}}\Z", re.ASCII)


class PlainNameError(ValueError):
    """A name that would become part of a path is not plain; the message names where it came from."""


def check_plain_name(value: Any, what: str) -> str:
    """
    ``value`` if it is a plain name, else :class:`PlainNameError` in one line naming ``what``.

    :param value: the name, from the command line or a file.
    :param what: where it comes from (an option or a field), for the message.
    :return: the name.
    """
    expected = "a name of ASCII letters, digits, '_' and '-' (starting with a letter or digit, at most"
    return _matching(PLAIN_NAME, value, what, f"{expected} {MAX_NAME_CHARS})")


#: A preference as it appears in a benchmark method's key and folder name (``goal=0.4,avoid=1.6``): term
#: names, numbers, ``=`` and ``,``; no path separator, and it cannot start with a dot.
PREFERENCE_TEXT = re.compile(r"\A[A-Za-z0-9][A-Za-z0-9_.=,-]{0,199}\Z", re.ASCII)


def check_preference_text(value: Any, what: str) -> str:
    """
    ``value`` if it is a preference that may be part of a folder name, else :class:`PlainNameError`.

    :param value: the preference text, from a file.
    :param what: where it comes from, for the message.
    :return: the text.
    """
    return _matching(PREFERENCE_TEXT, value, what, "TERM=WEIGHT pairs joined by ',' (at most 200 characters)")


def _matching(pattern: re.Pattern[str], value: Any, what: str, expected: str) -> str:
    if isinstance(value, str) and pattern.match(value):
        return value
    shown = repr(value) if len(repr(value)) <= 80 else repr(value)[:79] + "…"
    raise PlainNameError(f"{what}: expected {expected}, got {shown}")
