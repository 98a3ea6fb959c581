"""What a study tunes: the level, its base config block, each trial's budget and the env its trials use."""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym

from hddpg_zoo.hyperparams_opt import (
    SampledBlock,
    Trial,
    base_params,
    sampler_for,
    tunable_algorithms,
)
from sb3_hddpg.algorithms import ROLES
from sb3_hddpg.artifacts.limits import LimitError, check_count
from sb3_hddpg.artifacts.manifests import load_workers, read_workers_manifest
from sb3_hddpg.artifacts.records import ModelsManifest
from sb3_hddpg.artifacts.workers import observed_components, shared_env_of
from sb3_hddpg.baselines.ham import DEFAULT_MARGIN, HAMSwitch
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID, WORKER_ENV_IDS
from sb3_hddpg.envs.terms_env import TermsEnv, make_term_view
from sb3_hddpg.episode_sets import CURVE, TUNING
from sb3_hddpg.hierarchy.hierarchy import SelectionConfig
from sb3_hddpg.policy import Policy
from sb3_hddpg.training.agent import make_snake_env
from sb3_hddpg.training.backends import algo_class
from sb3_hddpg.training.config import (
    DEFAULT_CONFIG,
    MANAGER_KEY,
    Hyperparams,
    default_config,
    load_config_file,
    parse_block,
    select_block,
)
from sb3_hddpg.training.manager_setup import ManagerEnvFactory

#: What can be tuned.
LEVELS = ("worker", "manager", "flat", "ham")
#: The state component HAM's switch rule reads (the snake's per-link obstacle clearances).
HAM_COMPONENT = "joint_obstacle_distances"


def check_budget_fraction(fraction: float | None, final_budget: int | None, timesteps: int | None) -> None:
    """
    A trial budget given as a share: ``fraction`` in (0, 1] of a ``final_budget`` >= 1, and not with
    ``timesteps`` too (nothing to check without ``fraction``).

    :raises ValueError: naming the field, the expected and the actual value.
    """
    if fraction is None:
        return
    if not 0 < fraction <= 1:
        raise ValueError(f"Expected budget_fraction in (0, 1], actually: {fraction!r}")
    if final_budget is None or final_budget < 1:
        raise ValueError(
            f"Expected final_budget >= 1 env steps with budget_fraction, actually: {final_budget!r}"
        )
    if timesteps is not None:
        raise ValueError(
            f"Expected timesteps or budget_fraction, not both; actually: {timesteps} and {fraction}"
        )


class TargetError(ValueError):
    """
    A :class:`TuningTarget` that cannot be tuned, naming the field at fault (so that a front end can name
    its own option for it).

    :param field: the field at fault.
    :param message: what is wrong, and what was expected.
    """

    def __init__(self, field: str, message: str) -> None:
        super().__init__(message)
        self.field = field


@dataclass(frozen=True)
class TuningTarget:
    """
    What a study tunes, and how each trial is trained and evaluated. Picklable, so that every trial
    process rebuilds the same objective.

    :param level: ``worker``, ``manager``, ``flat`` or ``ham``.
    :param worker: the worker to tune (``goal`` or ``avoid``; level ``worker`` only).
    :param workers_dir: a ``train-workers`` run folder (levels ``manager`` and ``ham``).
    :param config: the base ``zoo_configs`` file whose block the sampled values override (default: the
        bundled one); its other keys (``learning_starts``, ``env_kwargs``...) are kept.
    :param timesteps: training steps per trial (default: ``budget_fraction`` of ``final_budget``, else the
        base block's ``n_timesteps``).
    :param budget_fraction: each trial's env steps as this share of ``final_budget``, the method's budget in
        the benchmark, so that every method's study spends the same share of what it finally trains with.
    :param final_budget: the method's final budget in env steps (needed with ``budget_fraction``).
    :param block: level ``flat`` only: another block of the base config to tune instead of the env's, e.g.
        ``flat-her`` (the benchmark's ``sac-her`` / ``ddpg-her``: the goal worker's tricks on the reach task).
    :param episode_set: the episodes every trial is evaluated on (:mod:`sb3_hddpg.episode_sets`): the tuning
        set, disjoint from the curve episodes the benchmark picks checkpoints on and from every test set;
        ``curve`` resumes a study made before studies had their own episodes.
    :param n_evaluations: evaluations per trial, evenly spread, each reported to the pruner.
    :param eval_episodes: episodes per evaluation.
    :param seed: the training seed of every trial (the same for all, so trials differ only by their
        hyperparameters).
    :param n_seeds: training seeds per trial, ``seed``, ``seed + 1``...: a trial's value is the mean over
        them of each run's last evaluation (its ``peak`` score the mean of each run's best), so that a
        configuration is ranked on what it does across seeds rather than on one seed's luck. Each costs
        the trial budget again.
    :param algo: the algorithm (levels ``worker``, ``flat`` and ``manager``: one whose record plays the role,
        each with its own search space and bundled base config ``zoo_configs/<algo>.yml``).
    :param backend: the trials' training backend, ``sb3`` or ``sbx`` (``None``: the base block's
        ``backend`` key, else ``sb3``).
    :param env: another env with several objectives (:func:`~sb3_hddpg.envs.terms_env.terms_env`, the
        same as ``train-workers --env``; ``None``: the snake arm). Level ``worker`` tunes the worker of one
        of its terms on that term's view, ``flat`` a flat agent on its shared env; level ``manager`` acts in
        it instead of the shared env recorded in the workers' manifest (which is the default, as in
        ``train-manager``).
    """

    level: str
    worker: str | None = None
    workers_dir: str | None = None
    config: str | None = None
    timesteps: int | None = None
    n_evaluations: int = 5
    eval_episodes: int = 5
    seed: int = 0
    algo: str = "ddpg"
    backend: str | None = None
    env: TermsEnv | None = None
    n_seeds: int = 1
    budget_fraction: float | None = None
    final_budget: int | None = None
    episode_set: str = TUNING.name
    block: str | None = None

    def __post_init__(self) -> None:
        self._check_level()
        try:
            check_budget_fraction(self.budget_fraction, self.final_budget, self.timesteps)
        except ValueError as error:
            raise TargetError("budget_fraction", str(error)) from None
        if self.episode_set not in (TUNING.name, CURVE.name):
            raise TargetError(
                "episode_set", f"Expected episode_set 'tuning' or 'curve', actually: {self.episode_set!r}"
            )
        for field_name, count in (("n_evaluations", "evaluations"), ("eval_episodes", "episodes")):
            try:  # the one table of counts, as the CLI's options
                check_count(count, getattr(self, field_name), field_name)
            except LimitError as error:
                raise TargetError(field_name, str(error)) from None
        if self.timesteps is not None and self.timesteps < self.n_evaluations:
            raise TargetError(
                "timesteps",
                f"Expected timesteps >= n_evaluations ({self.n_evaluations}), actually: {self.timesteps}",
            )

    def _check_level(self) -> None:
        """The level and the fields that depend on it."""
        if self.level not in LEVELS:
            raise TargetError("level", f"Unknown level {self.level!r}; choose from {list(LEVELS)}")
        if isinstance(self.n_seeds, bool) or not isinstance(self.n_seeds, int) or self.n_seeds < 1:
            raise TargetError(
                "n_seeds", f"Expected n_seeds to be an integer >= 1, actually: {self.n_seeds!r}"
            )
        if self.level == "ham" and self.n_seeds != 1:
            raise TargetError(
                "n_seeds", "Level 'ham' trains nothing: its trials have no seed to repeat (n_seeds 1)"
            )
        if self.level == "ham" and self.env is not None:
            raise TargetError(
                "env",
                "HAM's switch rule is defined for the snake arm only (it reads its obstacle clearances)",
            )
        if self.algo != "ddpg" and self.level not in ROLES:
            raise TargetError(
                "algo", f"An algorithm applies to levels {', '.join(ROLES)}, not {self.level!r}"
            )
        if self.level in ROLES and self.algo not in tunable_algorithms(self.level):
            raise TargetError(
                "algo",
                f"Expected an algorithm among {list(tunable_algorithms(self.level))}, got {self.algo!r}",
            )
        sampler_for(self.level, self.algo)
        if self.level == "worker" and self.worker not in self.worker_names:
            raise TargetError(
                "worker", f"Level 'worker' needs a worker among {self.worker_names}, got {self.worker!r}"
            )
        if self.level != "worker" and self.worker is not None:
            raise TargetError("worker", f"A worker name only applies to level 'worker', not {self.level!r}")
        if self.level in ("manager", "ham") and not self.workers_dir:
            raise TargetError(
                "workers_dir", f"Level {self.level!r} needs the run folder of train-workers (workers_dir)"
            )
        if self.block is not None and self.level != "flat":
            raise TargetError(
                "block", f"Expected block only with level 'flat', actually: level {self.level!r}"
            )

    @property
    def worker_names(self) -> list[str]:
        """The workers level ``worker`` can tune: :attr:`env`'s terms, else the snake arm's."""
        return list(self.env.terms) if self.env is not None else sorted(WORKER_ENV_IDS)

    @property
    def name(self) -> str:
        """
        A short name: ``worker-goal``, ``manager`` (``manager-sac``...), ``flat`` (``flat-td3``...) or ``ham``
        (the default study name).
        """
        if self.level == "worker":
            return f"worker-{self.worker}"
        return f"{self.level}-{self.algo}" if self.algo != "ddpg" else self.level

    @property
    def block_keys(self) -> tuple[str, ...]:
        """
        The ``zoo_configs`` keys the tuned agent's block is read from, most specific first, as the training
        commands read them (empty for HAM, which has none): a worker on another env has a block of its own,
        ``<env id>/<term>``, over the env's.
        """
        if self.block is not None:
            return (self.block,)
        if self.level == "worker" and self.env is not None:
            return self.env.worker_config_keys(str(self.worker))
        if self.level == "flat" and self.env is not None:
            return (self.env.config_key,)
        if self.level == "worker":
            return (WORKER_ENV_IDS[str(self.worker)],)
        key = {"manager": MANAGER_KEY, "flat": SNAKE_REACH_ENV_ID}.get(self.level)
        return (key,) if key is not None else ()

    @property
    def block_key(self) -> str | None:
        """The ``zoo_configs`` key the tuned block is saved under (``None`` for HAM, which has none)."""
        return self.block_keys[0] if self.block_keys else None

    @property
    def config_path(self) -> Path:
        """The base config file (default: the bundled one of the algorithm)."""
        if self.config:
            return Path(self.config)
        return default_config(self.algo) if self.algo != "ddpg" else DEFAULT_CONFIG

    @property
    def algo_class(self) -> type:
        """The SB3 class of :attr:`algo`."""

        return algo_class(self.algo)

    def sampler(self, trial: Trial) -> SampledBlock:
        """The changes to the base block a trial samples (:func:`~hddpg_zoo.hyperparams_opt.sampler_for`)."""
        return sampler_for(self.level, self.algo)(trial)

    def base_block(self) -> dict[str, Any]:
        """The base config's block for :attr:`block_keys` (empty for HAM)."""
        if not self.block_keys:
            return {}
        return select_block(load_config_file(self.config_path), self.block_keys, source=str(self.config_path))

    def check(self) -> None:
        """
        Fail before any study or trial exists if a trial could not even start: the base config's block must
        parse, and for the levels over workers, the workers must load (hashes verified) and fit the env.
        Otherwise every trial would fail the same way, one after another.
        """
        hyperparams = None
        # RL Zoo falls back to the `default` block for a key it lacks: a named block must be there.
        if self.block is not None and self.block not in load_config_file(self.config_path):
            raise ValueError(
                f"Expected block {self.block!r} in {str(self.config_path)!r}, actually: no such block"
            )
        if self.block_key is not None:
            hyperparams = parse_block(
                dict(self.base_block(), n_envs=1),
                self.algo_class,
                source=f"{self.config_path}[{self.block_key}]",
                manager=self.level == "manager",
            )
        if self.level == "manager" and hyperparams is not None:  # a manager always has its block
            trial_env_factory(self, hyperparams)().close()
        elif self.level == "ham":
            workers = load_workers(str(self.workers_dir))
            manifest = workers.manifest
            env = ham_env(self, manifest)
            try:
                make_ham(workers, env, _ham_default_threshold(env), manifest)
            finally:
                env.close()
        elif self.level == "worker" and self.env is not None and hyperparams is not None:
            trial_env_factory(
                self, hyperparams
            )().close()  # e.g. block env_kwargs the env does not take fail here

    def base_params(self) -> tuple[dict[str, object], list[str]]:
        """
        The base config's values as the sampler's parameters (:func:`~hddpg_zoo.hyperparams_opt.base_params`;
        for HAM its default threshold), and the names it cannot reproduce: a new study's first trial.
        """
        threshold = None
        if self.level == "ham":
            env = ham_env(self, workers_manifest(str(self.workers_dir)))
            try:
                threshold = _ham_default_threshold(env)
            finally:
                env.close()
        return base_params(self.level, self.base_block(), self.algo, threshold)

    def budget(self) -> int:
        """Training env steps per trial (a manager's decisions are this divided by its ``option_steps``)."""
        if self.timesteps is not None:
            return int(self.timesteps)
        if self.budget_fraction is not None and self.final_budget is not None:
            return max(self.n_evaluations, round(self.budget_fraction * self.final_budget))
        return int(self.base_block().get("n_timesteps", 0)) or 1

    def describe(self) -> dict[str, object]:
        """What makes trials comparable, stored in the study so that a mismatching re-run is refused."""
        described: dict[str, object] = {
            "level": self.level,
            "worker": self.worker,
            "timesteps": self.budget() if self.level != "ham" else None,
            "n_evaluations": self.n_evaluations if self.level != "ham" else 1,
            "eval_episodes": self.eval_episodes,
        }
        if self.n_seeds != 1:  # only when not 1: studies made before n_seeds stay resumable
            described["n_seeds"] = self.n_seeds
        if (
            self.episode_set != CURVE.name
        ):  # studies made before studies had their own episodes stay resumable
            described["episode_set"] = self.episode_set
        if self.block is not None:  # only when given: studies of the env's block stay resumable
            described["block"] = self.block
        if self.budget_fraction is not None:  # only when given: studies made before stay resumable
            described["budget_fraction"] = self.budget_fraction
            described["final_budget"] = self.final_budget
        if self.algo != "ddpg":  # DDPG studies made before other algorithms were tunable stay resumable
            described["algo"] = self.algo
        if self.env is not None:  # only when given: snake studies made before --env stay resumable
            described["env"] = {"env_id": self.env.env_id, "env_kwargs": self.env.env_kwargs}
        # Only when not the default: studies made before the backend choice (all SB3) stay resumable.
        if self.level != "ham" and (self.backend or self.base_block().get("backend")) == "sbx":
            described["backend"] = "sbx"
        return described


def merge_block(base: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    """``base`` updated by ``changes``; ``wrapper_kwargs`` are merged key by key, ``noise_std`` dropped without noise."""
    block = copy.deepcopy(base)
    for key, value in changes.items():
        if key == "wrapper_kwargs":
            block[key] = {**(block.get(key) or {}), **value}
        else:
            block[key] = value
    if "noise_type" in block and block["noise_type"] is None:
        block.pop("noise_std", None)  # meaningless without noise; a reader would wonder which applies
    return block


def trial_env_factory(target: TuningTarget, hyperparams: Hyperparams) -> Callable[[], gym.Env]:
    """A picklable factory of the training env of ``target``, as the ``train-*`` commands build it."""
    env = target.env
    if target.level == "worker":
        if env is None:
            # The worker is one of the snake arm's (checked when the target was built).
            return functools.partial(
                make_snake_env, WORKER_ENV_IDS[str(target.worker)], dict(hyperparams.env_kwargs)
            )
        # As train_workers builds a worker's env: the term's view, the block's env_kwargs on top.
        env_id, view_kwargs = env.term_view(str(target.worker))
        return functools.partial(
            make_term_view, env_id, {**view_kwargs, **hyperparams.env_kwargs}, str(target.worker)
        )
    if target.level == "flat":
        # As train_flat builds it: the block's env_kwargs, the chosen env's on top.
        env_id, env_kwargs = (env.env_id, env.env_kwargs) if env is not None else (SNAKE_REACH_ENV_ID, {})
        return functools.partial(make_snake_env, env_id, {**hyperparams.env_kwargs, **env_kwargs})

    manifest = workers_manifest(str(target.workers_dir))
    # As prepare_manager: --env, else the manifest's shared env (safe-loading checks), the block's kwargs on top.
    env_id, env_kwargs = _shared_env(target, manifest)
    names = list(manifest["workers"])
    wrapper = dict(hyperparams.wrapper_kwargs)
    # Each worker sees the state components it was trained on, as train-manager feeds it.
    wrapper["worker_states"] = {
        **observed_components(manifest, names),
        **(wrapper.get("worker_states") or {}),
    }
    selection = SelectionConfig(preferences=dict.fromkeys(names, 1.0), **wrapper)
    return ManagerEnvFactory(
        env_id,
        {**env_kwargs, **hyperparams.env_kwargs},
        str(target.workers_dir),
        names,
        selection.wrapper_kwargs(),
    )


def _shared_env(target: TuningTarget, manifest: ModelsManifest) -> tuple[str, dict[str, Any]]:
    """The env a manager (or HAM) over the manifest's workers acts in, chosen as train-manager does."""
    env = target.env
    return shared_env_of(manifest, env.env_id if env else None, env.env_kwargs if env else None)


def _worker_names(workers_dir: str) -> list[str]:
    return list(workers_manifest(workers_dir)["workers"])


def workers_manifest(workers_dir: str) -> ModelsManifest:
    folder = Path(workers_dir)
    manifest = folder / "workers" / "manifest.json"
    if not manifest.exists():
        manifest = folder / "manifest.json"
    if not manifest.exists():
        raise FileNotFoundError(f"No workers manifest in {workers_dir!r}; run train-workers first")

    return read_workers_manifest(manifest)


def ham_env(target: TuningTarget, manifest: ModelsManifest) -> gym.Env:
    """
    The env HAM is evaluated in (as the manager's: ``--env``, else the manifest's shared env), refused
    with one line unless its state layout declares the component HAM's switch rule reads.
    """
    env_id, env_kwargs = _shared_env(target, manifest)
    env = make_snake_env(env_id, env_kwargs)
    if HAM_COMPONENT not in state_layout_of(env):
        env.close()
        raise ValueError(
            f"HAM's switch rule reads the state component {HAM_COMPONENT!r} (the snake arm's obstacle "
            f"clearances), which {env_id!r} does not declare: tune HAM on the snake arm only"
        )
    return env


def _ham_default_threshold(env: gym.Env) -> float:
    """HAM's default threshold in ``env``: the number of links minus the default margin."""
    return float(len(state_layout_of(env).indices([HAM_COMPONENT]))) - DEFAULT_MARGIN


def make_ham(
    workers: Mapping[str, Policy], env: gym.Env, threshold: float, manifest: ModelsManifest
) -> HAMSwitch:
    """The HAM switch over the goal and avoid workers, each fed the state components it was trained on."""
    return HAMSwitch(
        workers["goal"],
        workers["avoid"],
        state_layout_of(env),
        threshold=threshold,
        worker_states=observed_components(manifest, list(workers)),
    )
