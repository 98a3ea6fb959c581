"""
The front's support method (``hddpg-support``): the front scenario's members over a support of workers that
cover the front, not one worker per term. In a copy of the seed's workers it trains a worker on each weighting
of the terms the settings name (``front_support``, their ``<env>/mix`` config block), fits every worker a
critic on rollouts (``front_critic_steps``: state values over the full state, or a discrete worker's Q over
its actions), and trains the conditioned manager over all
of them, started from GPI (``front_start``). GPI over the same critics is a member beside it. Every env step
of the support, its critics' rollouts included, counts in the record's ``worker_timesteps``.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from hddpg_zoo.benchmark.method_inputs import MethodSettings, MethodTask
from hddpg_zoo.benchmark.workers_source import copy_workers
from sb3_hddpg.artifacts.manifests import read_workers_manifest
from sb3_hddpg.envs.weighted import parse_term_weights
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.training.term_critic import STATE_CRITIC_OPTIONS, TermCriticOptions, fit_state_critics
from sb3_hddpg.training.workers import folder_algos, plan_workers, train_workers

#: The front scenario's method over a support of workers with critics.
SUPPORT_METHOD = "hddpg-support"


def support_weights(settings: MethodSettings) -> list[dict[str, float]]:
    """The weightings of the terms the support adds a worker for (``front_support``; none when unset)."""
    text = settings.front_support
    return [parse_term_weights(part) for part in text.split(";")] if text else []


def support_folder(task: MethodTask, settings: MethodSettings, folder: Path) -> Path:
    """
    The seed's support, built or finished (a resumed task keeps what is done): the seed's workers copied,
    the weighted workers trained beside them, every worker's critic fitted on rollouts (a state value, or a
    discrete worker's Q).

    :param folder: the seed's folder (its per-term workers).
    :return: the support's run folder (its ``workers/``).
    """
    root = folder / SUPPORT_METHOD / "support"
    if not (root / "workers" / "manifest.json").exists():
        copy_workers(folder, root)
    weights = support_weights(settings)
    if weights:
        algos = folder_algos(root, weights, settings.terms_env)
        planned = plan_workers(None, weights, None, settings.terms_env, algos)
        budget = max(int(p.hyperparams.n_timesteps) for p in planned)
        # A benchmark's worker budget, where set, is every worker's (the block's otherwise).
        run = settings.run_options(task.seed, settings.worker_timesteps, settings.worker_timesteps or budget)
        # Without state critics to come, the weighted workers keep the critic of their own transitions.
        critic = None if settings.front_critic_steps else TermCriticOptions()
        train_workers(root, weights=weights, env=settings.terms_env, algos=algos, run=run, term_critic=critic)
    steps = settings.front_critic_steps
    entries = read_workers_manifest(root / "workers" / "manifest.json").entries
    # Only critics fitted on rollouts record their env steps (of either kind: state values, or discrete Q).
    # A resumed task fits only the workers still without one: each worker's fit is seeded on its own, so
    # the critics come out as one call over all of them would make them.
    stale = [
        name for name, entry in entries.items() if (entry.get("term_critic") or {}).get("env_steps") != steps
    ]
    if steps and stale:
        options = replace(STATE_CRITIC_OPTIONS, rollout_steps=steps)
        fit_state_critics(root, stale, options=options, seed=task.seed)
    return root


def support_sweep(settings: MethodSettings, root: Path) -> PreferenceSpace:
    """
    The preferences the support's managers are trained over and measured at, over its workers (in the
    manifest's order): ``front_sweep``'s ratio sweep, or the preferences it lists.
    """
    names = list(read_workers_manifest(root / "workers" / "manifest.json").entries)
    return PreferenceSpace.parse(settings.front_sweep, names)
