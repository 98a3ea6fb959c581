"""
Training the workers: each named worker as a plain SB3 model on its own reward (paper Algorithm 1, first
half), and the workers manifest beside them.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
from stable_baselines3.common.callbacks import BaseCallback

from sb3_hddpg.algorithms import REGISTRY, algorithm
from sb3_hddpg.artifacts.manifests import check_resumed_agent, check_resumed_env, model_entry, save_manifest
from sb3_hddpg.artifacts.records import ModelEntry, ModelsManifest, models_manifest, read_models_manifest
from sb3_hddpg.artifacts.run_folder import holds_run_folder
from sb3_hddpg.artifacts.values import check_make_kwargs
from sb3_hddpg.envs import REWARD_TERMS
from sb3_hddpg.envs.contract import env_contract
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID, WORKER_ENV_IDS
from sb3_hddpg.envs.terms_env import TermsEnv, make_term_view
from sb3_hddpg.training.agent import (
    AgentPaths,
    TrainingOutcome,
    agent_run,
    finished_with_budget,
    make_snake_env,
    train_agent,
)
from sb3_hddpg.training.config import Hyperparams, default_config, load_hyperparams
from sb3_hddpg.training.run_options import RunOptions, run_options

#: The algorithm of a worker no ``algos`` entry names: the paper's.
DEFAULT_WORKER_ALGO = "ddpg"
#: The snake arm's workers' algorithms where ``algos`` names none, chosen by the workers study
#: (docs/WORKERS.md): DDPG for both, each with its bundled block's prior towards a hand-written controller
#: (the IK reacher, the field avoider); the avoid worker's prior keeps it clear without the saturated
#: joints that DDPG's avoid worker kept on about 80 % of its outputs without one, and clearer than SAC's.
SNAKE_WORKER_ALGOS = {"goal": "ddpg", "avoid": "ddpg"}


def worker_env_factory(name: str, env_kwargs: dict[str, Any] | None = None) -> Callable[[], gym.Env]:
    """A picklable factory of the registered env whose reward is worker ``name``'s."""
    if name not in WORKER_ENV_IDS:
        raise ValueError(f"Unknown worker {name!r}; choose from {sorted(WORKER_ENV_IDS)}")
    return functools.partial(make_snake_env, WORKER_ENV_IDS[name], dict(env_kwargs or {}))


def worker_hyperparams(
    workers: Sequence[str],
    config: str | Path | None = None,
    env: TermsEnv | None = None,
    algos: Mapping[str, str] | None = None,
) -> dict[str, Hyperparams]:
    """
    Check worker names and read each worker's config block, before anything is trained: a bad block for
    the second worker should not surface after the first one has trained for an hour.

    :param workers: worker names among :data:`WORKER_ENV_IDS` (or ``env``'s terms), each at most once.
    :param config: a ``zoo_configs``-format file (default: each worker's algorithm's bundled one).
    :param algos: worker name -> its algorithm (default: :func:`worker_algorithms`'s).
    :param env: another env with several objectives (default: the snake arm); a worker's block is the one
        keyed ``<adapted env id>/<term>``, else the adapted env's id, else ``default``
        (:meth:`~sb3_hddpg.envs.terms_env.TermsEnv.worker_config_keys`).
    :return: name -> its parsed block; raises ``ValueError`` (``ConfigError`` for the file) naming the problem.
    """
    known = list(env.terms) if env is not None else sorted(WORKER_ENV_IDS)
    if isinstance(workers, str):
        raise ValueError(f"Expected a sequence of worker names, actually the string {workers!r}")
    if not workers:
        raise ValueError(f"Expected at least one worker; choose from {known}")
    unknown = [w for w in workers if w not in known]
    if unknown:
        raise ValueError(f"Unknown worker names {unknown}; choose from {known}")
    duplicates = sorted({w for w in workers if list(workers).count(w) > 1})
    if duplicates:
        raise ValueError(f"Duplicate worker names {duplicates} in {list(workers)}: name each worker once")
    chosen = worker_algorithms(workers, algos, env)
    blocks = {
        name: load_hyperparams(
            env.worker_config_keys(name) if env is not None else WORKER_ENV_IDS[name],
            algorithm(chosen[name]).cls,
            config if config is not None else default_config(chosen[name]),
        )
        for name in workers
    }
    for name, block in blocks.items():
        env_id, view_kwargs = env.term_view(name) if env is not None else (WORKER_ENV_IDS[name], {})
        check_make_kwargs(env_id, {**view_kwargs, **block.env_kwargs}, f"worker {name!r}: env_kwargs")
    return blocks


def parse_worker_algorithms(text: str, workers: Sequence[str], env: TermsEnv | None = None) -> dict[str, str]:
    """
    Parse ``--algo``'s text: ``goal=crossq,avoid=sac`` (a worker not named keeps its default, see
    :func:`worker_algorithms`), or one algorithm name for every worker (``crossq``).

    :param text: the option's value.
    :param workers: the workers being trained.
    :param env: the env with several objectives they are trained on (``None``: the snake arm).
    :return: worker name -> algorithm, checked by :func:`worker_algorithms`.
    """
    parts = [part.strip() for part in text.split(",") if part.strip()]
    if len(parts) == 1 and "=" not in parts[0]:
        return worker_algorithms(workers, dict.fromkeys(workers, parts[0]), env)
    algos: dict[str, str] = {}
    for part in parts:
        name, sep, algo = (piece.strip() for piece in part.partition("="))
        if not sep or not name or not algo:
            raise ValueError(
                f"Expected WORKER=ALGORITHM pairs separated by commas, actually {part!r} in {text!r}"
            )
        if name in algos:
            raise ValueError(f"Expected each worker once, actually {name!r} twice in {text!r}")
        algos[name] = algo
    return worker_algorithms(workers, algos, env)


def worker_algorithms(
    workers: Sequence[str], algos: Mapping[str, str] | None = None, env: TermsEnv | None = None
) -> dict[str, str]:
    """
    Each worker's algorithm: the one ``algos`` names, else on the snake arm :data:`SNAKE_WORKER_ALGOS`'s
    and on another env DDPG (the paper's); checked against the algorithm records (a worker role).

    :param workers: the worker names.
    :param algos: worker name -> algorithm name (any case); a name not among ``workers`` is refused.
    :param env: the env with several objectives the workers are trained on (``None``: the snake arm).
    :return: worker name -> registry name.
    """
    defaults = SNAKE_WORKER_ALGOS if env is None else {}
    algos = dict(algos or {})
    unknown = sorted(set(algos) - set(workers))
    if unknown:
        raise ValueError(f"Expected algorithms for the workers {list(workers)}, actually also for {unknown}")
    chosen = {
        name: algorithm(algos.get(name, defaults.get(name, DEFAULT_WORKER_ALGO))).name for name in workers
    }
    for name, algo in chosen.items():
        if "worker" not in REGISTRY[algo].roles:
            raise ValueError(
                f"Expected a worker algorithm for {name!r}, actually {algo!r}, which cannot be one"
            )
    return chosen


@holds_run_folder(lambda call: call.arguments["out_dir"], "train_workers")
def train_workers(
    out_dir: str | Path,
    workers: Sequence[str] | None = None,
    config: str | Path | None = None,
    *,
    run: RunOptions | None = None,
    on_worker_done: Callable[[str, TrainingOutcome], None] | None = None,
    extra_callbacks: Sequence[BaseCallback] = (),
    env: TermsEnv | None = None,
    algos: Mapping[str, str] | None = None,
    resume_changes: Sequence[str] = (),
    **run_changes: object,
) -> dict[str, Any]:
    """
    Train each named worker as a plain SB3 model (see :func:`worker_algorithms` for its algorithm) on its
    own registered env id (paper Algorithm 1, first half) and write ``out_dir/workers/<name>.zip`` and
    ``out_dir/workers/manifest.json``.

    :param out_dir: the run folder.
    :param workers: worker names among :data:`WORKER_ENV_IDS`, or ``env``'s terms (``None``: all of them).
    :param config: a ``zoo_configs``-format file (default: each worker's algorithm's bundled one).
    :param algos: worker name -> its algorithm (e.g. ``{"goal": "crossq"}``; default: on the snake arm
        :data:`SNAKE_WORKER_ALGOS`, DDPG on another env).
    :param run: the run-control settings (:class:`~sb3_hddpg.training.run_options.RunOptions`): the same for every worker; ``timesteps`` is per worker, and ``resume`` keeps finished workers and continues interrupted ones.
    :param resume_changes: with ``resume``, which of the run's ``algo``, ``seed`` and ``config`` may differ
        on purpose (by default a difference is refused: the worker would continue with other settings and
        be recorded with them while trained mostly with the old); the manifest records the new ones.
    :param run_changes: :class:`~sb3_hddpg.training.run_options.RunOptions` fields as keywords (e.g.
        ``seed=3``), over ``run``'s.
    :param on_worker_done: called after each worker with its outcome.
    :param extra_callbacks: more SB3 callbacks for every worker (e.g. progress reporting).
    :param env: another env with several objectives (:func:`~sb3_hddpg.envs.terms_env.terms_env`; default:
        the snake arm): one worker per named term, each on that term's view; the manifest records the
        shared env (``shared_env``) so that ``train_manager`` acts in it.
    :return: the manifest written.
    """
    run = run_options(run, run_changes, "train_workers")
    shared = env if env is not None else TermsEnv(SNAKE_REACH_ENV_ID, {}, REWARD_TERMS)
    if workers is None:
        workers = list(shared.terms)
    chosen = worker_algorithms(workers, algos, env)
    blocks = worker_hyperparams(workers, config, env, chosen)
    out_dir = Path(out_dir)
    manifest_path = out_dir / "workers" / "manifest.json"
    manifest = _start_manifest(
        manifest_path, shared, env, workers, blocks, run.resume, (chosen, run.seed, resume_changes)
    )
    for name in workers:
        hyperparams = blocks[name]
        env_id, view_kwargs = shared.term_view(name)
        env_kwargs = {**view_kwargs, **hyperparams.env_kwargs}
        budget = int(run.timesteps if run.timesteps is not None else hyperparams.n_timesteps)
        if run.resume and finished_with_budget(manifest.entries.get(name), budget):
            continue  # finished in an earlier run
        paths = AgentPaths(out_dir, name, out_dir / "workers" / f"{name}.zip")
        outcome = train_agent(
            functools.partial(make_term_view, env_id, env_kwargs, name),
            hyperparams,
            paths,
            algo=chosen[name],
            run=agent_run(run, paths, budget),
            extra_callbacks=extra_callbacks,
        )
        source = str(config) if config else f"sb3_hddpg/zoo_configs/{chosen[name]}.yml"
        entry = _worker_entry(
            name, outcome, chosen[name], (env_id, env_kwargs), hyperparams, source, run, budget
        )
        manifest = manifest.with_entry(name, entry)
        save_manifest(manifest_path, manifest)
        if on_worker_done is not None:
            on_worker_done(name, outcome)
    return manifest.to_json()


def _start_manifest(
    manifest_path: Path,
    shared: TermsEnv,
    env: TermsEnv | None,
    workers: Sequence[str],
    blocks: Mapping[str, Hyperparams],
    resume: bool,
    asked: tuple[Mapping[str, str], int, Sequence[str]],
) -> ModelsManifest:
    """
    The manifest the workers are added to: a new one, or on ``resume`` the earlier run's, refused in one line
    when its env, or a worker's algorithm, seed or config block, differs from this run's (a worker is
    continued only with what it was trained with).

    :param asked: each worker's algorithm, the seed this run asks for, and what may differ on purpose.
    """
    manifest = models_manifest("workers")
    if resume and manifest_path.exists():
        manifest = read_models_manifest(manifest_path, "workers")
        algos, seed, accept = asked
        for name in workers:
            entry = manifest.entries.get(name)
            check_resumed_agent(entry, name, algos[name], seed, blocks[name].raw, accept=accept)
        if env is not None or manifest.shared_env is not None:
            check_resumed_env(
                manifest.shared_env or {"env_id": SNAKE_REACH_ENV_ID}, shared.env_id, shared.env_kwargs
            )
        for name in workers:
            env_id, view_kwargs = shared.term_view(name)
            check_resumed_env(manifest.entries.get(name), env_id, {**view_kwargs, **blocks[name].env_kwargs})
    if env is not None:
        manifest = manifest.with_shared_env(env.env_id, env.env_kwargs)
    return manifest


def _worker_entry(
    name: str,
    outcome: TrainingOutcome,
    algo: str,
    made: tuple[str, dict[str, Any]],
    hyperparams: Hyperparams,
    config_file: str,
    run: RunOptions,
    budget: int,
) -> ModelEntry:
    """
    A trained worker's manifest entry, with the bounds of its reward term (the manager normalises by them).

    :param made: the env id and keyword arguments of the worker's view.
    :param config_file: the config file its block was read from, as recorded.
    """
    env_id, env_kwargs = made
    probe = make_term_view(env_id, env_kwargs, name)
    try:
        bounds = env_contract(probe).reward_bounds[name]
    finally:
        probe.close()
    return model_entry(
        name,
        outcome,
        algo,
        env_id,
        env_kwargs,
        {"file": config_file, "block": hyperparams.raw},
        run.seed,
        budget,
        reward_term=name,
        reward_bounds=list(bounds),
        stopped_early=outcome.stopped_early,
        threads=run.threads,
    )
