"""
Preparing the manager: load and check its workers, config block, preferences and selection settings, and
build the factory of its env, before anything trains.
"""

from __future__ import annotations

import contextlib
import inspect
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import gymnasium as gym

from sb3_hddpg.algorithms import algorithms_for
from sb3_hddpg.artifacts.limits import brief
from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.artifacts.records import ModelsManifest
from sb3_hddpg.artifacts.values import check_make_kwargs
from sb3_hddpg.artifacts.workers import Workers, shared_env_of
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.hierarchy.frozen import FrozenWorker
from sb3_hddpg.hierarchy.gpi import gpi_of
from sb3_hddpg.hierarchy.option_end import OptionEnd
from sb3_hddpg.hierarchy.relabeling import PreferenceRelabelingReplayBuffer
from sb3_hddpg.hierarchy.selection import (
    SelectionConfig,
    check_preferences,
    check_selection_settings,
    preferences_from_bias,
)
from sb3_hddpg.hierarchy.wrapper import WorkerSelectionWrapper
from sb3_hddpg.training.agent import make_snake_env
from sb3_hddpg.training.backends import algo_class
from sb3_hddpg.training.config import Hyperparams, manager_hyperparams
from sb3_hddpg.training.imitation_start import START_ALGOS, GpiStart, HamStart, check_ham_workers

#: The algorithms a manager can be (DDPG is the paper's), each with a ``manager`` block in its bundled config;
#: one acting in Discrete spaces (DQN) selects with the ``discrete`` mode, its action the worker's index.
MANAGER_ALGOS = algorithms_for("manager")


@dataclass
class ManagerEnvFactory:
    """
    Builds the manager's env: the shared env wrapped in ``WorkerSelectionWrapper`` over the workers already
    loaded; pickled into a ``SubprocVecEnv`` process it drops them, and that process loads them from
    ``workers_dir`` once (hashes verified).

    :param env_id: the shared env.
    :param env_kwargs: its keyword arguments.
    :param workers_dir: the workers' folder (for processes that must load them themselves).
    :param worker_names: the workers, in the manager's action order.
    :param wrapper_kwargs: the selection settings (``SelectionConfig.wrapper_kwargs()``).
    :param trusted: load the workers with SB3's full loader.
    :param workers: name -> worker already loaded in this process (``None``: load on first use).
    """

    env_id: str
    env_kwargs: dict[str, Any]
    workers_dir: str
    worker_names: Sequence[str]
    wrapper_kwargs: dict[str, Any]
    trusted: bool = False
    workers: Mapping[str, Any] | None = None

    def __call__(self) -> gym.Env:
        if self.workers is None:
            self.workers = load_workers(self.workers_dir, self.worker_names, trusted=self.trusted)
        env = make_snake_env(self.env_id, self.env_kwargs)
        return WorkerSelectionWrapper(env, self.workers, **self.wrapper_kwargs)

    def __getstate__(self) -> dict[str, Any]:
        # Models do not cross process boundaries: the receiving process loads them from the files.
        return {**self.__dict__, "workers": None}


@dataclass
class ManagerSetup:
    """
    Everything :func:`train_manager` needs before training starts, checked: see :func:`prepare_manager`.

    :param workers: the loaded workers, in the manager's action order.
    :param manifest: the workers' manifest.
    :param hyperparams: the manager's config block.
    :param selection: the selection settings, preferences included.
    :param env_id: the shared env the manager acts in.
    :param env_kwargs: its keyword arguments (from the manager's config block).
    :param workers_dir: the workers' folder.
    :param trusted: load the workers with SB3's full loader.
    :param algo: the manager's algorithm, one of :data:`MANAGER_ALGOS`.
    :param start: imitate HAM or GPI before RL (``None``: start from the random initialisation).
    """

    workers: Workers
    manifest: ModelsManifest
    hyperparams: Hyperparams
    selection: SelectionConfig
    env_id: str
    env_kwargs: dict[str, Any]
    workers_dir: str = ""
    trusted: bool = False
    algo: str = "ddpg"
    start: HamStart | GpiStart | None = None

    @property
    def names(self) -> list[str]:
        return list(self.workers)

    def env_factory(self) -> ManagerEnvFactory:
        """The manager's env factory over these (already loaded) workers."""
        return ManagerEnvFactory(
            self.env_id,
            self.env_kwargs,
            self.workers_dir,
            self.names,
            self.selection.wrapper_kwargs(),
            self.trusted,
            self.workers,
        )


@dataclass(frozen=True)
class ManagerOptions:
    """
    What a manager is trained from, besides its workers' folder and the run-control settings.

    Preference factors (paper Section 3.4) multiply each worker's normalised reward term in the manager's
    reward: 1 by default; ``prefer=NAME`` makes that worker's ``1 + bias``; ``preferences`` sets every one.

    :param worker_names: which workers, in the manager's action order (default: all in the manifest).
    :param prefer: a worker to prefer.
    :param bias: the preferred worker's extra factor, > 0 (the paper's 15 %).
    :param preferences: explicit factors, name -> value (over ``prefer``).
    :param selection: a registered selection mode (default: the config's ``wrapper_kwargs``).
    :param option_steps: env steps per manager decision (default: the config's).
    :param temperature: the simplex map's temperature (default: the config's).
    :param floor: the probability floor (default: the config's).
    :param config: a ``zoo_configs`` file; its ``manager`` block is used (default: ``algo``'s bundled one).
    :param trusted: load the workers with SB3's full loader.
    :param env_id: the shared env the manager acts in (default: the workers manifest's ``shared_env``,
        else ``hddpg/SnakeReach-v0``).
    :param env_kwargs: its keyword arguments (default: the manifest's), under the config block's.
    :param algo: the manager's algorithm, one of :data:`MANAGER_ALGOS` (``ddpg`` is the paper's).
    :param manager_preferences: train one manager for every preference of a
        :class:`~sb3_hddpg.hierarchy.conditioning.PreferenceSpace` (``"ratio-sweep[:N]"``,
        ``"dirichlet[:ALPHA]"``, ``"goal=1.6,avoid=0.4;goal=0.4,avoid=1.6"`` or a space): it observes the
        preference, drawn every episode; ``preferences`` is then the one the bundle acts at first.
    :param relabel_fraction: a conditioned off-policy manager's share of replayed steps given another
        preference.
    :param init_from_ham: imitate HAM's choices before RL: HAM's threshold or a
        :class:`~sb3_hddpg.training.imitation_start.HamStart`.
    :param init_from_gpi: imitate GPI over the workers' per-term critics before RL, at each episode's
        preference: ``True`` or a :class:`~sb3_hddpg.training.imitation_start.GpiStart`.
    :param option_end: options that also end by state: ``"distance=0.5"``, ``"touch"``, both
        (``"distance=0.5,touch"``) or an :class:`~sb3_hddpg.hierarchy.option_end.OptionEnd`.
    :param manager_motion: the manager also observes its state's change over the last env step, scaled by
        this factor (0: not; default: the config's).
    :param gamma: the manager's discount per decision, in (0, 1] (default: the config block's).
    """

    worker_names: Sequence[str] | None = None
    prefer: str | None = None
    bias: float = 0.15
    preferences: dict[str, float] | None = None
    selection: str | None = None
    option_steps: int | None = None
    temperature: float | None = None
    floor: float | None = None
    config: str | Path | None = None
    trusted: bool = False
    env_id: str | None = None
    env_kwargs: dict[str, Any] | None = None
    algo: str = "ddpg"
    manager_preferences: str | PreferenceSpace | None = None
    relabel_fraction: float = 0.5
    init_from_ham: float | HamStart | None = None
    init_from_gpi: bool | GpiStart | None = None
    option_end: str | OptionEnd | None = None
    manager_motion: float | None = None
    gamma: float | None = None


#: The arguments of :func:`prepare_manager` after the workers' folder: :class:`ManagerOptions`' fields.
MANAGER_OPTION_NAMES = tuple(option.name for option in fields(ManagerOptions))


def prepare_manager(
    workers_dir: str | Path, options: ManagerOptions | None = None, **option_changes: Any
) -> ManagerSetup:
    """
    Load and check everything the manager is trained from, without training: the workers (hashes
    verified), the config block, the preferences and selection settings, and that every worker fits the
    manager's env. Call it to validate arguments early; ``train_manager`` takes the set-up it returns.

    :param workers_dir: the run folder of ``train-workers`` (or its ``workers`` folder).
    :param options: what the manager is trained from (default: :class:`ManagerOptions`' defaults).
    :param option_changes: :class:`ManagerOptions` fields as keywords, over ``options``' (``None``: keep it).
    :return: the checked set-up; raises ``ValueError`` (or ``FileNotFoundError``) naming the problem.
    """
    return setup_manager(workers_dir, manager_options(options, option_changes, "prepare_manager"))


def manager_options(options: ManagerOptions | None, changes: dict[str, Any], caller: str) -> ManagerOptions:
    """
    ``options`` (default: :class:`ManagerOptions`' defaults) with the fields given as keywords on top; a
    ``None`` keyword keeps the field, and a keyword that is not a field is a ``TypeError`` naming it.

    :param caller: the function's name, for the error.
    """
    unknown = sorted(set(changes) - set(MANAGER_OPTION_NAMES))
    if unknown:
        raise TypeError(f"{caller}() got an unexpected keyword argument {unknown[0]!r}")
    given = {name: value for name, value in changes.items() if value is not None}
    base = options if options is not None else ManagerOptions()
    return replace(base, **given) if given else base


def setup_manager(workers_dir: str | Path, options: ManagerOptions) -> ManagerSetup:
    """
    :func:`prepare_manager` with its arguments as one record.

    :param workers_dir: the run folder of ``train-workers`` (or its ``workers`` folder).
    :param options: what the manager is trained from.
    """
    if isinstance(options.worker_names, str):
        raise ValueError(f"Expected a sequence of worker names, actually the string {options.worker_names!r}")
    algo = options.algo
    if algo not in MANAGER_ALGOS:
        raise ValueError(f"Unknown manager algorithm {algo!r}; choose from {list(MANAGER_ALGOS)}")
    hyperparams = _with_gamma(manager_hyperparams(algo, options.config), options.gamma)
    workers = load_workers(workers_dir, options.worker_names, trusted=options.trusted)
    env_id, given_kwargs = shared_env_of(
        workers.manifest, options.env_id, options.env_kwargs, options.trusted
    )
    wrapper_kwargs, hyperparams = _selection_settings(options, hyperparams, workers)
    try:
        selection_config = SelectionConfig(**wrapper_kwargs)
    except TypeError as error:  # an unknown key in the config's wrapper_kwargs
        raise ValueError(f"Invalid wrapper_kwargs in the manager's config block: {error}") from None
    # Checked as a bundle's are: a value of the wrong type is one line naming it, not a TypeError later.
    check_selection_settings(wrapper_kwargs, list(workers), "the manager block's wrapper_kwargs")
    env_kwargs = check_make_kwargs(env_id, {**given_kwargs, **hyperparams.env_kwargs}, "manager env_kwargs")
    if "observe" in env_kwargs:
        raise ValueError(
            "The manager's env must give the full state (its workers slice it): remove `observe` from the "
            "manager block's env_kwargs; to feed the manager part of the state, set wrapper_kwargs.manager_state"
        )
    _check_workers_fit(workers, selection_config, env_id, env_kwargs)
    return ManagerSetup(
        workers,
        workers.manifest,
        hyperparams,
        selection_config,
        env_id,
        env_kwargs,
        str(Path(workers_dir)),
        options.trusted,
        algo,
        _start(options, workers, algo),
    )


def _selection_settings(
    options: ManagerOptions, hyperparams: Hyperparams, workers: Workers
) -> tuple[dict[str, Any], Hyperparams]:
    """
    The selection settings (``SelectionConfig``'s fields): the config block's ``wrapper_kwargs`` with the
    options given on top, the preference factors, and each worker's slice of the state; and the config
    block, with the relabelling buffer for a conditioned manager.
    """
    names = list(workers)
    wrapper_kwargs = dict(hyperparams.wrapper_kwargs)
    factors = preferences_from_bias(names, options.prefer, options.bias)
    if options.preferences:
        factors = check_preferences(options.preferences, names)
    if options.manager_preferences is not None:
        given = options.manager_preferences
        space = PreferenceSpace.parse(given, names) if isinstance(given, str) else given
        if list(space.names) != names:
            raise ValueError(f"The preference space names workers {list(space.names)}, the manager {names}")
        wrapper_kwargs["manager_preferences"] = space.to_json()
        factors = space.check(options.preferences or space.default)
        hyperparams = _with_preference_relabeling(
            hyperparams, options.algo, names, space, options.relabel_fraction
        )
    for key in ("selection", "option_steps", "temperature", "floor", "manager_motion"):
        value = getattr(options, key)
        if value is not None:
            wrapper_kwargs[key] = value
    wrapper_kwargs["preferences"] = factors
    if options.option_end is not None:  # else the config block's
        end = options.option_end
        wrapper_kwargs["option_end"] = (OptionEnd.parse(end) if isinstance(end, str) else end).to_json()
    # A worker trained on part of the state (env_kwargs `observe`) is fed the same components of the
    # manager's full state; a worker_states entry in the config block wins.
    configured = wrapper_kwargs.get("worker_states") or {}
    if not isinstance(configured, dict):
        raise ValueError(
            f"Expected wrapper_kwargs.worker_states to map worker names to component lists, actually: {configured!r:.200}"
        )
    wrapper_kwargs["worker_states"] = {**workers.states, **configured}
    return wrapper_kwargs, hyperparams


def _check_workers_fit(
    workers: Workers, selection_config: SelectionConfig, env_id: str, env_kwargs: dict[str, Any]
) -> None:
    """
    Check that every worker fits the manager's env: its observation shape, unless the selection settings
    slice the state for it, and the wrapper's own checks, run once here rather than inside env subprocesses.
    """
    with contextlib.closing(make_snake_env(env_id, env_kwargs)) as probe:
        expected = probe.observation_space.shape
        for name, worker in workers.items():
            space = getattr(worker, "observation_space", None)
            sliced = name in selection_config.worker_states  # the wrapper checks the sliced shape itself
            if space is not None and not sliced and space.shape != expected:
                trained_on = brief(workers.manifest.entries[name].get("env_kwargs", {}))
                raise ValueError(
                    f"Worker {name!r} was trained on observations of shape {space.shape} (env_kwargs "
                    f"{trained_on}), but the manager's env {env_id} with env_kwargs {env_kwargs} gives "
                    f"{expected}: give the manager's config block the workers' env_kwargs"
                )
        WorkerSelectionWrapper(probe, workers, **selection_config.wrapper_kwargs())


def _start(options: ManagerOptions, workers: Workers, algo: str) -> HamStart | GpiStart | None:
    """
    The manager's start, checked: HAM switches between workers named ``goal`` and ``avoid``; GPI needs a
    per-term critic for every worker.
    """
    ham, gpi = options.init_from_ham, options.init_from_gpi
    if ham is None and not gpi:
        return None
    if ham is not None and gpi:
        raise ValueError("Start the manager from HAM or from GPI, not both")
    if algo not in START_ALGOS:
        raise ValueError(f"A manager's start fits managers of {list(START_ALGOS)}, not {algo!r}")
    if gpi:
        # GPI's own checks (a critic for every worker, of one kind and discount), before anything trains
        gpi_of([FrozenWorker(model) for model in workers.values()], workers.critics, list(workers))
        return gpi if isinstance(gpi, GpiStart) else GpiStart()
    check_ham_workers(list(workers))
    return ham if isinstance(ham, HamStart) else HamStart(float(ham or 0.0))


def _with_gamma(hyperparams: Hyperparams, gamma: float | None) -> Hyperparams:
    """The manager's config block with ``gamma`` as its discount (``None``: as it is), ``raw`` as written."""
    if gamma is None:
        return hyperparams
    if isinstance(gamma, bool) or not isinstance(gamma, (int, float)) or not 0.0 < gamma <= 1.0:
        raise ValueError(f"Expected the manager's gamma in (0, 1], actually: {gamma!r:.60}")
    return replace(hyperparams, algo_kwargs={**hyperparams.algo_kwargs, "gamma": float(gamma)})


def _with_preference_relabeling(
    hyperparams: Hyperparams, algo: str, names: list[str], space: PreferenceSpace, relabel_fraction: float
) -> Hyperparams:
    """The manager's config block with the preference-relabelling replay buffer, for an algorithm with one."""
    if "replay_buffer_class" not in inspect.signature(algo_class(algo).__init__).parameters:
        return hyperparams
    if hyperparams.algo_kwargs.get("replay_buffer_class") is not None:
        raise ValueError(
            "A conditioned manager replays its steps with PreferenceRelabelingReplayBuffer: remove "
            "replay_buffer_class from the manager's config block"
        )
    if not 0.0 <= relabel_fraction <= 1.0:
        raise ValueError(f"Expected the relabel fraction in [0, 1], actually: {relabel_fraction}")
    kwargs = {
        **hyperparams.algo_kwargs,
        "replay_buffer_class": PreferenceRelabelingReplayBuffer,
        "replay_buffer_kwargs": {
            "names": names,
            "space": space.to_json(),
            "relabel_fraction": relabel_fraction,
        },
    }
    return replace(hyperparams, algo_kwargs=kwargs)
