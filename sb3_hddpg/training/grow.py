"""
``grow``: a support of workers that grows where the front gains most (optimistic linear support,
:mod:`~sb3_hddpg.training.linear_support`), each new worker on a corner weighting of the terms, warm-started
from its nearest neighbour, within one total env-step budget.

It starts from a per-term worker with its per-term critic for every term. A policy's vector value is its
critic at the start states of the development episodes, ``mean_s0 Q(s0, pi(s0))``: no env step.
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from sb3_hddpg.artifacts.io import atomic_write_json, holds_folder_lock
from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.artifacts.provenance import verify_sha256
from sb3_hddpg.artifacts.records.support import SupportRecord, SupportStep, read_support_record
from sb3_hddpg.artifacts.term_critic import TermCritic
from sb3_hddpg.artifacts.transitions import Transitions
from sb3_hddpg.artifacts.workers import Workers
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.envs.terms_env import TermsEnv
from sb3_hddpg.envs.weighted import weighted_name
from sb3_hddpg.episode_sets import DEVELOPMENT
from sb3_hddpg.hierarchy.frozen import FrozenWorker
from sb3_hddpg.training.linear_support import Corner, ranked_corners
from sb3_hddpg.training.run_options import RunOptions, run_options
from sb3_hddpg.training.term_critic import TermCriticOptions
from sb3_hddpg.training.warm_start import WarmStart
from sb3_hddpg.training.workers import plan_workers, train_workers

#: The support's record, beside the workers manifest.
SUPPORT_FILE = "support.json"


@dataclass(frozen=True)
class SupportOptions:
    """
    How far a support grows.

    :param size: the most workers it holds (the per-term workers included).
    :param budget: the env steps its new workers may train, together.
    :param tolerance: it stops when the largest optimistic gain is below this fraction of the front's value
        at that corner weight.
    :param start_states: development episodes whose start states value each policy.
    """

    size: int
    budget: int
    tolerance: float = 0.01
    start_states: int = 32

    def __post_init__(self) -> None:
        if isinstance(self.size, bool) or not isinstance(self.size, int) or not 2 <= self.size <= 32:
            raise ValueError(f"Expected `support` (the most workers) in [2, 32], actually: {self.size}")
        if isinstance(self.budget, bool) or not isinstance(self.budget, int) or self.budget < 1:
            raise ValueError(
                f"Expected `budget` (env steps) to be a whole number >= 1, actually: {self.budget}"
            )
        if not (isinstance(self.tolerance, (int, float)) and 0 <= self.tolerance < 1):
            raise ValueError(f"Expected `tolerance` in [0, 1), actually: {self.tolerance}")
        if not 1 <= self.start_states <= DEVELOPMENT.size:
            raise ValueError(
                f"Expected `start_states` in [1, {DEVELOPMENT.size}], actually: {self.start_states}"
            )


def support_weights(workers: Workers, terms: Sequence[str]) -> dict[str, np.ndarray]:
    """Each worker's weighting as a vector over ``terms``: its recorded weights, or its term's corner."""
    out = {}
    for name in workers:
        entry = workers.manifest.entries[name]
        weights = entry.get("reward_weights") or {entry.get("reward_term", name): 1.0}
        vector = np.array([float(weights.get(term, 0.0)) for term in terms])
        out[name] = vector / vector.sum()
    return out


def policy_values(workers: Workers, start_states: int) -> dict[str, np.ndarray]:
    """Each worker's vector value: its critic of its own action at ``start_states`` development starts."""
    with contextlib.closing(workers.make_env()) as env:
        layout = state_layout_of(env)
        starts = np.stack([env.reset(seed=seed)[0] for seed in DEVELOPMENT.seeds(start_states)])
    values = {}
    for name, model in workers.items():
        critic: TermCritic = workers.critics[name]
        indices = layout.indices(workers.states[name]) if name in workers.states else None
        frozen = FrozenWorker(model, indices)
        seen = starts if indices is None else starts[..., indices]
        actions = np.asarray(frozen.act(starts))
        if critic.spec.state_value:  # over the full state, of the worker's own policy
            picked = critic.values(starts)
        elif critic.spec.discrete:
            per_action = critic.values(seen)
            picked = per_action[np.arange(len(seen)), actions.reshape(-1).astype(int)]
        else:
            picked = critic.values(seen, actions)
        values[name] = picked.mean(axis=0)
    return values


def check_growable(out_dir: str | Path, resume: bool = False) -> tuple[Workers, list[str]]:
    """
    Check, before anything trains, that a folder's workers can start a support: every worker has a per-term
    critic, there is a per-term worker for every term, and a support record is only continued with ``resume``.

    :return: the loaded workers and the critics' terms.
    """
    root = Path(out_dir)
    workers = load_workers(root)
    missing = [name for name in workers if name not in workers.critics]
    if missing:
        raise ValueError(
            f"grow needs every worker's per-term critic; {missing} have none (retrain them with train-workers)"
        )
    terms = list(next(iter(workers.critics.values())).spec.terms)
    visited = support_weights(workers, terms)
    corners_missing = [
        t for i, t in enumerate(terms) if not any(np.isclose(w[i], 1.0) for w in visited.values())
    ]
    if corners_missing:
        raise ValueError(f"grow starts from a per-term worker for every term; none for {corners_missing}")
    if (root / "workers" / SUPPORT_FILE).exists() and not resume:
        raise FileExistsError(
            f"{root / 'workers' / SUPPORT_FILE} exists: continue it with --resume, or grow in another folder"
        )
    return workers, terms


@holds_folder_lock(lambda call: call.arguments["out_dir"])
def grow(
    out_dir: str | Path,
    options: SupportOptions,
    *,
    run: RunOptions | None = None,
    config: str | Path | None = None,
    env: TermsEnv | None = None,
    term_critic: TermCriticOptions | None = None,
    **run_changes: object,
) -> SupportRecord:
    """
    Grow the support of a workers folder one worker at a time at the corner weight of largest optimistic
    gain, until it holds ``options.size`` workers, the gain falls below ``options.tolerance`` or the budget is
    spent; record it in ``workers/support.json`` after every worker.

    :param out_dir: the run folder of ``train-workers`` (per-term workers with critics for every term).
    :param options: size, budget, tolerance, start states.
    :param run: the run-control settings; ``timesteps`` is ignored (each new worker's budget is its share of
        what is left), ``resume`` continues a support and its interrupted worker.
    :param config: a ``zoo_configs``-format file for the new workers (block ``<env>/mix``, else the env's).
    :param env: the env with several objectives (``None``: the shared env the workers manifest records).
    :param term_critic: how each new worker's critic is trained (default settings).
    :return: the support record written.
    """
    run = run_options(run, run_changes, "grow")
    root = Path(out_dir)
    workers, terms = check_growable(root, run.resume)
    # Not the snake arm: the shared env the workers manifest records.
    if env is None and workers.env_id not in (None, SNAKE_REACH_ENV_ID):
        env = TermsEnv(str(workers.env_id), dict(workers.env_kwargs), tuple(terms))
    record = _start_record(root, workers, terms, options, run.resume)
    visited = support_weights(workers, terms)
    values = policy_values(workers, options.start_states)
    while True:
        stop, corner = _next_corner(record, options, workers, values, visited)
        if corner is None:
            break
        step = _add_worker(
            root,
            corner,
            terms,
            workers,
            visited,
            (config, env, term_critic),
            run,
            share=((options.budget - record.steps_used) // (options.size - len(workers))),
        )
        workers = load_workers(root)
        visited[step.name] = np.asarray(corner.weights)
        values.update(policy_values(_only(workers, step.name), options.start_states))
        record = _save(root, record.with_step(step), values)
    return _save(root, replace(record, stopped=stop), values)


def _add_worker(
    root: Path,
    corner: Corner,
    terms: Sequence[str],
    workers: Workers,
    visited: Mapping[str, np.ndarray],
    settings: tuple[str | Path | None, TermsEnv | None, TermCriticOptions | None],
    run: RunOptions,
    share: int,
) -> SupportStep:
    """Train the worker of ``corner``'s weighting (warm-started where a neighbour fits) and describe it."""
    config, env, term_critic = settings
    weights = dict(zip(terms, corner.weights))
    name = weighted_name(weights)
    with contextlib.closing(plan_workers([], [weights], config, env)[0].env_factory()()) as probe:
        spaces = (probe.observation_space, probe.action_space)
    warm = _warm_start(root, workers, visited, np.asarray(corner.weights), weights, spaces)
    manifest = train_workers(
        root,
        workers=[],
        weights=[weights],
        config=config,
        env=env,
        run=run.replace(timesteps=share),
        term_critic=term_critic or TermCriticOptions(),
        keep_transitions=True,
        warm_starts={name: warm} if warm is not None else {},
    ).manifest
    entry = manifest["workers"][name]
    start = entry.get("warm_start") or {}
    return SupportStep(
        name,
        weights,
        corner.gain,
        corner.value,
        int(entry["timesteps_trained"]),
        warm.neighbour if warm is not None else None,
        int(start.get("replay", 0)),
    )


def _next_corner(
    record: SupportRecord,
    options: SupportOptions,
    workers: Workers,
    values: Mapping[str, np.ndarray],
    visited: Mapping[str, np.ndarray],
) -> tuple[str, Corner | None]:
    """The corner the next worker goes to, or why the support stops growing."""
    if len(workers) >= options.size:
        return f"reached {options.size} workers", None
    if (
        record.steps_used >= options.budget
        or (options.budget - record.steps_used) // (options.size - len(workers)) < 1
    ):
        return f"spent the budget of {options.budget} env steps", None
    names = list(workers)
    corners = ranked_corners(np.stack([values[n] for n in names]), [visited[n] for n in names])
    fresh = [c for c in corners if weighted_name(dict(zip(record.terms, c.weights))) not in workers]
    if not fresh:
        return "every corner weight has a worker", None
    best = fresh[0]
    if best.gain <= options.tolerance * max(abs(best.value), 1e-12):
        return f"the largest optimistic gain {best.gain:.4g} is below the tolerance", None
    return "", best


def _warm_start(
    root: Path,
    workers: Workers,
    visited: Mapping[str, np.ndarray],
    corner: np.ndarray,
    weights: dict[str, float],
    spaces: tuple[object, object],
) -> WarmStart | None:
    """
    The new worker's start: the nearest worker that acts in the same ``spaces`` (its parameters and, when
    kept, its transitions), else ``None``.
    """
    fitting = [n for n in visited if (workers[n].observation_space, workers[n].action_space) == spaces]
    if not fitting:
        return None
    neighbour = min(fitting, key=lambda name: float(np.abs(visited[name] - corner).sum()))
    kept = workers.manifest.entries[neighbour].get("transitions")
    kept = kept if isinstance(kept, dict) else {}
    file, transitions = kept.get("file"), None
    if isinstance(file, str) and Path(file).name == file:  # a bare file name: nothing outside the folder
        path = root / "workers" / file
        if path.is_file():
            verify_sha256(path, str(kept.get("sha256")), str(path))
            transitions = Transitions.load(path)
    return WarmStart(neighbour, workers[neighbour], weights, transitions)


def _only(workers: Workers, name: str) -> Workers:
    """``workers`` reduced to one (to value only the new worker)."""
    states = {k: v for k, v in workers.states.items() if k == name}
    return replace(
        workers, models={name: workers[name]}, states=states, critics={name: workers.critics[name]}
    )


def _start_record(
    root: Path, workers: Workers, terms: list[str], options: SupportOptions, resume: bool
) -> SupportRecord:
    """A new record, or on ``resume`` the folder's; an existing record is never replaced without ``resume``."""
    path = root / "workers" / SUPPORT_FILE
    if path.exists() and resume:
        record = read_support_record(path)
        if list(record.terms) != terms:
            raise ValueError(
                f"--resume: the support's terms were {list(record.terms)}, the workers' are {terms}"
            )
        return SupportRecord(
            terms, options.budget, options.size, options.tolerance, record.start, record.added
        )
    return SupportRecord(terms, options.budget, options.size, options.tolerance, list(workers))


def _save(root: Path, record: SupportRecord, values: Mapping[str, np.ndarray]) -> SupportRecord:
    record = replace(
        record, worker_values={name: [float(v) for v in value] for name, value in values.items()}
    )
    atomic_write_json(root / "workers" / SUPPORT_FILE, record.to_json())
    return record
