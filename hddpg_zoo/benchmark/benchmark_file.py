"""
The one reader of a benchmark folder's ``benchmark.json``: its header (settings, budgets, invocations) checked
before a resumed benchmark, ``report`` or ``--workers-from`` reads a field of it, and its settings made into
:class:`~.settings.BenchmarkSettings` (every field's kind and bound checked there).

A folder may come from someone else, or have been edited: a field of the wrong kind is one ``ValueError`` line
naming the file, never a ``KeyError`` or ``TypeError`` at the end of a run that already trained everything.
"""

from __future__ import annotations

from dataclasses import fields
from pathlib import Path
from typing import Any, cast

from hddpg_zoo.benchmark.settings import BenchmarkSettings
from hddpg_zoo.provenance import CodeProvenance
from sb3_hddpg.artifacts.limits import brief, read_json_record
from sb3_hddpg.artifacts.values import is_finite_number


def read_benchmark_file(path: str | Path) -> dict[str, Any]:
    """
    ``benchmark.json`` through the JSON size and depth limits, with the shape its readers rely on: an object
    whose ``settings`` is an object (its ``methods`` a list of names), ``budgets`` an object, and
    ``invocations`` a list of objects whose ``wall_time_s`` is a finite number >= 0 (their ``code``:
    :func:`invocation_codes`).

    :raises ValueError: one line naming the file and the field.
    """
    value = read_json_record(path, f"{path}: not a readable benchmark.json")
    settings = value.get("settings") if isinstance(value, dict) else None
    if not isinstance(settings, dict):
        raise ValueError(f"{path}: expected an object with the benchmark's settings, got {brief(value)}")
    methods = settings.get("methods", [])
    if not isinstance(methods, list) or not all(isinstance(m, str) for m in methods):
        raise ValueError(f"{path}: settings.methods: expected a list of names, got {brief(methods)}")
    if not isinstance(value.get("budgets", {}), dict):
        raise ValueError(f"{path}: budgets: expected an object, got {brief(value['budgets'])}")
    invocations = value.get("invocations", [])
    if not isinstance(invocations, list) or not all(_is_invocation(i) for i in invocations):
        raise ValueError(
            f"{path}: invocations: expected a list of objects with wall_time_s a finite number >= 0, got "
            f"{brief(invocations)}"
        )
    return value


def invocation_codes(header: dict[str, Any], what: str) -> list[CodeProvenance | None]:
    """
    The code each earlier invocation of a benchmark ran (its ``code`` field, checked), ``None`` for an
    invocation written before the field existed (not recorded).

    :param header: ``benchmark.json`` as :func:`read_benchmark_file` returns it.
    :param what: the file, for errors.
    :raises ValueError: one line naming the file and the invocation.
    """
    return [
        CodeProvenance.from_json(entry["code"], f"{what}: invocations[{i}].code") if "code" in entry else None
        for i, entry in enumerate(header.get("invocations", []))
    ]


def check_same_code(
    earlier: list[CodeProvenance | None], code: CodeProvenance, allow_mixed: bool, what: str
) -> bool:
    """
    Refuse to resume a benchmark with other code than its earlier invocations ran (another version or commit,
    or earlier invocations whose commit was not recorded), unless ``allow_mixed``: one benchmark's records
    then come from code that no single commit holds.

    :param earlier: :func:`invocation_codes`.
    :param code: the code of this invocation (:func:`~hddpg_zoo.provenance.code_provenance`).
    :param allow_mixed: resume anyway (the invocation's record says so).
    :param what: the benchmark folder, for the error.
    :return: whether the benchmark's invocations now mix code.
    :raises ValueError: one line naming the folder, the codes and ``--allow-mixed-commits``.
    """
    others = sorted(
        {
            "not recorded" if c is None else c.describe()
            for c in earlier
            if c is None or c.code_id != code.code_id
        }
    )
    if others and not allow_mixed:
        raise ValueError(
            f"{what} was run by {', '.join(others)}; this is {code.describe()}: one benchmark's records come "
            "from one commit (check out that commit, or pass --allow-mixed-commits, which the record keeps)"
        )
    return bool(others)


def _is_invocation(entry: object) -> bool:
    seconds = entry.get("wall_time_s", 0.0) if isinstance(entry, dict) else None
    return is_finite_number(seconds) and cast(float, seconds) >= 0


def settings_from_json(value: object, what: str) -> BenchmarkSettings:
    """
    :class:`~.settings.BenchmarkSettings` from their JSON (``benchmark.json``'s ``settings``): an object of the
    class's fields only, each checked by the class itself (kinds, bounds, env id and kwargs).

    :raises ValueError: one line naming ``what``.
    """
    names = {f.name for f in fields(BenchmarkSettings)}
    if not isinstance(value, dict):
        raise ValueError(f"{what}: expected an object of the benchmark's settings, got {brief(value)}")
    unknown = sorted(str(key) for key in value if key not in names)
    if unknown:
        raise ValueError(f"{what}: unknown settings {brief(unknown)}")
    try:
        return BenchmarkSettings(**value)
    except ValueError as error:
        raise ValueError(f"{what}: {error}") from None


def read_benchmark_settings(path: str | Path) -> BenchmarkSettings:
    """The settings of the ``benchmark.json`` at ``path`` (:func:`read_benchmark_file`, :func:`settings_from_json`)."""
    return settings_from_json(read_benchmark_file(path)["settings"], str(path))


__all__ = [
    "check_same_code",
    "invocation_codes",
    "read_benchmark_file",
    "read_benchmark_settings",
    "settings_from_json",
]
