"""
The benchmark's methods as records: a new method is one :class:`Method` passed to :func:`register_method`.

The built-in ones (``hddpg``, ``hddpg-goal``/``hddpg-avoid``, ``ham``, flat ``ddpg``/``td3``/``sac``/``tqc``)
are registered here, with the functions that run them in a task's process.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym

from hddpg_zoo.agent_settings import read_history
from hddpg_zoo.baselines.ttc import CLOSE_SECONDS, DecisionStates, KinematicsScales
from hddpg_zoo.benchmark.episodes import episode_rows
from hddpg_zoo.benchmark.method_inputs import MethodSettings, MethodTask
from sb3_hddpg.algorithms import REGISTRY, algorithms_for
from sb3_hddpg.artifacts.manifests import read_workers_manifest
from sb3_hddpg.baselines.ham import DEFAULT_MARGIN, HAMSwitch, load_ham, save_ham
from sb3_hddpg.baselines.random import RandomPolicy
from sb3_hddpg.envs.contract import env_contract, state_layout_of
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.envs.snake.controllers import DEFAULT_MAX_JOINT_SPEED, make_controller
from sb3_hddpg.envs.terms_env import config_key
from sb3_hddpg.evaluation import EVAL_SEED_BASE, evaluate
from sb3_hddpg.hierarchy.loading import load_policy
from sb3_hddpg.policy import Policy
from sb3_hddpg.training.config import MANAGER_KEY
from sb3_hddpg.training.flat import FLAT_HER_KEY, flat_hyperparams, train_flat
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.manager_setup import manager_hyperparams

#: The pseudo-method of a seed's two workers, which the methods that need them depend on.
WORKERS = "workers"


def _no_blocks(settings: MethodSettings) -> dict[str, object]:
    """No config block of its own (HAM's threshold is a setting; a worker alone is the workers' run)."""
    return {}


@dataclass(frozen=True)
class Method:
    """
    One benchmark method: everything the benchmark knows of it, so that a new method is one record.

    :param name: its name in ``--methods`` and the results.
    :param run: ``run(task, settings, folder) -> fields`` trains (if it learns) and evaluates the task in
        its own process, in the seed's ``folder``, and returns the record's fields: ``history`` (the
        learning curve, every point with ``timesteps`` and ``total_timesteps``), ``test`` (the final test
        summary), ``worker_timesteps`` and anything else worth keeping. It must be a module-level function
        (or a ``functools.partial`` of one) registered at import, since it runs in a spawned process.
    :param cost: its training budget in env steps for the given settings (for scheduling).
    :param needs_workers: it uses its seed's workers, so it runs after them.
    :param colour: its colour in every figure (a matplotlib colour).
    :param default: run when ``--methods`` is not given.
    :param baseline: compared with ``hddpg`` (paired differences by seed) whenever both ran.
    :param takes_preference: it can learn a given preference (the transfer scenario).
    :param challenger: compared, like ``hddpg``, with every baseline (and with ``hddpg``) whenever both ran.
    :param description: one line for the docs.
    :param config_blocks: ``config_blocks(settings) -> {label: block}``: the bundled config
        blocks it trains from, as written. A run's record keeps them, so that ``--resume`` can tell a run
        made from an older block (the workers' blocks belong to the workers' record).
    :param own_settings: the benchmark settings that only this method (and others declaring them) reads,
        e.g. HAM's threshold: a resumed benchmark may change one when it redoes every method that reads it.
    """

    name: str
    run: Callable[[MethodTask, MethodSettings, Path], dict[str, object]]
    cost: Callable[[MethodSettings], int]
    needs_workers: bool = False
    colour: str = "tab:olive"
    default: bool = False
    baseline: bool = False
    takes_preference: bool = False
    challenger: bool = False
    description: str = ""
    config_blocks: Callable[[MethodSettings], dict[str, object]] = _no_blocks
    own_settings: tuple[str, ...] = ()


#: Every method the benchmark knows, by name, in registration order.
METHOD_REGISTRY: dict[str, Method] = {}


def register_method(method: Method) -> Method:
    """
    Add a method to :data:`METHOD_REGISTRY` (a name may be registered once; ``@`` is reserved).

    :param method: the record.
    :return: the record.
    """
    if method.name in METHOD_REGISTRY or method.name == WORKERS or "@" in method.name or not method.name:
        raise ValueError(f"Cannot register benchmark method {method.name!r}: taken or reserved")
    METHOD_REGISTRY[method.name] = method
    return method


def method_key(name: str, preference: str | None = None) -> str:
    """A run's key: the method's name, with ``@<preference>`` in the transfer scenario."""
    return name if preference is None else f"{name}@{preference}"


def split_key(key: str) -> tuple[str, str | None]:
    """The method name and the preference (``None``: none) of a run's key."""
    name, _, preference = key.partition("@")
    return name, preference or None


def final_test(policy_path: Path, settings: MethodSettings) -> dict[str, object]:
    """
    The test evaluation of a saved policy, loaded the safe way a user would load it, on the benchmark's test
    episode set (:attr:`~.settings.BenchmarkSettings.test_set`): the record's ``test``, ``episodes`` and
    ``test_episode_set`` fields.
    """

    # Another env is the user's choice: its id may be loaded from the run's files (allowed_env_ids).
    shared = settings.env
    # The adapter's own id and the env it adapts, as naming them on the command line allows them.
    allowed = [shared["env_id"], config_key(shared["env_id"], shared["env_kwargs"])] if shared else None
    loaded = load_policy(policy_path, allowed_env_ids=allowed)
    env = loaded.make_env()
    try:
        return test_fields(loaded.policy, env, settings)
    finally:
        env.close()


def test_fields(policy: Policy, env: gym.Env, settings: MethodSettings) -> dict[str, object]:
    """
    A policy's test evaluation on the benchmark's test episodes as a record's fields: ``test`` (the summary),
    ``episodes`` (every episode's metrics, :func:`~.episodes.episode_rows`) and ``test_episode_set``; on a
    highway-env env, for a policy that reports its worker choices, ``decisions_by_ttc`` (per worker, its
    share of the decisions made with a car close ahead and with the road clear: :func:`_ttc_shares`).
    """
    episodes = settings.test_episodes or 1
    seeds = settings.test_set.seeds(episodes)
    counted = _decision_states(policy, env, seeds.start)
    result = evaluate(policy if counted is None else counted, env, n_episodes=episodes, seed=seeds.start)
    return {
        "test": result.summary(),
        "episodes": episode_rows(result, env_contract(env).reward_bounds),
        "test_episode_set": settings.test_episode_set,
        **({"decisions_by_ttc": _ttc_shares(counted)} if counted is not None else {}),
    }


def _decision_states(policy: Policy, env: gym.Env, seed: int) -> DecisionStates | None:
    """
    On a highway-env env (Kinematics observation), ``policy`` wrapped to count its worker choices by the
    time to collision they were made at; ``None`` on any other env or for a policy without worker choices.
    """
    if not hasattr(policy, "last_selection"):
        return None
    env.reset(seed=seed)  # highway-env sets the observation's scales at its first reset
    try:
        scales = KinematicsScales.from_env(env)
    except ValueError:
        return None
    return DecisionStates(policy, scales, close=CLOSE_SECONDS)


def _ttc_shares(counted: DecisionStates) -> dict[str, object]:
    """Each worker's share of the decisions with a car close ahead and with the road clear (issue's target)."""
    names = list(getattr(counted.policy, "names", None) or sorted({*counted.close, *counted.clear}))
    return {name: counted.shares(name) for name in names}


def random_reference(settings: MethodSettings) -> dict[str, object]:
    """A random policy's evaluation on the learning-curve episodes: the floor of the transfer figure."""

    env = gym.make(SNAKE_REACH_ENV_ID)
    try:
        policy = RandomPolicy(env.action_space, seed=0)
        return evaluate(policy, env, n_episodes=settings.eval_episodes, seed=EVAL_SEED_BASE).summary()
    finally:
        env.close()


def workers_steps(folder: Path) -> int:
    """Env steps of the seed's workers together, their critics' rollouts included, as their manifest records them."""
    return sum(worker_steps(folder).values())


def worker_steps(folder: Path) -> dict[str, int]:
    """
    Each worker's env steps, its critic's rollouts included, as the manifest records them.

    :param folder: the run folder (its ``workers/manifest.json``).
    :raises ValueError: naming the manifest when an entry has no whole ``timesteps_trained``.
    """
    path = folder / "workers" / "manifest.json"
    manifest = read_workers_manifest(path)
    try:
        # A critic fitted on rollouts (fit-critics) cost their env steps; one fitted on the worker's own
        # transitions cost none.
        return {
            name: int(entry["timesteps_trained"]) + int((entry.get("term_critic") or {}).get("env_steps", 0))
            for name, entry in manifest.entries.items()
        }
    except (KeyError, TypeError, ValueError, OverflowError):
        raise ValueError(f"{path}: a worker entry has no whole timesteps_trained") from None


def _run_manager(
    prefer: str | None, task: MethodTask, settings: MethodSettings, folder: Path, algo: str = "ddpg"
) -> dict[str, object]:
    """
    A manager over the seed's workers, preferring ``prefer`` by ``bias`` (or with the task's factors), of
    algorithm ``algo`` (its bundled config's manager block), for the manager's env steps.
    """

    run_dir = folder / task.method
    env = settings.terms_env
    train_manager(
        folder,
        run_dir,
        env_id=env.env_id if env is not None else None,
        env_kwargs=env.env_kwargs if env is not None else None,
        prefer=prefer,
        bias=settings.bias,
        preferences=task.preferences,
        algo=algo,
        run=settings.manager_run_options(task.seed, algo),
    )
    offset = workers_steps(folder)
    steps_per_decision = settings.option_steps_of(algo)
    return {
        "worker_timesteps": offset,
        "history": read_history(run_dir / "evaluations" / "manager.json", steps_per_decision, offset),
        **final_test(run_dir / "hierarchy.zip", settings),
    }


def _run_flat(
    algo: str, task: MethodTask, settings: MethodSettings, folder: Path, block: str | None = None
) -> dict[str, object]:
    """
    A flat agent on the combined reward (or the task's scalarised one) for the hierarchy's total steps, from
    its config's block for the env (or ``block``).
    """

    run_dir = folder / task.method
    env = settings.terms_env
    train_flat(
        run_dir,
        algo=algo,
        env_id=env.env_id if env is not None else SNAKE_REACH_ENV_ID,
        env_kwargs=env.env_kwargs if env is not None else None,
        preferences=task.preferences,
        run=settings.run_options(task.seed, settings.flat_budget, settings.flat_budget),
        block=block,
    )
    return {
        "worker_timesteps": 0,
        "history": read_history(run_dir / "evaluations" / f"flat-{algo}.json"),
        **final_test(run_dir / "flat" / f"{algo}.zip", settings),
    }


def _run_ham(tuned: bool, task: MethodTask, settings: MethodSettings, folder: Path) -> dict[str, object]:
    """
    Save the seed's HAM switch and evaluate it: one learning-curve point (it does not learn) and the test.

    With ``tuned`` its threshold is the best of a grid on the learning-curve episodes (the episodes every
    other method's best model is picked on), never on the test episodes; otherwise ``--ham-threshold``.
    """

    env = gym.make(SNAKE_REACH_ENV_ID)
    try:
        n_links = state_layout_of(env)["joint_obstacle_distances"]
        n_links_count = n_links.stop - n_links.start
        threshold = settings.ham_threshold
        if threshold is None or tuned:
            threshold = n_links_count - DEFAULT_MARGIN
        offset = workers_steps(folder)
        ham_path = save_ham(
            folder / task.method / "ham.json",
            folder / "workers" / "manifest.json",
            threshold=threshold,
            hysteresis=settings.ham_hysteresis,
            env_id=SNAKE_REACH_ENV_ID,
            metadata={"seed": task.seed, "worker_timesteps": offset},
        )
        switch, _ = load_ham(ham_path)
        grid: list[dict[str, float]] = []
        if tuned:
            threshold, grid = _tune_threshold(switch, env, settings)
            ham_path = save_ham(
                ham_path,
                folder / "workers" / "manifest.json",
                threshold=threshold,
                hysteresis=settings.ham_hysteresis,
                env_id=SNAKE_REACH_ENV_ID,
                metadata={"seed": task.seed, "worker_timesteps": offset, "threshold_grid": grid},
            )
            switch.threshold = threshold
        curve = evaluate(switch, env, n_episodes=settings.eval_episodes, seed=EVAL_SEED_BASE).summary()
    finally:
        env.close()
    return {
        "worker_timesteps": offset,
        "history": [{"timesteps": 0, "total_timesteps": offset, **curve}],
        **final_test(ham_path, settings),
        "threshold": threshold,
        "hysteresis": settings.ham_hysteresis,
        **({"threshold_grid": grid} if tuned else {}),
    }


def _tune_threshold(
    switch: HAMSwitch, env: gym.Env, settings: MethodSettings
) -> tuple[float, list[dict[str, float]]]:
    """
    The switch's best threshold on its grid (:meth:`~sb3_hddpg.baselines.ham.HAMSwitch.threshold_grid`),
    scored on the learning-curve episodes, and the grid's scores; ``switch`` is left at the best.
    """
    grid: list[dict[str, float]] = []
    for threshold in switch.threshold_grid():
        switch.threshold = threshold
        point = evaluate(switch, env, n_episodes=settings.eval_episodes, seed=EVAL_SEED_BASE).summary()
        grid.append({"threshold": switch.threshold, "mean_reward": point["mean_reward"]})
    # The first best on ties: the smallest threshold, the one that hands over to the avoid worker least.
    switch.threshold = max(grid, key=lambda point: point["mean_reward"])["threshold"]
    return switch.threshold, grid


def _run_controllers(task: MethodTask, settings: MethodSettings, folder: Path) -> dict[str, object]:
    """
    HAM's switch over the snake arm's hand-written controllers instead of trained workers: the IK reacher
    and the potential-field avoider, its threshold tuned as ``ham-tuned``'s. Nothing is trained or saved
    (the code is the policy), and every seed measures the same policy: what a user who writes both skills
    and the switch by hand gets, the bar a learned hierarchy is held to on the snake arm.
    """

    env = gym.make(SNAKE_REACH_ENV_ID)
    try:
        layout = state_layout_of(env)
        speed = float(getattr(env.unwrapped, "max_joint_speed", DEFAULT_MAX_JOINT_SPEED))
        switch = HAMSwitch(
            make_controller("ik", layout, speed),
            make_controller("field", layout, speed),
            layout,
            hysteresis=settings.ham_hysteresis,
        )
        threshold, grid = _tune_threshold(switch, env, settings)
        curve = evaluate(switch, env, n_episodes=settings.eval_episodes, seed=EVAL_SEED_BASE).summary()
        test = test_fields(switch, env, settings)
    finally:
        env.close()
    return {
        "worker_timesteps": 0,
        "history": [{"timesteps": 0, "total_timesteps": 0, **curve}],
        **test,
        "threshold": threshold,
        "hysteresis": settings.ham_hysteresis,
        "threshold_grid": grid,
    }


def _run_worker_alone(
    worker: str, task: MethodTask, settings: MethodSettings, folder: Path
) -> dict[str, object]:
    """
    The seed's ``worker`` alone on the combined task (seeing its own share of the state): what a manager
    over it has to beat, since a manager could always pick that worker.
    """

    offset = workers_steps(folder)
    loaded = load_policy(folder / "workers" / f"{worker}.zip")
    env = loaded.make_env(SNAKE_REACH_ENV_ID)
    try:
        curve = evaluate(loaded.policy, env, n_episodes=settings.eval_episodes, seed=EVAL_SEED_BASE).summary()
        test = test_fields(loaded.policy, env, settings)
    finally:
        env.close()
    return {
        "worker_timesteps": offset,
        "history": [{"timesteps": 0, "total_timesteps": offset, **curve}],
        **test,
    }


def _manager_blocks(algo: str, settings: MethodSettings) -> dict[str, object]:
    """The manager block of ``algo``'s bundled config."""
    return {f"{algo}.yml[{MANAGER_KEY}]": manager_hyperparams(algo).raw}


def _flat_blocks(algo: str, settings: MethodSettings, block: str | None = None) -> dict[str, object]:
    """The block of ``algo``'s bundled config that a flat agent on the benchmark's env reads (or ``block``)."""
    env = settings.terms_env
    env_id, env_kwargs = (env.env_id, env.env_kwargs) if env is not None else (SNAKE_REACH_ENV_ID, None)
    label = f"{algo}.yml[{block}]" if block else f"{algo}.yml, flat agent on {env_id}"
    return {label: flat_hyperparams(algo, env_id, env_kwargs, block=block).raw}


def _manager_cost(settings: MethodSettings) -> int:
    return settings.manager_env_steps


def _flat_cost(settings: MethodSettings) -> int:
    return settings.flat_budget


def _no_cost(settings: MethodSettings) -> int:
    return 0


register_method(
    Method(
        "hddpg",
        functools.partial(_run_manager, None),
        _manager_cost,
        needs_workers=True,
        colour="tab:red",
        default=True,
        takes_preference=True,
        description="the two workers, then a manager with equal preferences (paper Algorithm 1)",
        config_blocks=functools.partial(_manager_blocks, "ddpg"),
    )
)
register_method(
    Method(
        "ham",
        functools.partial(_run_ham, False),
        _no_cost,
        needs_workers=True,
        colour="tab:gray",
        default=True,
        baseline=True,
        description="the hand-written switch over the same workers, no training",
        own_settings=("ham_threshold", "ham_hysteresis"),
    )
)
register_method(
    Method(
        "ham-tuned",
        functools.partial(_run_ham, True),
        _no_cost,
        needs_workers=True,
        colour="black",
        default=True,
        baseline=True,
        description="the same switch with its threshold the best of a grid on the learning-curve episodes",
        own_settings=("ham_hysteresis",),
    )
)
register_method(
    Method(
        "controllers",
        _run_controllers,
        _no_cost,
        colour="sienna",
        baseline=True,
        description="the tuned switch over hand-written skills (the IK reacher, the field avoider), no training",
        own_settings=("ham_hysteresis",),
    )
)
#: Every algorithm that can be a flat agent on the combined task's Box action (each a method in its record's
#: colour): ``train_flat``'s algorithms.
FLAT_METHODS = algorithms_for("flat", gym.spaces.Box(-1, 1))


def flat_method(algo: str, reward: str, default: bool = False) -> Method:
    """
    The flat agent of ``algo`` as a method, in its record's colour, for the hierarchy's total env steps.

    :param reward: what it learns, as its description says it (``combined``, ``scalarised``).
    :param default: whether the benchmark runs it unless ``--methods`` says otherwise.
    """
    return Method(
        algo,
        functools.partial(_run_flat, algo),
        _flat_cost,
        colour=REGISTRY[algo].colour,
        default=default,
        baseline=True,
        takes_preference=True,
        description=f"flat {REGISTRY[algo].class_name} on the {reward} reward for the hierarchy's total env steps",
        config_blocks=functools.partial(_flat_blocks, algo),
    )


for _algo in FLAT_METHODS:
    register_method(flat_method(_algo, "combined", default=_algo == "ddpg"))
for _algo, _colour in (("sac", "darkviolet"), ("ddpg", "navy")):
    register_method(
        Method(
            f"{_algo}-her",
            functools.partial(_run_flat, _algo, block=FLAT_HER_KEY),
            _flat_cost,
            colour=_colour,
            baseline=True,
            description=(
                f"flat {REGISTRY[_algo].class_name} with the goal worker's tricks (hindsight relabelling"
                + (", the IK reacher's prior" if _algo == "ddpg" else "")
                + f"; {_algo}.yml[{FLAT_HER_KEY}]) on the full observation and the reach reward, the flat budget"
            ),
            config_blocks=functools.partial(_flat_blocks, _algo, block=FLAT_HER_KEY),
        )
    )
for _worker, _colour in (("goal", "yellowgreen"), ("avoid", "gold")):
    register_method(
        Method(
            f"{_worker}-only",
            functools.partial(_run_worker_alone, _worker),
            _no_cost,
            needs_workers=True,
            colour=_colour,
            default=True,
            baseline=True,
            description=f"the {_worker} worker alone on the combined task, no manager",
        )
    )
for _worker, _colour in (("goal", "tab:green"), ("avoid", "tab:orange")):
    register_method(
        Method(
            f"hddpg-{_worker}",
            functools.partial(_run_manager, _worker),
            _manager_cost,
            needs_workers=True,
            colour=_colour,
            default=True,
            description=f"a manager preferring the {_worker} worker by the bias (paper Figure 10)",
            own_settings=("bias",),
            config_blocks=functools.partial(_manager_blocks, "ddpg"),
        )
    )

register_method(
    Method(
        "hddpg-sac",
        functools.partial(_run_manager, None, algo="sac"),
        _manager_cost,
        needs_workers=True,
        colour="tab:pink",
        challenger=True,
        takes_preference=True,
        description="the same hierarchy with a SAC manager (zoo_configs/sac.yml's manager block), the same env steps",
        config_blocks=functools.partial(_manager_blocks, "sac"),
    )
)

#: The built-in methods (the registry may hold more).
METHODS = tuple(METHOD_REGISTRY)
#: The methods run by default: the paper's three, the biased managers of Figure 10 and the references that need no
#: training (HAM tuned, each worker alone).
DEFAULT_METHODS: tuple[str, ...] = tuple(m.name for m in METHOD_REGISTRY.values() if m.default)
#: Flat agents with the goal worker's tricks, and the algorithm each trains.
FLAT_HER_METHODS = {"sac-her": "sac", "ddpg-her": "ddpg"}
#: The default methods on another env with several objectives and continuous actions (``BenchmarkSettings.env``;
#: every method defined there, and the defaults on discrete actions: :mod:`.env_methods`).
DEFAULT_ENV_METHODS = ("hddpg", "ddpg")
