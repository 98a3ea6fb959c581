"""``hddpg-cli evaluate PATH``: the env's metrics for any policy, on fixed evaluation seeds."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.table import Table

from sb3_hddpg.artifacts.io import atomic_write_json
from sb3_hddpg.cli.app import app, console
from sb3_hddpg.cli.options import (
    ENV_HELP,
    ENV_OPTIONS,
    ReplaceFileOpt,
    RunPreferenceOpt,
    apply_run_preference,
    count,
    output_file,
    seed_range,
    takes_options,
    terms_env_of,
    usage_errors,
    writable_file,
)
from sb3_hddpg.envs.terms_env import TermsEnv, adapted_env_id
from sb3_hddpg.evaluation import (
    DEPENDENCE_WORKER,
    EVAL_SEED_BASE,
    clearance_bands,
    dependence_rows,
    evaluate,
    state_dependence,
)
from sb3_hddpg.hierarchy.loading import LoadedPolicy, load_policy
from sb3_hddpg.metric_labels import manager_warnings, summary_rows

# The options of `evaluate_command`.
_PathOpt = Annotated[
    str,
    typer.Argument(
        help="A worker or flat zip, a hierarchy.zip, a ham.json, or 'random' / 'scripted' (Jacobian-transpose) / 'ik' (damped-least-squares IK) / 'field' (potential-field avoider)."
    ),
]
_EnvIdOpt = Annotated[
    str | None, typer.Option("--env", help=ENV_HELP + " Default: the env it was trained on.")
]
_EpisodesOpt = Annotated[
    int, typer.Option("--episodes", callback=count("episodes"), help="Evaluation episodes.")
]
_SeedOpt = Annotated[
    int,
    typer.Option("--seed", callback=seed_range, help="Seed of the first episode (episode k uses seed + k)."),
]
_DeterministicOpt = Annotated[
    bool, typer.Option("--deterministic/--stochastic", help="Deterministic actions.")
]
_JsonPathOpt = Annotated[
    Path | None,
    typer.Option(
        "--json",
        callback=writable_file,
        help="Also write the metrics (and every episode) as JSON (an existing file only with --force).",
    ),
]
_TrustOpt = Annotated[
    bool,
    typer.Option(
        "--trust",
        help="Allow SB3's full loader, which runs code stored in the file: only for files you trust.",
    ),
]
_AlgoOpt = Annotated[
    str | None, typer.Option("--algo", help="Algorithm of a zip without manifest (with --trust).")
]
_WorkerOpt = Annotated[
    str | None,
    typer.Option(
        "--state-worker",
        help="For a hierarchy: the worker whose share near obstacles vs with none in range is reported "
        "(default: avoid, where the hierarchy has it).",
    ),
]
_NearClearanceOpt = Annotated[
    float | None,
    typer.Option(
        "--near-clearance",
        help="A choice is 'near an obstacle' at a clearance <= this (default: half the env's sensor range).",
    ),
]


@app.command("evaluate")
@takes_options(*ENV_OPTIONS)
def evaluate_command(
    context: typer.Context,
    path: _PathOpt,
    env_id: _EnvIdOpt = None,
    episodes: _EpisodesOpt = 20,
    seed: _SeedOpt = EVAL_SEED_BASE,
    deterministic: _DeterministicOpt = True,
    json_path: _JsonPathOpt = None,
    trust: _TrustOpt = False,
    algo: _AlgoOpt = None,
    worker: _WorkerOpt = None,
    preference: RunPreferenceOpt = None,
    near_clearance: _NearClearanceOpt = None,
    force: ReplaceFileOpt = False,
) -> None:
    """
    Evaluate a policy on fixed seeds: the env's own reward, each reward term and the return of the
    normalised terms; goal touches, contacts, success and clearance only where the env reports them (the
    snake arm); a hierarchy's worker choices.
    """
    # What depends only on the arguments is checked first, as a usage error; a failing episode is not one.
    output_file(json_path, force, "'--json'")
    shared = terms_env_of(context, env_id)
    loaded = load_cli_policy(path, shared, trust, algo, preference)
    # --state-worker: one of the workers the policy selects among (a hierarchy's or HAM's names).
    policy_names = getattr(loaded.policy, "names", None) or getattr(loaded.policy, "worker_names", None) or []
    names = [str(name) for name in policy_names]
    if worker is not None and worker not in names:
        shown = f"its workers are {names}" if names else "it selects no worker"
        message = f"{worker!r} is not a worker of this policy: {shown}"
        raise typer.BadParameter(message, param_hint="'--state-worker'")
    worker = worker or DEPENDENCE_WORKER
    with usage_errors("'--env'"):
        env = loaded.make_env(shared.env_id, **shared.env_kwargs) if shared else loaded.make_env()
    with usage_errors("'--near-clearance'"):
        clearance_bands(env, near_clearance, None)
    result = evaluate(
        loaded.policy,
        env,
        n_episodes=episodes,
        seed=seed,
        deterministic=deterministic,
        near_clearance=near_clearance,
    )
    summary = result.summary()
    dependence = state_dependence(summary, worker)
    # The env by the id people know (an adapter's inner env), the policy by its kind and, if it has one, name.
    source = shared or loaded
    env_name = adapted_env_id(source.env_id, source.env_kwargs)
    policy_name = loaded.kind if loaded.name in ("", loaded.kind) else f"{loaded.kind} {loaded.name!r}"
    title = (
        f"{policy_name} on {env_name}: mean over {episodes} episodes, "
        f"seeds {seed}..{seed + episodes - 1} (± standard deviation across episodes)"
    )
    preferences = getattr(loaded.policy, "preferences", None)  # the one a hierarchy acted at
    if isinstance(preferences, dict) and preferences:
        shown = ",".join(f"{name}={factor:g}" for name, factor in preferences.items())
        origin = "given with --preference" if preference is not None else "the bundle's own"
        console.print(f"Preference: {shown} ({origin}; only the ratio matters)")
    console.print(_summary_table(title, summary, dependence, worker))
    console.print(_reward_note(summary))
    for warning in manager_warnings(summary):
        console.print(f"[yellow]Note:[/] {warning}")
    # Say so rather than print nothing: without the proximity capability choices cannot be split by state.
    if "selection_rate" in summary and summary.get("near_clearance") is None:
        console.print(
            f"State dependence of the worker choices: not available for {env_name} (it declares "
            "no proximity: no obstacle clearance to split the choices by; see docs/ENVIRONMENTS.md)"
        )
    if json_path is not None:
        ids = {"path": str(path), "kind": loaded.kind, "env_id": env_id or loaded.env_id}
        atomic_write_json(json_path, {**ids, **result.to_dict(), "state_dependence": dependence})
        console.print(f"Metrics written to {json_path}")


def _reward_note(summary: Mapping[str, Any]) -> str:
    """How the reward rows relate: the env's own reward, each term's raw sum, and the normalised return."""
    terms = [key[5:-7] for key in summary if key.startswith("mean_") and key.endswith("_reward")]
    terms = [t for t in terms if t not in ("", "reach")]
    note = "reward: the env's own, summed over the episode"
    if terms:
        note += (
            f"; {', '.join(terms)} reward: each term's raw sum (in its own units, so they need not add up to the "
            "reward)"
        )
    note += (
        "; return (normalised terms): each term min-max normalised to [0, 1] by the env's bounds, summed over "
        "terms and steps (the benchmark's score; on hddpg/SnakeReach-v0 it is the reward itself)"
    )
    return note


def _summary_table(
    title: str, summary: Mapping[str, Any], dependence: dict[str, Any] | None, worker: str
) -> Table:
    """The evaluation summary as a table of quantity, value and unit, with ``worker``'s state ``dependence``."""
    table = Table(title=title)
    table.add_column("quantity")
    table.add_column("value", justify="right")
    table.add_column("unit")
    # The counts behind the state-dependence rows below are not rows of their own.
    counts = ("selections_near", "selections_clear", "near_clearance", "clear_clearance")
    for label, value, unit in summary_rows({k: v for k, v in summary.items() if k not in counts}):
        table.add_row(label, value, unit)
    for row in dependence_rows(dependence, worker) if dependence is not None else []:
        table.add_row(*row)
    return table


def load_cli_policy(
    path: str, shared: TermsEnv | None, trust: bool, algo: str | None, preference: str | None
) -> LoadedPolicy:
    """
    The policy named on the command line, checked (hashes, spaces, env id) as a usage error naming PATH, at
    ``--preference``: what ``evaluate``, ``record`` and ``plot-selection`` act with.

    :param path: the policy (``PATH``).
    :param shared: the env the ``--env`` options name, which naming allows (``None``: the trained-on one).
    :param trust: ``--trust``: allow SB3's full loader.
    :param algo: ``--algo``: the algorithm of a zip without manifest.
    :param preference: ``--preference``: the run-time preference (``None``: the policy's own).
    """
    with usage_errors("'PATH'"):
        # Naming an env with --env opts in to it, as allowed_env_ids does in the library.
        loaded = load_policy(
            path,
            env_id=shared.env_id if shared else None,
            env_kwargs=shared.env_kwargs if shared else None,
            trusted=trust,
            algo=algo,
            allowed_env_ids=[shared.env_id, shared.config_key] if shared else None,
        )
    apply_run_preference(loaded.policy, preference, loaded.kind)
    return loaded
