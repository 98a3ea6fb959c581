"""Option validators of the harness's commands (benchmark, quickstart, tune): runs, jobs, executors."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from typing import Annotated, Any

import typer

from sb3_hddpg.artifacts.limits import LimitError, check_count, count_bounds
from sb3_hddpg.cli.options import BACKEND_HELP, backend_name


def between(minimum: int, maximum: int) -> Callable[[int | None], int | None]:
    """A typer callback that accepts integers in ``[minimum, maximum]`` (``None`` passes)."""

    def check(value: int | None) -> int | None:
        if value is not None and not minimum <= value <= maximum:
            raise typer.BadParameter(f"must be in [{minimum}, {maximum}], got {value}")
        return value

    return check


def check_jobs(n_jobs: int | None, executor: str) -> None:
    """
    ``--n-jobs`` against what runs them: on this machine, at most its usable cores (each job is a process
    with its own torch: 200 of them took 3.4 GB); on a Ray cluster, what the cluster schedules.
    """
    if n_jobs is not None and executor == "local":
        try:
            check_count("n_jobs", n_jobs, "--n-jobs")
        except LimitError:
            low, high = count_bounds("n_jobs")
            raise typer.BadParameter(
                f"must be in [{low}, {high}] (the usable cores of this machine) with --executor local, got {n_jobs}",
                param_hint="'--n-jobs'",
            ) from None


def positive_float(value: float | None) -> float | None:
    """A typer callback that accepts finite floats > 0 (``None`` passes)."""
    if value is not None and (not math.isfinite(value) or value <= 0):
        raise typer.BadParameter(f"must be a finite number > 0, got {value}")
    return value


def build_settings(record: Callable[..., Any], options: Mapping[str, str], **values: Any) -> Any:
    """
    Build a settings record from a command's options, a refusal naming the one option at fault: the one
    whose value, put back to the record's default, makes the error go away (a record's message names its
    field, or nothing a user typed; a list of every option that feeds the record left the user to guess).

    :param record: the settings dataclass (its fields' defaults are used to find the option at fault).
    :param options: field -> the option that sets it, e.g. ``{"ham_threshold": "--ham-threshold"}``.
    :param values: the record's keyword arguments.
    :return: the record; raises ``typer.BadParameter`` naming the option.
    """
    try:
        return record(**values)
    except (ValueError, TypeError) as error:
        message = str(error) or type(error).__name__
        defaults = {
            f.name: f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore[misc,operator]
            for f in dataclasses.fields(record)  # type: ignore[arg-type]
            if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING
        }
        for field, option in options.items():
            if field not in values or field not in defaults or values[field] == defaults[field]:
                continue
            try:
                record(**{**values, field: defaults[field]})
            except (ValueError, TypeError) as other:
                if str(other) == message:
                    continue
            raise typer.BadParameter(message, param_hint=f"'{option}'") from None
        raise typer.BadParameter(
            message, param_hint=" / ".join(f"'{o}'" for o in dict.fromkeys(options.values()))
        ) from None


#: ``--backend`` of the commands that run whole experiments (benchmark, quickstart): sb3 unless asked.
ExperimentBackendOpt = Annotated[
    str,
    typer.Option(
        "--backend", callback=backend_name, help=BACKEND_HELP.split(" Default:")[0] + " Default: sb3."
    ),
]


#: Help of the options that choose where a command's independent runs go (benchmark, quickstart, tune).
EXECUTOR_HELP = (
    "Where the runs go: local (processes on this machine) or ray (one Ray task each on an existing Ray "
    'cluster, see --ray-address; pip install "sb3-hddpg[cluster]"; shared filesystem assumed, docs/CLUSTER.md).'
)


RAY_ADDRESS_HELP = (
    "With --executor ray: the cluster's head, auto (the cluster `ray start` runs on this machine, or "
    "RAY_ADDRESS) or HOST:PORT. Default: auto."
)


EXECUTORS = ("local", "ray")


def executor_name(value: str) -> str:
    """A typer callback for ``--executor``: ``local`` or ``ray``."""
    if value not in EXECUTORS:
        raise typer.BadParameter(f"must be one of {list(EXECUTORS)}, got {value!r}")
    return value


ExecutorOpt = Annotated[str, typer.Option("--executor", callback=executor_name, help=EXECUTOR_HELP)]


RayAddressOpt = Annotated[str | None, typer.Option("--ray-address", help=RAY_ADDRESS_HELP)]


def cluster_address(executor: str, ray_address: str | None) -> str | None:
    """
    The Ray address the executor options name (``None``: run locally). Connects to the cluster now, before
    any work starts, so that a missing Ray or an unreachable address is a usage error naming the option.
    """
    if executor == "local":
        if ray_address is not None:
            raise typer.BadParameter("applies to --executor ray only", param_hint="'--ray-address'")
        return None
    # Lazily: Ray is optional (the `cluster` extra) and only --executor ray needs it.
    from hddpg_zoo.ray_executor import ClusterError, connect

    address = ray_address or "auto"
    try:
        connect(address)
    except ClusterError as error:
        raise typer.BadParameter(str(error), param_hint="'--ray-address'") from None
    return address
