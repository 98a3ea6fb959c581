"""
The benchmark's methods on environments other than the snake arm (``BenchmarkSettings.env``).

- ``term1-only`` ... ``term4-only``: the env's 1st ... 4th worker (one per reward term, in the env's term
  order) alone on the scalarised task, no manager: what a manager over it has to beat;
- ``dqn``, ``qrdqn``: flat agents for envs with discrete actions (``ppo`` takes both kinds and is registered
  with the continuous ones), on the scalarised reward at the hierarchy's total env steps;
- ``hddpg-dqn``, ``hddpg-qrdqn``: the hierarchy with a DQN (QR-DQN) manager in the ``discrete`` selection
  mode (its action is the index of the worker to run, held for ``option_steps`` env steps);
- ``ttc`` / ``ttc-tuned``: on highway-env's envs, the hand-written time-to-collision switch
  (:class:`~hddpg_zoo.baselines.ttc.TTCSwitch`) over the env's first worker (fast) and its last (safe), at its
  default threshold or at the best of a grid on the learning-curve episodes (never the test episodes).

Every test evaluation on a highway-env env also counts the decisions of a policy that reports its worker
choices by the time to collision they were made at (:func:`~.methods.test_fields`'s ``decisions_by_ttc``).
"""

from __future__ import annotations

import functools
from pathlib import Path

import gymnasium as gym

from hddpg_zoo.baselines.ttc import DEFAULT_TTC_THRESHOLD, TTC_GRID, KinematicsScales, TTCSwitch
from hddpg_zoo.benchmark.method_inputs import MethodSettings, MethodTask
from hddpg_zoo.benchmark.methods import (
    DEFAULT_ENV_METHODS,
    FLAT_METHODS,
    Method,
    _manager_blocks,
    _manager_cost,
    _no_cost,
    _run_manager,
    flat_method,
    register_method,
    test_fields,
    workers_steps,
)
from sb3_hddpg.algorithms import REGISTRY, algorithms_for
from sb3_hddpg.envs.terms_env import TermsEnv, config_key
from sb3_hddpg.evaluation import EVAL_SEED_BASE, evaluate
from sb3_hddpg.hierarchy.loading import load_policy
from sb3_hddpg.policy import Policy

#: Workers alone by position: as many methods as an env may have terms worth comparing one by one.
MAX_ALONE_WORKERS = 4


def _shared_env(settings: MethodSettings, method: str) -> TermsEnv:
    env = settings.terms_env
    if env is None:
        raise ValueError(f"Method {method!r} runs on another env than the snake arm (benchmark --env)")
    return env


def combined_env(env: TermsEnv) -> gym.Env:
    """The env with the step reward every method is scored on: the sum of the normalised terms."""
    return gym.make(env.env_id, **env.env_kwargs)


def load_env_worker(folder: Path, env: TermsEnv, name: str) -> Policy:
    """A seed's worker, loaded the safe way, its env id allowed as the benchmark's own."""
    allowed = [env.env_id, config_key(env.env_id, env.env_kwargs)]
    return load_policy(folder / "workers" / f"{name}.zip", allowed_env_ids=allowed).policy


def _curve_point(policy: Policy, env: gym.Env, settings: MethodSettings) -> dict[str, float]:
    """One learning-curve evaluation (the learning-curve episodes): a reference that does not learn."""
    return evaluate(policy, env, n_episodes=settings.eval_episodes, seed=EVAL_SEED_BASE).summary()


def _run_term_alone(
    index: int, task: MethodTask, settings: MethodSettings, folder: Path
) -> dict[str, object]:
    """The seed's worker of the env's ``index``-th term alone on the scalarised task."""
    shared = _shared_env(settings, task.method)
    if index >= len(shared.terms):
        raise ValueError(
            f"Method {task.method!r}: the env has {len(shared.terms)} terms {list(shared.terms)}, no term {index + 1}"
        )
    worker = shared.terms[index]
    policy = load_env_worker(folder, shared, worker)
    env = combined_env(shared)
    try:
        curve = _curve_point(policy, env, settings)
        test = test_fields(policy, env, settings)
    finally:
        env.close()
    offset = workers_steps(folder)
    return {
        "worker": worker,
        "worker_timesteps": offset,
        "history": [{"timesteps": 0, "total_timesteps": offset, **curve}],
        **test,
    }


def kinematics_scales(env: gym.Env) -> KinematicsScales | None:
    """The scales of ``env``'s highway-env Kinematics observation (reset at the curve episodes' first seed), else ``None``."""
    env.reset(seed=EVAL_SEED_BASE)  # highway-env sets the observation's scales at its first reset
    try:
        return KinematicsScales.from_env(env)
    except ValueError:
        return None


def ttc_switch(folder: Path, env: TermsEnv, probe: gym.Env) -> TTCSwitch:
    """The time-to-collision switch over the seed's fast and safe workers (:func:`ttc_workers`), on ``probe``."""
    scales = kinematics_scales(probe)
    if scales is None:
        raise ValueError(
            f"The time-to-collision switch needs highway-env's Kinematics observation; {env.env_id!r} has none"
        )
    fast, safe = ttc_workers(env)
    return TTCSwitch(
        load_env_worker(folder, env, fast), load_env_worker(folder, env, safe), scales, names=(fast, safe)
    )


def ttc_workers(env: TermsEnv) -> tuple[str, str]:
    """The time-to-collision switch's (fast, safe) workers: the env's first and last terms."""
    if len(env.terms) < 2:
        raise ValueError(
            f"The time-to-collision switch needs two workers; the env has terms {list(env.terms)}"
        )
    return env.terms[0], env.terms[-1]


def _run_ttc(tuned: bool, task: MethodTask, settings: MethodSettings, folder: Path) -> dict[str, object]:
    """
    The time-to-collision switch over the seed's fast and safe workers: one learning-curve point (it does not
    learn) and the test; with ``tuned`` its threshold is the best of :data:`TTC_GRID` on the learning-curve
    episodes (the first best on ties: the smallest, which hands over to the safe worker least).
    """
    shared = _shared_env(settings, task.method)
    fast, safe = ttc_workers(shared)
    env = combined_env(shared)
    try:
        switch = ttc_switch(folder, shared, env)
        grid: list[dict[str, float]] = []
        if tuned:
            for threshold in TTC_GRID:
                switch.threshold = threshold
                point = _curve_point(switch, env, settings)
                grid.append({"threshold": threshold, "mean_reach_reward": point["mean_reach_reward"]})
            switch.threshold = max(grid, key=lambda p: p["mean_reach_reward"])["threshold"]
        curve = _curve_point(switch, env, settings)
        test = test_fields(switch, env, settings)
    finally:
        env.close()
    offset = workers_steps(folder)
    return {
        "worker_timesteps": offset,
        "history": [{"timesteps": 0, "total_timesteps": offset, **curve}],
        **test,
        "threshold": switch.threshold,
        "workers": {"fast": fast, "safe": safe},
        **({"threshold_grid": grid} if tuned else {}),
    }


for _index in range(MAX_ALONE_WORKERS):
    register_method(
        Method(
            f"term{_index + 1}-only",
            functools.partial(_run_term_alone, _index),
            _no_cost,
            needs_workers=True,
            colour=("yellowgreen", "gold", "peru", "khaki")[_index],
            baseline=True,
            description=f"the env's worker of its term {_index + 1} alone on the scalarised task, no manager",
        )
    )

#: Flat agents that act in discrete action spaces only (PPO, which takes both, is among :data:`FLAT_METHODS`).
DISCRETE_FLAT_METHODS = tuple(
    a for a in algorithms_for("flat", gym.spaces.Discrete(2)) if a not in FLAT_METHODS
)
for _algo in DISCRETE_FLAT_METHODS:
    register_method(flat_method(_algo, "scalarised"))

#: Managers in the ``discrete`` selection mode (their bundled manager block's ``wrapper_kwargs``).
DISCRETE_MANAGERS = tuple(
    a
    for a in algorithms_for("manager", gym.spaces.Discrete(2))
    if not REGISTRY[a].takes(gym.spaces.Box(-1, 1))
)
for _algo in DISCRETE_MANAGERS:
    register_method(
        Method(
            f"hddpg-{_algo}",
            functools.partial(_run_manager, None, algo=_algo),
            _manager_cost,
            needs_workers=True,
            colour={"dqn": "firebrick", "qrdqn": "darkred"}.get(_algo, "tab:red"),
            challenger=True,
            takes_preference=True,
            description=(
                f"the hierarchy with a {REGISTRY[_algo].class_name} manager picking a worker by index ({_algo}.yml's manager "
                "block: the discrete selection mode), the same env steps"
            ),
            config_blocks=functools.partial(_manager_blocks, _algo),
        )
    )

for _tuned in (False, True):
    register_method(
        Method(
            "ttc-tuned" if _tuned else "ttc",
            functools.partial(_run_ttc, _tuned),
            _no_cost,
            needs_workers=True,
            colour="black" if _tuned else "tab:gray",
            baseline=True,
            description=(
                "highway-env: the safe (last) worker while the time to collision with the car ahead is below "
                + (
                    "the best threshold of a grid on the learning-curve episodes"
                    if _tuned
                    else f"{DEFAULT_TTC_THRESHOLD:g} s"
                )
                + ", else the fast (first) worker; no training"
            ),
        )
    )

#: Every method defined on another env with several objectives (``BenchmarkSettings.env``).
ENV_METHODS = (
    "hddpg",
    *FLAT_METHODS,
    *DISCRETE_FLAT_METHODS,
    *(f"hddpg-{a}" for a in DISCRETE_MANAGERS),
    *(f"term{i + 1}-only" for i in range(MAX_ALONE_WORKERS)),
    "ttc",
    "ttc-tuned",
)
#: The methods defined on another env only, not on the snake arm.
ENV_ONLY_METHODS = tuple(m for m in ENV_METHODS if m != "hddpg" and m not in FLAT_METHODS)
#: The methods that act in discrete action spaces only, refused on an env with continuous actions.
DISCRETE_ONLY_METHODS = (*DISCRETE_FLAT_METHODS, *(f"hddpg-{a}" for a in DISCRETE_MANAGERS))
#: The methods that read highway-env's Kinematics observation.
KINEMATICS_METHODS = ("ttc", "ttc-tuned")


def default_env_methods(env: TermsEnv) -> tuple[str, ...]:
    """
    The methods ``benchmark --env`` runs by default on ``env``: on continuous actions the DDPG hierarchy and
    flat DDPG; on discrete actions the DQN-manager hierarchy, each worker alone, flat DQN and PPO, and on a
    highway-env env the tuned time-to-collision switch.
    """
    probe = combined_env(env)
    try:
        discrete = isinstance(probe.action_space, gym.spaces.Discrete)
        kinematics = kinematics_scales(probe) is not None
    finally:
        probe.close()
    if not discrete:
        return DEFAULT_ENV_METHODS
    alone = tuple(f"term{i + 1}-only" for i in range(min(len(env.terms), MAX_ALONE_WORKERS)))
    return ("hddpg-dqn", *alone, "dqn", "ppo", *(("ttc-tuned",) if kinematics else ()))


def is_discrete(env: TermsEnv) -> bool:
    """Whether ``env`` acts in a ``Discrete`` action space (its workers are then DQN by default)."""
    probe = combined_env(env)
    try:
        return isinstance(probe.action_space, gym.spaces.Discrete)
    finally:
        probe.close()


__all__ = [
    "DISCRETE_FLAT_METHODS",
    "DISCRETE_MANAGERS",
    "DISCRETE_ONLY_METHODS",
    "ENV_METHODS",
    "ENV_ONLY_METHODS",
    "KINEMATICS_METHODS",
    "MAX_ALONE_WORKERS",
    "combined_env",
    "default_env_methods",
    "is_discrete",
    "kinematics_scales",
    "load_env_worker",
    "ttc_switch",
    "ttc_workers",
]
