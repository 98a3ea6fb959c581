"""The benchmark's settings (``benchmark.json``), each checked when built; its tasks are planned by :mod:`~.tasks`."""

from __future__ import annotations

import contextlib
import functools
import json
import math
from dataclasses import dataclass, field

import gymnasium as gym
from stable_baselines3 import DDPG

from hddpg_zoo.agent_settings import backend_for, manager_option_steps
from hddpg_zoo.benchmark.env_methods import (
    DISCRETE_FLAT_METHODS,
    DISCRETE_ONLY_METHODS,
    ENV_METHODS,
    ENV_ONLY_METHODS,
    is_discrete,
)
from hddpg_zoo.benchmark.method_inputs import EnvChoice
from hddpg_zoo.benchmark.methods import (
    DEFAULT_METHODS,
    FLAT_HER_METHODS,
    FLAT_METHODS,
    METHOD_REGISTRY,
    method_key,
)
from hddpg_zoo.benchmark.morl import mo_gymnasium_env
from hddpg_zoo.records.field_types import check_field_types
from sb3_hddpg.algorithms import algorithm, algorithms_for
from sb3_hddpg.artifacts.limits import (
    MAX_BENCHMARK_SEEDS,
    MAX_OPTION_STEPS,
    MAX_SEED,
    MAX_TERMS,
    brief,
    check_env_id,
    check_name,
)
from sb3_hddpg.artifacts.values import RUN_SETTINGS, check_env_kwargs
from sb3_hddpg.envs import EnvUnavailableError
from sb3_hddpg.envs.ids import WORKER_ENV_IDS
from sb3_hddpg.envs.terms_env import TermsEnv
from sb3_hddpg.envs.weighted import parse_term_weights
from sb3_hddpg.episode_sets import DEVELOPMENT, FINAL_TEST, FINAL_TEST_EPISODES, EpisodeSet
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.hierarchy.selection import parse_preferences, preferences_from_bias
from sb3_hddpg.training.backends import check_algo, check_backend
from sb3_hddpg.training.config import MANAGER_KEY, load_hyperparams
from sb3_hddpg.training.run_options import RunOptions
from sb3_hddpg.training.workers import worker_hyperparams


@functools.cache
def _config_budgets() -> dict[str, int]:
    """The bundled config's budgets (``n_timesteps``): each snake worker's and the manager's."""

    budgets = {name: hp.n_timesteps for name, hp in worker_hyperparams(sorted(WORKER_ENV_IDS)).items()}
    budgets[MANAGER_KEY] = load_hyperparams(MANAGER_KEY, DDPG, manager=True).n_timesteps
    return budgets


@functools.cache
def _manager_option_steps() -> int:
    """Env steps per decision of the benchmark's managers: the bundled manager block's ``option_steps``."""
    return manager_option_steps()


@functools.cache
def _env_worker_budgets(env_json: str, worker_algo: str | None = None) -> list[int]:
    """Each worker's config budget on another env (given as JSON, so that the config is read once per env)."""
    env = json.loads(env_json)
    shared = TermsEnv(env["env_id"], dict(env["env_kwargs"]), tuple(env["terms"]))
    algos = dict.fromkeys(shared.terms, worker_algo) if worker_algo else None
    return [
        block.n_timesteps for block in worker_hyperparams(list(shared.terms), None, shared, algos).values()
    ]


@functools.cache
def _env_is_discrete(env_json: str) -> bool:
    """Whether another env (given as JSON) acts in a Discrete action space: made once per env and process."""
    env = json.loads(env_json)
    return is_discrete(TermsEnv(env["env_id"], dict(env["env_kwargs"]), tuple(env["terms"])))


#: Test episodes per trained model of a development run (the final test set has its own number).
DEVELOPMENT_TEST_EPISODES = 20
#: The most env steps of rollouts a front's state-value critic is fitted on, per worker.
MAX_CRITIC_STEPS = 10_000_000

#: ``standard``: every method once per seed; ``transfer``: managers and flat agents on new preferences;
#: ``front``: every hierarchy over the whole trade-off (:mod:`.front`).
SCENARIOS = ("standard", "transfer", "front")
#: The methods of the front scenario, each measuring every front of a seed: over the per-term workers, and
#: over a support of workers with critics. The first is the scenario's default.
FRONT_METHODS = ("hddpg-front", "hddpg-support")
#: The preferences of the transfer scenario by default: the goal term weighted twice, then the avoid term.
DEFAULT_TRANSFER_PREFERENCES = ("goal=2,avoid=1", "goal=1,avoid=2")
#: The methods of the transfer scenario by default: the manager against flat DDPG.
DEFAULT_TRANSFER_METHODS = ("hddpg", "ddpg")


def canonical_preference(text: str) -> str:
    """
    A preference such as ``"goal=2, avoid=1"`` checked and written one way (``goal=2,avoid=1``: factors in
    the given order, ``%g``), so that it names the same runs however it was typed.

    :raises ValueError: naming the bad entry.
    """

    factors = parse_preferences(text)
    for name, value in factors.items():
        if not (math.isfinite(value) and value > 0):
            raise ValueError(
                f"Expected preference of {name!r} to be a finite number > 0, actually: {value!r}"
            )
    return ",".join(f"{name}={value:g}" for name, value in factors.items())


def _is_flat(method: str) -> bool:
    """A flat agent's method (continuous, with the goal worker's tricks, or discrete), trained by its algorithm."""
    return method in FLAT_METHODS or method in FLAT_HER_METHODS or method in DISCRETE_FLAT_METHODS


@dataclass
class BenchmarkSettings:
    """
    What to run; stored in ``DIR/benchmark.json`` so that ``--resume`` continues the same benchmark.

    :param methods: methods among :data:`METHOD_REGISTRY`.
    :param seeds: training seeds (each method runs once per seed).
    :param timesteps: the manager's budget, in its own (env) steps (``0``: the bundled config's manager
        block, ``n_timesteps``; resolved when the settings are made, so ``benchmark.json`` records it).
    :param worker_timesteps: each worker's budget (``None``: each worker's own config block, e.g. 150k steps
        for the goal worker and 30k for the avoid worker).
    :param flat_timesteps: a flat agent's budget (``None``: ``timesteps`` plus every worker's budget, so
        that a flat agent uses as many environment steps as the whole hierarchy).
    :param eval_freq: steps between learning-curve evaluations of every run (``None``: ``timesteps // 10``).
    :param eval_episodes: episodes per learning-curve evaluation.
    :param test_episodes: episodes of each trained model's test evaluation (``None``: 20 on the development
        episodes, :data:`~sb3_hddpg.episode_sets.FINAL_TEST_EPISODES` on the final test set).
    :param ham_threshold: HAM's switching threshold (``None``: its default).
    :param ham_hysteresis: HAM's hysteresis.
    :param bias: the biased managers' extra preference factor.
    :param scenario: ``standard`` or ``transfer`` (see the module's docstring).
    :param preferences: the transfer scenario's preferences, e.g. ``["goal=2,avoid=1"]``; every method runs
        once per preference and seed (empty in the standard scenario).
    :param backend: the training backend of every agent, ``sb3`` or ``sbx`` (saved models are SB3 either way).
    :param env: another env with several objectives, as ``{"env_id", "env_kwargs", "terms"}`` (a
        :class:`~sb3_hddpg.envs.terms_env.TermsEnv`'s fields, see :attr:`terms_env`; ``None``: the snake
        arm): its workers, managers and flat agents are trained and tested on it. Only the methods of
        :data:`ENV_METHODS`, the front's and the standard and front scenarios apply there (HAM's switch rule
        and the biased managers are the snake's).
    :param workers_from: another benchmark folder whose workers every seed reuses instead of training its
        own (they must have been trained with the same config blocks, budget, backend, env and seed: then
        they are the workers this benchmark would train, since a seed's run is deterministic on the CPU).
        The copies are checked against their manifest's sha256 (:func:`~.workers_source.check_workers_source`).
        Records state it relative to the benchmark's folder (:func:`~.machine_paths.settings_record`).
    :param final_test: score every run on the final test set (:data:`~sb3_hddpg.episode_sets.FINAL_TEST`):
        for the runs of record only, never for a choice; otherwise on the development episodes.
    :param worker_algo: the algorithm of every worker on another env (``None``: DDPG on continuous actions,
        DQN on discrete ones; see :attr:`worker_algos`). The snake arm's workers keep their own.
    :param front_manager: the algorithm of the front's managers (method ``hddpg-front``: the
        preference-conditioned one and one per sweep preference), any manager algorithm: DDPG on the
        simplex as in the paper, or e.g. DQN choosing a worker by index (on SB3 if ``backend`` does not
        train it).
    :param front_timesteps: the budget of each of the front's managers, in env steps (``None``: the
        manager's, :attr:`manager_env_steps`). A flat agent's default budget does not change with it.
    :param front_sweep: the preferences the front's conditioned manager is trained over and its front is
        measured at, one manager per preference beside it: ``ratio-sweep`` (ratios 1 to 4, 7 preferences
        for two workers) or ``ratio-sweep:MAX`` (ratios doubling up to ``MAX``; ``ratio-sweep:16``: 9).
    :param front_motion: the front's managers also see how their state moved over the last env step,
        scaled by this factor (``manager_motion`` of ``train_manager``; 0: not).
    :param front_option_steps: env steps per decision of the front's managers (``None``: their manager
        block's ``option_steps``). On an env whose state changes faster than the block's options last (a
        car closing in within a few steps) a manager holding a choice that long cannot react in time. The
        block's discount is scaled to keep its horizon in env steps (``horizon_gamma``).
    :param front_per_preference: the front also trains one manager per sweep preference, the reference the
        conditioned manager is measured against (``False``: the conditioned manager alone, which is what one
        policy for every preference costs; on a slow env it saves most of the front's training).
    :param front_support: weightings of the terms (``goal=0.5,avoid=0.5``, several separated by ``;``), one
        worker each, that the front's support method (``hddpg-support``) trains beside the per-term workers
        (their config block ``<env>/mix``), in a copy of the seed's workers.
    :param front_start: how the support method's conditioned manager starts: ``gpi`` (it imitates GPI over
        the workers' critics before RL, ``init_from_gpi``; its manager then trains on SB3), or ``None``.
    :param front_critic_steps: the support method fits each worker a critic on this many env steps of its
        rollouts (``fit-critics``: a state value over the full state, or a discrete worker's Q over its
        actions; 0: the workers keep the critics they have).
    :param front_gpi: the front's GPI member over discrete workers: ``actions`` (GPI over actions) or
        ``policies`` (the action of the worker whose critic values its own action most).
    :param morl_python: the python of a virtual environment with MORL-baselines: the front then adds its
        CAPQL, trained for the hierarchy's env steps (:mod:`.morl`; an MO-Gymnasium env only). Records state
        its version instead of its path (:func:`~.machine_paths.settings_record`).
    """

    methods: list[str] = field(default_factory=lambda: list(DEFAULT_METHODS))
    seeds: list[int] = field(default_factory=lambda: list(range(5)))
    timesteps: int = 0
    worker_timesteps: int | None = None
    flat_timesteps: int | None = None
    eval_freq: int | None = None
    eval_episodes: int = 5
    test_episodes: int | None = None
    ham_threshold: float | None = None
    ham_hysteresis: float = 0.0
    bias: float = 0.15
    scenario: str = "standard"
    preferences: list[str] = field(default_factory=list)
    backend: str = "sb3"
    env: EnvChoice | None = None
    workers_from: str | None = None
    final_test: bool = False
    worker_algo: str | None = None
    front_manager: str = "ddpg"
    front_timesteps: int | None = None
    front_sweep: str = "ratio-sweep"
    front_motion: float = 0.0
    front_option_steps: int | None = None
    front_per_preference: bool = True
    front_support: str | None = None
    front_start: str | None = None
    front_critic_steps: int = 0
    front_gpi: str = "actions"
    morl_python: str | None = None

    def __post_init__(self) -> None:
        # Every field's kind first: settings read back from a benchmark.json someone may have edited.
        check_field_types(self, "benchmark settings")
        self._check_methods()
        self._check_front_manager()
        self._check_front_inputs()
        if self.env is not None:
            self._check_env()
        if self.morl_python is not None:
            self._check_morl()
        # The biased managers' factor passes the hierarchy's own rule (finite, and small enough that a
        # weighted reward cannot overflow) before anything trains.
        preferences_from_bias(["a", "b"], "a", self.bias)
        if not 1 <= len(self.seeds) <= MAX_BENCHMARK_SEEDS or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(
                f"Expected distinct seeds, 1 to {MAX_BENCHMARK_SEEDS} of them, actually: {brief(self.seeds)}"
            )
        if not all(0 <= seed <= MAX_SEED for seed in self.seeds):
            raise ValueError(f"Expected seeds in [0, {MAX_SEED}], actually: {brief(self.seeds)}")
        if not self.timesteps:
            self.timesteps = _config_budgets()[MANAGER_KEY]
        if self.test_episodes is None:
            self.test_episodes = FINAL_TEST_EPISODES if self.final_test else DEVELOPMENT_TEST_EPISODES
        self.test_set.seeds(self.test_episodes)  # within the set's block
        for name in ("timesteps", "worker_timesteps", "front_timesteps", "eval_episodes", "test_episodes"):
            value = getattr(self, name)
            if value is not None and value < 1:
                raise ValueError(f"Expected `{name}` >= 1, actually: {getattr(self, name)}")
        self._check_scenario()
        self._check_budgets()

    def _check_budgets(self) -> None:
        """
        Every budget a task trains for, in env steps, and the evaluation settings, within the bounds of the run
        options the tasks build: checked here, a budget too large is refused before anything trains, not by
        the task that reaches it after the seed's workers have trained.
        """
        flat_timesteps = self.flat_timesteps
        if flat_timesteps is None and any(_is_flat(m) for m in self.methods):
            # The workers' config budgets need the env; where its package is missing, its records can still
            # be read, and running it fails in one line.
            with contextlib.suppress(EnvUnavailableError):
                flat_timesteps = self.flat_budget
        budgets = {
            "timesteps": self.manager_env_steps,
            "worker_timesteps": self.worker_timesteps,
            "front_timesteps": self.front_env_steps,
            "flat_timesteps": flat_timesteps,
        }
        for name, steps in budgets.items():
            if steps is not None:
                RUN_SETTINGS["timesteps"].check(steps, f"`{name}` (env steps)")
        RUN_SETTINGS["eval_freq"].check(self.eval_freq or 0, "`eval_freq`")
        RUN_SETTINGS["eval_episodes"].check(self.eval_episodes, "`eval_episodes`")

    def _check_scenario(self) -> None:
        """A known scenario, with its preferences (transfer) or its one method (front)."""
        if self.scenario not in SCENARIOS:
            raise ValueError(f"Unknown scenario {self.scenario!r}; choose from {list(SCENARIOS)}")
        if self.scenario != "transfer" and self.preferences:
            raise ValueError("Preferences apply to the transfer scenario only (scenario='transfer')")
        if self.scenario == "transfer":
            self._check_transfer()
        # The standard scenario may add the front's method to its others, so that one run of record
        # measures every method and every front over the same workers.
        if self.scenario == "front" and not set(self.methods) <= set(FRONT_METHODS):
            raise ValueError(f"The front scenario runs {list(FRONT_METHODS)}, actually: {self.methods}")

    def _check_methods(self) -> None:
        """Known and distinct methods, at least one; the backend, and that it trains each flat method."""
        unknown = [m for m in self.methods if m not in METHOD_REGISTRY]
        if unknown:
            raise ValueError(f"Unknown methods {unknown}; choose from {list(METHOD_REGISTRY)}")
        self.backend = check_backend(self.backend)
        for method in self.methods:
            if _is_flat(method):
                check_algo(FLAT_HER_METHODS.get(method, method), self.backend)
        if self.env is None:
            env_only = [m for m in self.methods if m in ENV_ONLY_METHODS]
            if env_only:
                raise ValueError(f"Methods {env_only} are defined on another env than the snake arm (--env)")
            if self.worker_algo is not None:
                raise ValueError(
                    "`worker_algo` applies to another env (--env); the snake's workers keep their own"
                )
        if len(set(self.methods)) != len(self.methods) or not self.methods:
            raise ValueError(f"Expected distinct methods, at least one, actually: {self.methods}")

    def _check_front_manager(self) -> None:
        """The front's managers: a manager algorithm (written by its registry name), whatever the backend."""
        managers = algorithms_for("manager")
        with contextlib.suppress(ValueError):  # an unknown name is refused below, among the managers
            self.front_manager = algorithm(self.front_manager).name
        if self.front_manager not in managers:
            raise ValueError(
                f"Expected the front's manager among {list(managers)}, actually: {self.front_manager!r}"
            )

    def _check_front_inputs(self) -> None:
        """
        The front's sweep, a ``ratio-sweep`` form (any env's terms take it), its managers' motion scale and
        option steps.
        """
        if self.front_sweep.partition(":")[0] == "ratio-sweep":
            PreferenceSpace.parse(self.front_sweep, ("a", "b"))  # a bad MAX is refused by name
        elif self.front_support is None or "=" not in self.front_sweep:
            raise ValueError(
                "Expected the front's sweep to be ratio-sweep[:MAX], or with --front-support the support's "
                f"preferences (goal=1,avoid=0.5,...;...), actually: {self.front_sweep!r:.60}"
            )
        if self.front_support is not None:
            for part in self.front_support.split(";"):
                parse_term_weights(part)
        if self.front_gpi not in ("actions", "policies"):
            raise ValueError(
                f"Expected the front's GPI to be actions or policies, actually: {self.front_gpi!r:.40}"
            )
        if self.front_start not in (None, "gpi"):
            raise ValueError(
                f"Expected the front's start to be gpi or none, actually: {self.front_start!r:.40}"
            )
        if isinstance(self.front_critic_steps, bool) or not 0 <= self.front_critic_steps <= MAX_CRITIC_STEPS:
            raise ValueError(
                f"Expected the front's critic steps in [0, {MAX_CRITIC_STEPS}], actually: {self.front_critic_steps!r}"
            )
        motion = self.front_motion
        if isinstance(motion, bool) or not isinstance(motion, (int, float)) or not 0 <= motion < math.inf:
            raise ValueError(
                f"Expected the front's motion scale to be a finite number >= 0, actually: {motion!r}"
            )
        self.front_motion = float(motion)
        steps = self.front_option_steps
        if steps is not None and not 1 <= steps <= MAX_OPTION_STEPS:
            raise ValueError(
                f"Expected the front's option steps in [1, {MAX_OPTION_STEPS}], actually: {steps!r}"
            )

    def _check_morl(self) -> None:
        """MORL-baselines' python, for the front on an MO-Gymnasium env."""
        if not any(m in FRONT_METHODS for m in self.methods):
            raise ValueError(f"MORL-baselines' learner is a member of the front ({list(FRONT_METHODS)})")
        shared = self.terms_env
        if shared is None:
            raise ValueError("MORL-baselines' learner runs on an MO-Gymnasium env (--env), not the snake arm")
        mo_gymnasium_env(shared)
        # Its file is checked where the benchmark runs (.machine_paths), not here: settings read from a record
        # state what ran, and the python of the machine that wrote them is not on this one.

    def _check_transfer(self) -> None:
        """The transfer scenario's preferences (written one way) and methods: hddpg and flat agents."""
        self.preferences = [canonical_preference(p) for p in self.preferences]
        if not self.preferences or len(set(self.preferences)) != len(self.preferences):
            raise ValueError(f"Expected distinct preferences, at least one, actually: {self.preferences}")
        fixed = [m for m in self.methods if not METHOD_REGISTRY[m].takes_preference]
        if fixed:
            choices = [m.name for m in METHOD_REGISTRY.values() if m.takes_preference]
            raise ValueError(
                f"Methods {fixed} cannot learn a given preference; the transfer scenario takes {choices}"
            )
        if "hddpg" not in self.methods or len(self.methods) < 2:
            raise ValueError(
                f"The transfer scenario compares hddpg with flat agents, actually: {self.methods}"
            )

    def _check_env(self) -> None:
        """Another env: its spec as plain JSON (so that ``benchmark.json`` resumes), and methods that apply."""
        env: dict[str, object] = dict(self.env) if isinstance(self.env, dict) else {}
        if set(env) != {"env_id", "env_kwargs", "terms"} or not isinstance(env["env_id"], str):
            raise ValueError(
                f"Expected `env` as {{'env_id', 'env_kwargs', 'terms'}}, actually: {str(self.env)[:200]}"
            )
        self.env = json.loads(json.dumps(env))  # tuples become lists, as benchmark.json stores them
        # As the --env option's are: no module prefix (gym.make would import it), kwargs bounded and path-free.
        check_env_kwargs(
            check_env_id(env["env_id"], "env.env_id", trusted=True), env["env_kwargs"], "env", trusted=True
        )
        terms = self.env["terms"]
        if not isinstance(terms, list) or not 1 <= len(terms) <= MAX_TERMS:
            raise ValueError(
                f"Expected `env.terms` to be a list of 1 to {MAX_TERMS} names, actually: {brief(terms)}"
            )
        for term in terms:
            check_name(term, "env.terms")
        snake_only = [m for m in self.methods if m not in ENV_METHODS and m not in FRONT_METHODS]
        if snake_only:
            raise ValueError(
                f"Methods {snake_only} are defined for the snake arm only; on {env['env_id']!r} choose from "
                f"{[*ENV_METHODS, *FRONT_METHODS]}"
            )
        if any(m in FRONT_METHODS for m in self.methods) and len(terms) < 2:
            raise ValueError(f"A front needs at least two terms, actually: {terms}")
        if self.scenario == "transfer":
            raise ValueError("The 'transfer' scenario is defined for the snake arm only")
        if self.worker_algo is not None:
            self.worker_algo = algorithm(self.worker_algo).name
        try:
            discrete = _env_is_discrete(json.dumps(self.env, sort_keys=True))
        except EnvUnavailableError:
            return  # its package is missing here: its records can be read, and running it fails in one line
        space = gym.spaces.Discrete(2) if discrete else gym.spaces.Box(-1, 1)
        # A flat agent or a worker selection by index that cannot act in the env's action space.
        misfits = [
            m
            for m in self.methods
            if (m in FLAT_METHODS and not algorithm(m).takes(space))
            or (not discrete and m in DISCRETE_ONLY_METHODS)
        ]
        if misfits:
            raise ValueError(
                f"Methods {misfits} cannot act in {env['env_id']!r}'s {type(space).__name__} action space"
            )
        if self.worker_algo is not None and self.worker_algo not in algorithms_for("worker", space):
            raise ValueError(
                f"Expected a worker algorithm for {env['env_id']!r}'s {type(space).__name__} actions, "
                f"actually {self.worker_algo!r}; choose from {list(algorithms_for('worker', space))}"
            )

    @property
    def terms_env(self) -> TermsEnv | None:
        """:attr:`env` as the :class:`~sb3_hddpg.envs.terms_env.TermsEnv` the training functions take."""
        if self.env is None:
            return None
        return TermsEnv(self.env["env_id"], dict(self.env["env_kwargs"]), tuple(self.env["terms"]))

    @property
    def worker_algos(self) -> dict[str, str] | None:
        """
        Each worker's algorithm on another env: :attr:`worker_algo`, else DQN on discrete actions and DDPG on
        continuous ones (``None`` on the snake arm: its workers' own).
        """
        if self.env is None:
            return None
        algo = self.worker_algo
        if algo is None:
            algo = "dqn" if _env_is_discrete(json.dumps(self.env, sort_keys=True)) else "ddpg"
        return dict.fromkeys(self.env["terms"], algo)

    @property
    def test_set(self) -> EpisodeSet:
        """The episodes every run is scored on: the final test set with :attr:`final_test`, else development."""
        return FINAL_TEST if self.final_test else DEVELOPMENT

    @property
    def test_episode_set(self) -> dict[str, int | str]:
        """The record of the episodes every run is scored on (what a record and ``results.json`` keep)."""
        return self.test_set.describe(self.test_episodes or 1)

    @property
    def method_keys(self) -> list[str]:
        """The runs of one seed: the methods, or in the transfer scenario each method on each preference."""
        if self.scenario == "transfer":
            return [method_key(m, p) for p in self.preferences for m in self.methods]
        return list(self.methods)

    @property
    def option_steps(self) -> int:
        """Env steps per manager decision (the manager block's ``option_steps``; 1 in the bundled config)."""
        return _manager_option_steps()

    @property
    def manager_env_steps(self) -> int:
        """
        Env steps of a manager's training: ``timesteps`` counts its decisions (SB3's steps of the wrapper),
        each of which runs ``option_steps`` env steps. Equal budgets and curve windows are in env steps.
        """
        return self.timesteps * self.option_steps

    @property
    def front_env_steps(self) -> int:
        """Env steps of each of the front's managers: :attr:`front_timesteps`, else :attr:`manager_env_steps`."""
        return self.front_timesteps if self.front_timesteps is not None else self.manager_env_steps

    @property
    def flat_budget(self) -> int:
        """A flat agent's budget: as many env steps as the hierarchy (workers + manager) by default."""
        if self.flat_timesteps is not None:
            return self.flat_timesteps
        return self.manager_env_steps + self.workers_budget

    @property
    def workers_budget(self) -> int:
        """Env steps of a seed's workers together: ``worker_timesteps`` each, or each worker's config budget."""
        if self.worker_timesteps is not None:  # one worker per term: no config (or env) to read
            return self.worker_timesteps * len(self.env["terms"] if self.env is not None else WORKER_ENV_IDS)
        if self.env is None:
            return sum(budget for name, budget in _config_budgets().items() if name != MANAGER_KEY)
        algo = next(iter((self.worker_algos or {}).values()), None)
        return sum(_env_worker_budgets(json.dumps(self.env, sort_keys=True), algo))

    def eval_freq_for(self, budget: int) -> int:
        """
        Steps between evaluations for a run of ``budget`` steps: the same for every run (default: a tenth
        of the manager's budget), so that all curves have points at the same own steps.
        """
        return min(self.eval_freq if self.eval_freq else max(self.manager_env_steps // 10, 1), budget)

    def option_steps_of(self, algo: str) -> int:
        """Env steps per decision of a manager of algorithm ``algo`` (its bundled manager block's ``option_steps``)."""
        return self.option_steps if algo == "ddpg" else manager_option_steps(algo=algo)

    def manager_run_options(
        self, seed: int, algo: str = "ddpg", env_steps: int | None = None, option_steps: int | None = None
    ) -> RunOptions:
        """
        :meth:`run_options` of a manager: ``timesteps`` decisions (another algorithm's manager: as many
        decisions as make :attr:`manager_env_steps` with its own ``option_steps``), evaluated every
        :meth:`eval_freq_for` env steps converted to decisions, so that its curve points fall at the same
        env steps as the others'. On :attr:`backend` if it trains ``algo``, else on SB3 (a DQN manager in an
        SBX benchmark).

        :param env_steps: another budget than :attr:`manager_env_steps`, in env steps.
        :param option_steps: env steps per decision of another block than the bundled one of ``algo`` (a
            study's pick may change them), so that it gets the same env steps.
        """
        budget = env_steps if env_steps is not None else self.manager_env_steps
        option_steps = option_steps if option_steps is not None else self.option_steps_of(algo)
        decisions = max(budget // option_steps, 1)  # the DDPG manager's: ``timesteps``
        every = max(self.eval_freq_for(budget) // option_steps, 1)
        run = self.run_options(seed, decisions, decisions)
        return run.replace(eval_freq=every, backend=backend_for(algo, self.backend))

    def front_run_options(self, seed: int, start: str | None = None) -> RunOptions:
        """
        :meth:`manager_run_options` of the front's managers: :attr:`front_manager`, :attr:`front_env_steps`;
        with a ``start`` (:attr:`front_start`) on SB3, the only backend a start fits.
        """
        run = self.manager_run_options(
            seed, self.front_manager, self.front_env_steps, option_steps=self.front_option_steps
        )
        return run.replace(backend="sb3") if start is not None else run

    def run_options(self, seed: int, timesteps: int | None, budget: int) -> RunOptions:
        """
        How every training run of the benchmark is run: ``timesteps`` (``None``: the config's) from ``seed``,
        evaluated every :meth:`eval_freq_for` ``budget`` steps, resumed where a checkpoint exists (a task
        re-run after an interruption continues; a finished agent is kept).
        """
        return RunOptions(
            timesteps=timesteps,
            seed=seed,
            resume=True,
            eval_freq=self.eval_freq_for(budget),
            eval_episodes=self.eval_episodes,
            backend=self.backend,
        )
