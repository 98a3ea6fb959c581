"""
Training the workers: each named worker as a plain SB3 model on its own reward (paper Algorithm 1, first
half), and the workers manifest beside them.
"""

from __future__ import annotations

import contextlib
import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.type_aliases import MaybeCallback

from sb3_hddpg.algorithms import REGISTRY, algorithm
from sb3_hddpg.artifacts.io import atomic_write
from sb3_hddpg.artifacts.manifests import check_resumed_agent, check_resumed_env, model_entry, save_manifest
from sb3_hddpg.artifacts.provenance import sha256_file
from sb3_hddpg.artifacts.records import ModelEntry, ModelsManifest, models_manifest, read_models_manifest
from sb3_hddpg.artifacts.run_folder import holds_run_folder
from sb3_hddpg.artifacts.term_critic import TERM_CRITIC_MEMBER, with_term_critic
from sb3_hddpg.artifacts.transitions import TRANSITIONS_SUFFIX
from sb3_hddpg.artifacts.values import check_make_kwargs
from sb3_hddpg.callbacks.checkpoint import checkpoint_record
from sb3_hddpg.callbacks.term_record import TermRecorder
from sb3_hddpg.envs import REWARD_TERMS
from sb3_hddpg.envs.contract import env_contract
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID, WORKER_ENV_IDS
from sb3_hddpg.envs.terms_env import TermsEnv, make_term_view
from sb3_hddpg.envs.weighted import (
    WEIGHTED_PREFIX,
    check_term_weights,
    corner_term,
    make_weighted_view,
    weighted_name,
)
from sb3_hddpg.training.agent import (
    AgentPaths,
    TrainingOutcome,
    agent_run,
    callback_list,
    finished_with_budget,
    train_agent,
)
from sb3_hddpg.training.config import Hyperparams, config_source, default_config, load_hyperparams
from sb3_hddpg.training.run_options import RunOptions, run_options
from sb3_hddpg.training.term_critic import TermCriticOptions, fit_term_critic, recorded_transitions
from sb3_hddpg.training.warm_start import WarmStart

#: The algorithm of a worker no ``algos`` entry names: the paper's.
DEFAULT_WORKER_ALGO = "ddpg"
#: The snake arm's workers' algorithms where ``algos`` names none, chosen by the workers study
#: (docs/WORKERS.md): DDPG for both, each with its bundled block's prior towards a hand-written controller.
SNAKE_WORKER_ALGOS = {"goal": "ddpg", "avoid": "ddpg"}


def worker_hyperparams(
    workers: Sequence[str],
    config: str | Path | None = None,
    env: TermsEnv | None = None,
    algos: Mapping[str, str] | None = None,
) -> dict[str, Hyperparams]:
    """
    Check worker names and read each worker's config block, before anything is trained.

    :param workers: worker names among :data:`WORKER_ENV_IDS` (or ``env``'s terms), each at most once.
    :param config: a ``zoo_configs``-format file (default: each worker's algorithm's bundled one).
    :param env: another env with several objectives (default: the snake arm); a worker's block is the one
        :meth:`~sb3_hddpg.envs.terms_env.TermsEnv.worker_config_keys` names.
    :param algos: worker name -> its algorithm (default: :func:`worker_algorithms`'s).
    :return: name -> its parsed block; raises ``ValueError`` naming the problem.
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
    Parse ``--algo``'s text: ``goal=crossq,avoid=sac`` (a worker not named keeps its default), or one
    algorithm name for every worker (``crossq``); checked by :func:`worker_algorithms`.

    :param text: the option's value.
    :param workers: the workers being trained.
    :param env: the env they are trained on (``None``: the snake arm).
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
    Each worker's algorithm (its registry name): the one ``algos`` names, else on the snake arm
    (``env=None``) :data:`SNAKE_WORKER_ALGOS`'s and on another env DDPG; refused if it cannot be a worker.

    :param workers: the worker names.
    :param algos: worker name -> algorithm name (any case); a name not among ``workers`` is refused.
    :param env: the env with several objectives the workers are trained on (``None``: the snake arm).
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


@dataclass(frozen=True)
class PlannedWorker:
    """
    One worker :func:`train_workers` is about to train.

    :param name: the worker's name (its term, or :func:`~sb3_hddpg.envs.weighted.weighted_name`'s).
    :param weights: term -> weight over their sum; a per-term worker's is its corner.
    :param algo: its algorithm's registry name.
    :param hyperparams: its config block.
    :param env_id: the env id of its view.
    :param env_kwargs: that view's keyword arguments.
    """

    name: str
    weights: dict[str, float]
    algo: str
    hyperparams: Hyperparams
    env_id: str
    env_kwargs: dict[str, Any]

    @property
    def term(self) -> str | None:
        """The term of a per-term worker (trained on that raw term), else ``None``."""
        return corner_term(self.weights) if corner_term(self.weights) == self.name else None

    def env_factory(self) -> Callable[[], gym.Env]:
        """A picklable factory of its view: the raw term's env, or the weighted normalised sum's."""
        if self.term is not None:
            return functools.partial(make_term_view, self.env_id, self.env_kwargs, self.term)
        return functools.partial(make_weighted_view, self.env_id, self.env_kwargs, self.weights)


def plan_workers(
    workers: Sequence[str] | None = None,
    weights: Sequence[Mapping[str, object]] = (),
    config: str | Path | None = None,
    env: TermsEnv | None = None,
    algos: Mapping[str, str] | None = None,
) -> list[PlannedWorker]:
    """
    Check what :func:`train_workers` is asked to train, before anything is trained (a corner weight is the
    per-term worker of its term).

    :param workers: per-term worker names (``None``: every term, unless ``weights`` are given).
    :param weights: weightings of the terms (term -> weight, finite, >= 0, positive sum), one worker each.
    :param config: a ``zoo_configs``-format file (default: each worker's algorithm's bundled one).
    :param env: another env with several objectives (default: the snake arm).
    :param algos: worker name -> algorithm; a weighted worker not named takes its heaviest term's.
    :return: the workers in order; raises ``ValueError`` naming the problem.
    """
    shared = env if env is not None else TermsEnv(SNAKE_REACH_ENV_ID, {}, REWARD_TERMS)
    terms = list(shared.terms)
    if isinstance(weights, Mapping):
        raise ValueError(f"Expected a sequence of weightings, actually one mapping: {dict(weights)!r:.200}")
    weighted: dict[str, dict[str, float]] = {}
    for index, given in enumerate(weights):
        checked = check_term_weights(given, terms, f"weights[{index}]")
        name = weighted_name(checked)
        if name in weighted:
            raise ValueError(f"Expected each weighting once, actually {name!r} twice in the weights")
        weighted[name] = checked
    names = list(workers) if workers is not None else ([] if weighted else terms)
    corners = [name for name in weighted if corner_term(weighted[name]) == name]
    term_names = names + [name for name in corners if name not in names]
    mixed = {name: w for name, w in weighted.items() if name not in corners}
    heaviest = {name: max(w, key=lambda term: w[term]) for name, w in mixed.items()}
    sources = term_names + [t for t in dict.fromkeys(heaviest.values()) if t not in term_names]
    algos = dict(algos or {})
    unknown = sorted(set(algos) - set(term_names) - set(mixed))
    if unknown:
        raise ValueError(
            f"Expected algorithms for the workers {term_names + list(mixed)}, actually also for {unknown}"
        )
    chosen = worker_algorithms(sources, {k: v for k, v in algos.items() if k in sources}, env)
    for name in mixed:
        chosen[name] = worker_algorithms([name], {name: algos.get(name, chosen[heaviest[name]])}, env)[name]
    blocks = (
        worker_hyperparams(term_names, config, env, {k: chosen[k] for k in term_names}) if term_names else {}
    )
    planned = []
    for name in term_names:
        env_id, view_kwargs = shared.term_view(name)
        block = blocks[name]
        corner = {term: float(term == name) for term in terms}
        planned.append(
            PlannedWorker(name, corner, chosen[name], block, env_id, {**view_kwargs, **block.env_kwargs})
        )
    for name, w in mixed.items():
        # Not its heaviest term's block: that one may observe part of the state only, or relabel by that
        # term alone (the snake's goal worker); a weighted worker learns the shared env's whole task.
        key = shared.config_key
        block = load_hyperparams(
            (f"{key}/{WEIGHTED_PREFIX}", key),
            algorithm(chosen[name]).cls,
            config or default_config(chosen[name]),
        )
        kwargs = {**shared.env_kwargs, **block.env_kwargs}
        check_make_kwargs(shared.env_id, kwargs, f"worker {name!r}: env_kwargs")
        planned.append(PlannedWorker(name, w, chosen[name], block, shared.env_id, kwargs))
    return planned


@holds_run_folder(lambda call: call.arguments["out_dir"], "train_workers")
def train_workers(
    out_dir: str | Path,
    workers: Sequence[str] | None = None,
    config: str | Path | None = None,
    *,
    run: RunOptions | None = None,
    on_worker_done: Callable[[str, TrainingOutcome], None] | None = None,
    callback: MaybeCallback = None,
    env: TermsEnv | None = None,
    algos: Mapping[str, str] | None = None,
    weights: Sequence[Mapping[str, object]] = (),
    term_critic: TermCriticOptions | None = TermCriticOptions(),
    keep_transitions: bool = False,
    warm_starts: Mapping[str, WarmStart] | None = None,
    resume_changes: Sequence[str] = (),
    **run_changes: object,
) -> WorkersResult:
    """
    Train each named worker as a plain SB3 model on its own reward (paper Algorithm 1, first half), and a
    worker per weighting of the terms on their weighted normalised sum, and write
    ``out_dir/workers/<name>.zip`` and ``out_dir/workers/manifest.json``.

    :param out_dir: the run folder.
    :param workers: worker names among :data:`WORKER_ENV_IDS`, or ``env``'s terms (``None``: all of them,
        unless ``weights`` are given: then only the weighted workers).
    :param config: a ``zoo_configs``-format file (default: each worker's algorithm's bundled one).
    :param run: the run-control settings (:class:`~sb3_hddpg.training.run_options.RunOptions`), the same for
        every worker; ``resume`` keeps finished workers and continues interrupted ones.
    :param on_worker_done: called after each worker with its outcome.
    :param callback: more SB3 callbacks for every worker, as SB3's ``learn`` takes them.
    :param env: another env with several objectives (:func:`~sb3_hddpg.envs.terms_env.terms_env`; default:
        the snake arm): one worker per named term, on that term's view.
    :param algos: worker name -> its algorithm (e.g. ``{"goal": "crossq"}``; default: on the snake arm
        :data:`SNAKE_WORKER_ALGOS`, DDPG on another env; a weighted worker: its heaviest term's).
    :param weights: weightings of the terms, one worker each (e.g. ``[{"goal": 0.7, "avoid": 0.3}]``), named
        by :func:`~sb3_hddpg.envs.weighted.weighted_name`; their config block is ``<env id>/mix``, else the
        env's.
    :param term_critic: how each off-policy worker's per-term critic is trained on the transitions it
        collected (:mod:`sb3_hddpg.training.term_critic`); ``None``: no critic.
    :param keep_transitions: also write each off-policy worker's transitions with their normalised terms
        (``<name>.transitions.npz``): what ``grow`` warm-starts a neighbour with.
    :param warm_starts: worker name -> what it starts from, for a fresh start.
    :param resume_changes: with ``resume``, which of the run's ``algo``, ``seed`` and ``config`` may differ
        on purpose (by default a difference is refused).
    :param run_changes: ``RunOptions`` fields as keywords, over ``run``'s.
    :return: the manifest written and the outcome of each worker trained.
    """
    run = run_options(run, run_changes, "train_workers")
    shared = env if env is not None else TermsEnv(SNAKE_REACH_ENV_ID, {}, REWARD_TERMS)
    out_dir = Path(out_dir)
    manifest_path = out_dir / "workers" / "manifest.json"
    planned = plan_workers(workers, weights, config, env, folder_algos(out_dir, weights, env, algos))
    manifest = _start_manifest(manifest_path, shared, env, planned, run.resume, (run.seed, resume_changes))
    with contextlib.closing(shared.make()) as probe:  # the bounds a worker's critic normalises by
        bounds = dict(env_contract(probe).reward_bounds)
    outcomes: dict[str, TrainingOutcome] = {}
    for worker in planned:
        name = worker.name
        budget = int(run.timesteps if run.timesteps is not None else worker.hyperparams.n_timesteps)
        if run.resume and finished_with_budget(manifest.entries.get(name), budget):
            continue  # finished in an earlier run
        paths = AgentPaths(out_dir, name, out_dir / "workers" / f"{name}.zip")
        outcome, facts = _train_worker(
            worker,
            paths,
            agent_run(run, paths, budget),
            (warm_starts or {}).get(name),
            bounds,
            callback,
            term_critic,
            keep_transitions,
        )
        outcomes[name] = outcome
        source = config_source(config, out_dir) if config else f"sb3_hddpg/zoo_configs/{worker.algo}.yml"
        entry = _worker_entry(worker, outcome, source, run, budget, facts)
        manifest = manifest.with_entry(name, entry)
        save_manifest(manifest_path, manifest)
        if on_worker_done is not None:
            on_worker_done(name, outcome)
    return WorkersResult(manifest.to_json(), manifest_path, outcomes)


@dataclass(frozen=True)
class WorkersResult:
    """
    What :func:`train_workers` made.

    :param manifest: the workers' manifest written (its JSON), every worker of the folder in it.
    :param manifest_path: where it was written.
    :param outcomes: worker name -> its training outcome, for the workers this call trained.
    """

    manifest: dict[str, Any]
    manifest_path: Path
    outcomes: dict[str, TrainingOutcome]


def _train_worker(
    worker: PlannedWorker,
    paths: AgentPaths,
    run: RunOptions,
    warm: WarmStart | None,
    bounds: Mapping[str, tuple[float, float]],
    callback: MaybeCallback,
    term_critic: TermCriticOptions | None,
    keep_transitions: bool,
) -> tuple[TrainingOutcome, dict[str, object]]:
    """
    Train one worker, recording the terms of its transitions where something needs them (its critic, its
    kept transitions), then its critic; return the outcome and the facts its entry records about them.

    :param bounds: the shared env's per-term bounds; the other arguments are ``train_workers``'.
    """
    wanted = term_critic is not None or keep_transitions
    recorder = TermRecorder(bounds) if wanted and not REGISTRY[worker.algo].on_policy else None
    facts: dict[str, object] = {}

    def prepare(model: BaseAlgorithm) -> None:
        if warm is not None:
            facts["warm_start"] = {"from": warm.neighbour, **warm.prepare(model, recorder)}

    outcome = train_agent(
        worker.env_factory(),
        worker.hyperparams,
        paths,
        algo=worker.algo,
        run=run,
        callback=[*callback_list(callback), *([recorder] if recorder is not None else [])],
        prepare_model=prepare,
    )
    if recorder is None or not recorder.filled.any():
        return outcome, facts
    transitions = recorded_transitions(recorder)
    if term_critic is not None:
        critic, critic_facts = fit_term_critic(
            outcome.model, transitions, recorder.term_names, term_critic, run.seed
        )
        data = with_term_critic(outcome.model_path.read_bytes(), critic)
        atomic_write(outcome.model_path, lambda tmp: tmp.write_bytes(data))
        facts["term_critic"] = {
            "member": TERM_CRITIC_MEMBER,
            "terms": list(recorder.term_names),
            **critic_facts,
        }
    if keep_transitions:
        path = transitions.save(outcome.model_path.with_name(f"{worker.name}{TRANSITIONS_SUFFIX}"))
        facts["transitions"] = {"file": path.name, "sha256": sha256_file(path), "count": len(transitions)}
    return outcome, facts


def folder_algos(
    out_dir: str | Path,
    weights: Sequence[Mapping[str, object]],
    env: TermsEnv | None = None,
    algos: Mapping[str, str] | None = None,
) -> dict[str, str]:
    """
    ``algos`` with each weighted worker it does not name given the algorithm of its heaviest term's worker in
    the run folder, where there is one: a worker joins a support of its own kind (DQN beside DQN workers).

    :param out_dir: the run folder (its ``workers/manifest.json``, if any).
    :param weights: the weightings of :func:`train_workers`.
    :param env: the env with several objectives (default: the snake arm).
    :param algos: worker name -> algorithm, as given.
    """
    manifest_path = Path(out_dir) / "workers" / "manifest.json"
    chosen = dict(algos or {})
    if not weights or isinstance(weights, Mapping) or not manifest_path.exists():
        return chosen
    entries = read_models_manifest(manifest_path, "workers").entries
    terms = list(env.terms if env is not None else REWARD_TERMS)
    for index, given in enumerate(weights):
        checked = check_term_weights(given, terms, f"weights[{index}]")
        name, heaviest = weighted_name(checked), max(checked, key=checked.__getitem__)
        # An entry need not name its algorithm (the manifest's reader allows it): then the default stands.
        if corner_term(checked) is None and name not in chosen and "algo" in entries.get(heaviest, {}):
            chosen[name] = str(entries[heaviest]["algo"])
    return chosen


def _start_manifest(
    manifest_path: Path,
    shared: TermsEnv,
    env: TermsEnv | None,
    planned: Sequence[PlannedWorker],
    resume: bool,
    asked: tuple[int, Sequence[str]],
) -> ModelsManifest:
    """
    The manifest the workers are added to: a new one, or on ``resume`` the earlier run's, refused in one line
    when its env, or a worker's algorithm, seed or config block, differs from this run's.

    :param asked: the seed this run asks for, and what may differ on purpose.
    """
    earlier = resume and manifest_path.exists()
    manifest = read_models_manifest(manifest_path, "workers") if earlier else models_manifest("workers")
    if resume:
        seed, accept = asked
        checkpoints = manifest_path.parent.parent / "checkpoints"
        for worker in planned:
            # a worker killed before its first entry is compared with what its checkpoint recorded
            entry = manifest.entries.get(worker.name) or checkpoint_record(checkpoints / worker.name)
            check_resumed_agent(entry, worker.name, worker.algo, seed, worker.hyperparams.raw, accept=accept)
    if earlier:
        if env is not None or manifest.shared_env is not None:
            check_resumed_env(
                manifest.shared_env or {"env_id": SNAKE_REACH_ENV_ID}, shared.env_id, shared.env_kwargs
            )
        for worker in planned:
            check_resumed_env(manifest.entries.get(worker.name), worker.env_id, worker.env_kwargs)
    if env is not None:
        manifest = manifest.with_shared_env(env.env_id, env.env_kwargs)
    return manifest


def _worker_entry(
    worker: PlannedWorker,
    outcome: TrainingOutcome,
    config_file: str,
    run: RunOptions,
    budget: int,
    facts: Mapping[str, object],
) -> ModelEntry:
    """
    A trained worker's manifest entry, with the bounds of its reward (the manager normalises by them): a
    per-term worker's raw term's, a weighted worker's [0, 1] (a convex mix of normalised terms).

    :param config_file: the config file its block was read from, as recorded.
    :param facts: what else it records (its critic, kept transitions, warm start).
    """
    if worker.term is not None:
        with contextlib.closing(make_term_view(worker.env_id, worker.env_kwargs, worker.term)) as probe:
            bounds = env_contract(probe).reward_bounds[worker.term]
        reward: dict[str, object] = {"reward_term": worker.term, "reward_bounds": list(bounds)}
    else:
        reward = {"reward_weights": dict(worker.weights), "reward_bounds": [0.0, 1.0]}
    return model_entry(
        worker.name,
        outcome,
        worker.algo,
        worker.env_id,
        worker.env_kwargs,
        {"file": config_file, "block": worker.hyperparams.raw},
        run.seed,
        budget,
        **reward,
        **facts,
        stopped_early=outcome.stopped_early,
        threads=run.threads,
    )
