"""``hddpg-cli benchmark --protocol morl-baselines``: its options, and the run it starts (parse, call, print)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from hddpg_zoo.benchmark.morl import check_morl_python
from hddpg_zoo.benchmark.morl_page import write_morl_page
from hddpg_zoo.benchmark.morl_protocol import (
    EVAL_EPISODES,
    PEERS,
    PROTOCOL,
    PROTOCOL_ENVS,
    ProtocolSettings,
)
from hddpg_zoo.benchmark.morl_protocol_run import (
    read_protocol_record,
    read_protocol_run,
    run_protocol,
    shipped_run,
)
from hddpg_zoo.cli.options import check_jobs
from sb3_hddpg.artifacts.containment import is_run_folder
from sb3_hddpg.artifacts.run_folder import mark_run_folder
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import prepare_out_dir, refuse_protected_out, usage_errors

ProtocolOpt = Annotated[
    str | None,
    typer.Option(
        "--protocol",
        help=f"Run a field's benchmark protocol instead of this one's scenarios: {PROTOCOL!r} (MORL-baselines' "
        f"envs {list(PROTOCOL_ENVS)}, budgets, reference points, evaluator and indicators, docs/MORL.md). With "
        "it, --env names one of those envs, --methods the hierarchy's methods, --timesteps every side's env "
        "steps (below the protocol's: a pilot, or with --final-test and >= 10 seeds a run of record at a "
        "reduced budget of at least a tenth of it, which its page states), --n-jobs the tasks (a side on a "
        "seed) in parallel, --test-episodes the episodes per weight, --resume goes on with a run (from its "
        "peers' checkpoints) and may add seeds and sides to it, also to a run's shipped records (protocol.json "
        "and records/ only, e.g. docs/results/morl-dev/<run>); --methods names the "
        "hierarchy's methods and MORL-baselines' learners together (default: hddpg-conditioned and the env's "
        "two strongest learners).",
    ),
]


def _names(text: str | None) -> tuple[str, ...]:
    return tuple(name.strip() for name in (text or "").split(",") if name.strip())


def protocol_command(context: typer.Context) -> None:
    """
    ``benchmark --protocol``: check the protocol's settings from the command's options (``--methods`` names
    the hierarchy's methods and the peers together), run every side on every seed, print each record.
    """
    given = context.params
    if given["protocol"] != PROTOCOL:
        raise typer.BadParameter(
            f"expected {PROTOCOL!r}, got {given['protocol'][:80]!r}", param_hint="'--protocol'"
        )
    if given["executor"] != "local":
        raise typer.BadParameter(
            "the protocol's tasks run on this machine (--n-jobs at most its cores)", param_hint="'--executor'"
        )
    check_jobs(given["n_jobs"], "local")
    names = _names(given["methods"])
    hierarchy = tuple(n for n in names if n not in PEERS) or ("hddpg-conditioned",)
    with usage_errors():
        settings = ProtocolSettings(
            env_id=given["env"] or "",
            seeds=tuple(range(given["seeds"])),
            methods=hierarchy,
            peers=tuple(n for n in names if n in PEERS) if names else None,
            timesteps=given["timesteps"],
            eval_episodes=given["test_episodes"] or EVAL_EPISODES,
            final_test=given["final_test"],
            morl_python=_python(given["morl_python"]),
        )
    out = Path(given["out"])
    if given["resume"]:
        _take_shipped_run(out, settings)
    prepare_out_dir(context, out, given["resume"], force=False)
    with usage_errors("'--out'"):
        paths = run_protocol(settings, out, n_jobs=given["n_jobs"] or 1)
    for path in paths:
        record = read_protocol_record(path)
        shown = ", ".join(f"{k} {v:.4g}" for k, v in record.indicators.items())
        console.print(
            f"{record.method} seed {record.seed}: {shown}; {record.total_env_steps} env steps, "
            f"{record.wall_time_train_s:.0f} s"
        )
    if not settings.of_record:
        console.print(
            "Not a run of record (the protocol's evaluation, >= 10 seeds, --final-test, at least a tenth of "
            "the protocol's budget)."
        )
    elif not settings.full_budget:
        console.print(
            f"A run of record at a reduced budget ({settings.budget} of the protocol's "
            f"{settings.env.env_steps} env steps per side): its page says so."
        )
    console.print(f"Records in {out / 'records'}; the page: hddpg-cli morl-report {out} --page docs/MORL.md")


def _take_shipped_run(out: Path, settings: ProtocolSettings) -> None:
    """
    ``--resume`` on a run's shipped records (``protocol.json`` and ``records/`` only, no run marker, e.g. a
    development run of docs/results/morl-dev on another machine): mark the folder as this tool's run, its
    records as its own, so that the run goes on there. Any other folder is left to the usual rules.
    """
    refuse_protected_out(out)
    if out.is_symlink() or not out.is_dir() or is_run_folder(out):
        return
    with usage_errors("'--out'"):
        if not shipped_run(out, settings):
            return
    mark_run_folder(out, "benchmark", entries=["protocol.json", "records"])
    console.print(f"{out}: a protocol run's shipped records; --resume goes on with them there")


def _python(path: str | None) -> str | None:
    """MORL-baselines' python, checked (an executable file); kept for this run only, never written."""
    if path is None:
        return None
    return check_morl_python(path)


@app.command("morl-report")
def morl_report_command(
    runs: list[Path] = typer.Argument(
        None,
        help="Folders of `benchmark --protocol morl-baselines` runs, one per env (none: the page says so).",
    ),
    page: Path = typer.Option(
        Path("docs/MORL.md"), "--page", help="The page written from the runs' records."
    ),
    check: bool = typer.Option(
        False, "--check", help="Write nothing; exit 1 if the page differs from its regenerated text."
    ),
) -> None:
    """Write docs/MORL.md (its fronts figures beside it, in results/) from protocol runs' records."""
    runs = list(runs or [])
    with usage_errors("'RUNS'"):
        for run in runs:
            read_protocol_run(run)
    changed = write_morl_page(runs, page, check=check)
    if check and changed:
        console.print(f"[red]Out of date[/]: {page} (run without --check to rewrite)")
        raise typer.Exit(1)
    console.print(f"{page}: {'up to date' if check else 'rewritten' if changed else 'unchanged'}")


__all__ = ["ProtocolOpt", "morl_report_command", "protocol_command"]
