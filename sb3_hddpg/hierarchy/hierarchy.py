"""
``Hierarchy``: a trained manager with its workers, as one verifiable bundle that acts like an SB3 model.

A bundle (``hierarchy.zip``) holds ``manager.zip``, one member per worker (an SB3 zip, or a nested
bundle), and ``manifest.json``: schema version, env id and kwargs, worker names with their reward
terms and bounds, preferences, selection mode, temperature and floor, option steps, state selections,
library versions, each SB3 model's rebuild spec, and the sha256 of every member.
:meth:`Hierarchy.load` verifies every hash before using anything, and by default rebuilds each model from
the manifest's JSON spec and loads only its tensors (``weights_only=True``): opening someone else's
bundle runs none of their code. ``trusted=True`` uses SB3's full loader instead.

A loaded ``Hierarchy`` is a valid worker of a higher :class:`~sb3_hddpg.hierarchy.wrapper.WorkerSelectionWrapper`
(paper design specification 3), and such a two-level hierarchy saves and loads as one bundle.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm

from sb3_hddpg.artifacts.io import atomic_write
from sb3_hddpg.artifacts.limits import (
    LoadBudget,
    brief,
    check_env_id,
)
from sb3_hddpg.artifacts.provenance import library_versions, sha256_bytes
from sb3_hddpg.artifacts.records import bundle_manifest
from sb3_hddpg.artifacts.safe_load import load_model
from sb3_hddpg.artifacts.spec import model_spec
from sb3_hddpg.artifacts.values import check_env_kwargs
from sb3_hddpg.artifacts.workers import Workers, states_of
from sb3_hddpg.envs.contract import mix_terms, state_layout_of
from sb3_hddpg.envs.headless import HeadlessRenderingError, rendering_errors
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.envs.layout import StateLayout
from sb3_hddpg.hierarchy.bundle import MANIFEST, BundleError, model_bytes, read_bundle, write_bundle
from sb3_hddpg.hierarchy.conditioning import WRITTEN_SLACK, PreferenceOutsideError, PreferenceSpace
from sb3_hddpg.hierarchy.frozen import FrozenWorker
from sb3_hddpg.hierarchy.manager_input import ManagerInput, subset_space
from sb3_hddpg.hierarchy.selection import (
    OptionEnd,
    SelectionConfig,
    SimplexMap,
    check_preferences,
    check_selection_settings,
    get_selector,
)
from sb3_hddpg.hierarchy.wrapper import WorkerSelectionWrapper
from sb3_hddpg.policy import Policy

#: The shared env of a hierarchy when neither ``env_id`` is given nor the models' training envs tell.
DEFAULT_ENV_ID = SNAKE_REACH_ENV_ID


class Hierarchy:
    """
    A manager and its workers, acting like an SB3 model: ``predict(obs, deterministic=True)`` returns the
    action of the worker the manager selects (single or batched observations).

    Example, over workers from :func:`~sb3_hddpg.artifacts.manifests.load_workers` and a manager of your own::

        hierarchy = Hierarchy(manager, workers)
        hierarchy.save("my-hierarchy.zip")
        evaluate(Hierarchy.load("my-hierarchy.zip"), n_episodes=5)

    :param manager: the manager's SB3 model (trained on ``WorkerSelectionWrapper``).
    :param workers: name -> worker, in the manager's action order; workers from ``load_workers`` also give
        each worker's state components, the shared env and the facts the bundle keeps about them.
    :param config: the selection settings the manager was trained with (default: those of the
        ``WorkerSelectionWrapper`` the manager still has as its env, else the wrapper's defaults with the
        state components the workers carry).
    :param env_id: the registered id of the shared env (default: the env the manager was trained on, else
        the one every worker was trained on, else the workers' shared env, else ``hddpg/SnakeReach-v0``; see
        :func:`infer_env`).
    :param env_kwargs: its keyword arguments (default: those of the inferred env; ``{}`` with ``env_id``).
    :param worker_meta: name -> JSON-able facts about each worker (reward bounds, metrics...; default: from
        the workers' manifest, for workers from ``load_workers``).
    :param metadata: JSON-able facts about the manager (metrics, seed, config...).
    """

    def __init__(
        self,
        manager: BaseAlgorithm,
        workers: Mapping[str, Policy],
        config: SelectionConfig | None = None,
        env_id: str | None = None,
        env_kwargs: dict[str, Any] | None = None,
        worker_meta: dict[str, dict[str, Any]] | None = None,
        metadata: dict[str, Any] | None = None,
    ) -> None:
        self.manager = manager
        self.workers = dict(workers)
        self.names = list(self.workers)
        config = _selection_config(manager, workers, config)
        self.config = config
        if env_id is None:
            # Without an env id the bundle would record the snake env whatever the models were trained on,
            # and fail only much later (in evaluate); the models' own training envs say which env it is.
            shared = _shared_env(workers)
            env_id, inferred_kwargs = infer_env(manager, self.workers) or shared or (DEFAULT_ENV_ID, {})
            env_kwargs = inferred_kwargs if env_kwargs is None else env_kwargs
        self.env_id = env_id
        self.env_kwargs = dict(env_kwargs or {})
        if worker_meta is None and isinstance(workers, Workers):
            worker_meta = workers.bundle_meta()
        self.worker_meta = dict(worker_meta or {})
        self.metadata = dict(metadata or {})
        with (
            rendering_errors()
        ):  # MuJoCo's OpenGL may fail on import: a problem of this machine, not the bundle
            probe = gym.make(env_id, **self.env_kwargs)
        # Absent a declared layout the whole observation is one component: naming any other is refused
        # by StateLayout.indices with the known names.
        layout = state_layout_of(probe)
        self.observation_space = probe.observation_space
        self.action_space = probe.action_space
        probe.close()
        check_spaces(
            manager, self.workers, config, self.observation_space, self.action_space, layout, self._env_name()
        )
        self._frozen = [
            FrozenWorker(w, layout.indices(config.worker_states[n]) if n in config.worker_states else None)
            for n, w in self.workers.items()
        ]
        #: The preferences a conditioned manager was trained over (``None``: a manager for one preference).
        self.preference_space = (
            PreferenceSpace.from_json(config.manager_preferences, self.names)
            if config.manager_preferences is not None
            else None
        )
        self._preference_obs: np.ndarray | None = None
        if self.preference_space is not None:
            self.config = config = replace(
                config, preferences=self.preference_space.check(config.preferences)
            )
            self._preference_obs = self.preference_space.weights(config.preferences).astype(np.float32)
        self._manager_input = manager_input_of(config, self.observation_space, layout, len(self.names))
        # The manager's input is built here (its state, motion and weights), so its frozen copy sees it all.
        self._manager = FrozenWorker(manager)
        #: The last observation ``predict`` saw in this episode (a manager that observes motion needs it).
        self._previous_obs: np.ndarray | None = None
        self.simplex = SimplexMap(len(self.names), temperature=config.temperature, floor=config.floor)
        self._selector = get_selector(config.selection)
        self._rng = np.random.default_rng(0)
        self._option_left = 0
        self._band = OptionEnd.from_json(config.option_end).bind(layout) if config.option_end else None
        self._option_band: tuple[int, bool] | None = None
        self._option_choice = 0
        self._option_probabilities = np.full(len(self.names), 1.0 / len(self.names))
        self.last_selection: str | None = None
        #: Whether the last ``predict`` made a new decision (``False`` inside an option).
        self.last_decided = False
        #: The manager actor's output at the last decision (in [-1, 1]; how saturated the manager is).
        self.last_manager_action: np.ndarray | None = None
        self.last_probabilities: dict[str, float] = {}

    def make_env(self, **overrides: object) -> gym.Env:
        """
        The shared env this hierarchy acts in: ``gym.make(env_id, **env_kwargs)``.

        :param overrides: keyword arguments over ``env_kwargs`` (e.g. ``render_mode="rgb_array"``).
        """
        return gym.make(self.env_id, **{**self.env_kwargs, **overrides})

    def _env_name(self) -> str:
        return f"{self.env_id!r}" + (f" with env_kwargs {self.env_kwargs}" if self.env_kwargs else "")

    # ------------------------------------------------------------------ acting
    @property
    def reward_spec(self) -> dict[str, float]:
        """This hierarchy's reward as a worker one level up: its preference-weighted mix of its workers' terms."""
        specs = {name: self.config.reward_terms.get(name, name) for name in self.names}
        return mix_terms(specs, self.config.preferences)

    @property
    def preferences(self) -> dict[str, float]:
        """The preference the hierarchy acts at (worker name -> factor)."""
        return dict(self.config.preferences)

    def set_preference(self, preferences: Mapping[str, float] | None = None, **factors: float) -> None:
        """
        Tell a preference-conditioned manager the trade-off to act at, e.g.
        ``hierarchy.set_preference(goal=0.4, avoid=1.6)`` or ``hierarchy.set_preference({"goal": 0.4})``.
        Only the ratio matters (the factors are rescaled to the sum the manager was trained with); names not
        given get the unweighted factor.

        :param preferences: worker name -> factor; or give the factors as keywords.
        :raises PreferenceOutsideError: for a preference outside those the manager was trained over (see
            ``manager_preferences`` in the bundle's manifest), or any other than its own for a manager
            trained for one preference.
        """
        given = {**dict(preferences or {}), **factors}
        if self.preference_space is None:
            own = self.config.preferences
            checked = check_preferences(given, self.names)
            ratio = np.array([checked[n] for n in self.names]) / sum(checked.values())
            trained = np.array([own[n] for n in self.names]) / sum(own.values())
            if not np.allclose(ratio, trained, rtol=0.0, atol=WRITTEN_SLACK):
                shown = ",".join(f"{n}={own[n]:g}" for n in self.names)
                raise PreferenceOutsideError(
                    f"This manager was trained for the preference {shown} only; train a conditioned manager "
                    "(train-manager --preferences ratio-sweep) to choose the preference at run time"
                )
            return
        checked = self.preference_space.check(given)
        self.config = replace(self.config, preferences=checked)
        self._preference_obs = self.preference_space.weights(checked).astype(np.float32)
        self._option_left = 0

    def _manager_obs(self, obs: np.ndarray, previous: np.ndarray | None = None) -> np.ndarray:
        """The manager's input for ``obs`` (one or a batch), ``previous`` the state one env step earlier."""
        return self._manager_input(obs, previous, self._preference_obs)

    def reset_episode(self) -> None:
        """Forget the current option and the last observation (call at an episode start)."""
        self._option_left = 0
        self._previous_obs = None
        for worker in self._frozen:
            worker.reset_episode()

    def seed(self, seed: int) -> None:
        """Seed the generator used to sample workers in stochastic prediction and to break exact ties."""
        self._rng = np.random.default_rng(seed)

    def predict(
        self,
        observation: np.ndarray,
        state: object = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """
        The action of the selected worker, like SB3's ``predict``.

        :param observation: the shared state, of the env's observation shape (``(obs_dim,)`` for the snake), or a
            batch of them (one more leading axis), each row deciding anew. A manager that observes motion
            needs one stream of observations: one at a time, or batches of one.
        :param state: unused (no recurrent state), for SB3 compatibility.
        :param episode_start: for SB3 compatibility; a true entry ends the current option.
        :param deterministic: the most probable worker (``True``) or one sampled from the probabilities. An
            exact tie among the most probable is drawn from the hierarchy's generator either way (see
            :meth:`seed`): the manager prefers neither, and the worker order must not decide.
        :return: the env action(s) and ``None``.
        """
        obs = np.asarray(observation, dtype=np.float32)
        if episode_start is not None and np.any(episode_start):
            self.reset_episode()
        # One observation has the env's own shape (a matrix for highway-env's Kinematics); one more axis is a batch.
        single_ndim = len(getattr(self.observation_space, "shape", None) or (0,))
        if obs.ndim == single_ndim + 1:
            if self._manager_input.motion:
                # A batch of one (SB3's evaluate_policy on one env) is the stream itself.
                if len(obs) == 1:
                    return self._act(obs[0], deterministic, keep_option=True)[None], None
                raise ValueError(
                    "This manager observes motion, which needs one stream of observations: call predict with "
                    "one observation at a time"
                )
            # Batched: options apply to a single stream of observations, so each row decides anew.
            actions = [self._act(row, deterministic, keep_option=False) for row in obs]
            return np.stack(actions), None
        return self._act(obs, deterministic, keep_option=True), None

    def _act(self, obs: np.ndarray, deterministic: bool, keep_option: bool) -> np.ndarray:
        band = self._band(obs) if self._band is not None else None
        self.last_decided = not keep_option or self._option_left <= 0 or band != self._option_band
        if self.last_decided:
            self._option_band = band
            previous = self._previous_obs if keep_option else None
            self.last_manager_action = self._manager.act(self._manager_obs(obs, previous))
            probabilities = np.asarray(self._selector.probabilities(self.simplex, self.last_manager_action))
            self._option_probabilities = probabilities
            self._option_choice = self._selector.choose(probabilities, self._rng, deterministic)
            self._option_left = self.config.option_steps
        self._option_left -= 1
        if keep_option:
            self._previous_obs = obs
        probabilities, chosen = self._option_probabilities, self._option_choice
        self.last_selection = self.names[chosen]
        self.last_probabilities = dict(zip(self.names, probabilities.tolist()))
        action = np.asarray(self._selector.act(probabilities, chosen, self._frozen, obs))
        # A discrete worker's action stays an index; a continuous one is the float32 of the env's Box.
        return action if np.issubdtype(action.dtype, np.integer) else action.astype(np.float32)

    def probabilities(self, observation: np.ndarray) -> dict[str, float]:
        """The manager's worker probabilities for one observation (for a manager that observes motion: with
        nothing moving)."""
        action = self._manager.act(self._manager_obs(np.asarray(observation, np.float32)))
        return dict(zip(self.names, self._selector.probabilities(self.simplex, action)))

    # ------------------------------------------------------------------ saving
    def to_bytes(self) -> bytes:
        """The bundle as zip bytes (see :meth:`save`)."""
        members: dict[str, bytes] = {}
        manager_bytes = model_bytes(self.manager)
        members["manager.zip"] = manager_bytes
        workers_manifest = {}
        for name, worker in self.workers.items():
            meta = dict(self.worker_meta.get(name, {}))
            if isinstance(worker, Hierarchy):
                member = f"workers/{name}.hierarchy.zip"
                members[member] = worker.to_bytes()
                meta.update({"kind": "hierarchy"})
            elif isinstance(worker, BaseAlgorithm):
                member = f"workers/{name}.zip"
                members[member] = model_bytes(worker)
                meta.update({"kind": "sb3", "spec": model_spec(worker)})
            else:
                raise BundleError(
                    f"Worker {name!r} of type {type(worker).__name__} cannot be bundled: only SB3 models and "
                    "hierarchies can (bundle the worker's own models instead)"
                )
            meta.update({"file": member, "sha256": sha256_bytes(members[member])})
            meta.setdefault("reward_term", self.config.reward_terms.get(name, name))
            workers_manifest[name] = meta
        manifest = bundle_manifest(
            self.env_id,
            self.env_kwargs,
            self.names,
            asdict(self.config),
            {
                "file": "manager.zip",
                "sha256": sha256_bytes(manager_bytes),
                "spec": model_spec(self.manager),
                **self.metadata,
            },
            workers_manifest,
            library_versions(),
        )
        return write_bundle(manifest, members)

    def save(self, path: str | Path) -> Path:
        """Write the bundle to ``path`` atomically (a ``.zip``)."""
        data = self.to_bytes()
        return atomic_write(path, lambda tmp: tmp.write_bytes(data))

    # ------------------------------------------------------------------ loading
    @classmethod
    def load(
        cls,
        path: str | Path | io.BytesIO,
        trusted: bool = False,
        allowed_env_ids: Sequence[str] | None = None,
        *,
        budget: LoadBudget | None = None,
    ) -> Hierarchy:
        """
        Load and verify a bundle.

        :param path: a ``hierarchy.zip`` (or its bytes).
        :param trusted: ``False`` (default): rebuild every model from the manifest's JSON spec and load only
            its tensors, so no code from the file runs. ``True``: SB3's full loader, which unpickles
            objects stored in the model zips (only for files you trust), and any registered env id.
        :param allowed_env_ids: registered env ids the bundle may name besides this package's own.
        :param budget: what the load may spend (bytes, models, nesting); nested bundles share their
            parent's (see :mod:`sb3_hddpg.artifacts.limits`).
        :return: the hierarchy; raises :class:`BundleError` naming the problem otherwise.
        """

        name = str(path) if not isinstance(path, io.BytesIO) else "<bytes>"
        budget = budget if budget is not None else LoadBudget()
        manifest, members = read_bundle(path, budget=budget)
        names = manifest.worker_names
        try:
            env_id = check_env_id(manifest.env_id, f"{name}: env_id", allowed_env_ids, trusted)
            env_kwargs = check_env_kwargs(
                env_id, manifest.env_kwargs, f"{name}: env_kwargs", allowed_env_ids, trusted
            )
            settings = check_selection_settings(manifest.selection, names, f"{name}: selection")
            if settings.get("manager_preferences") is not None:
                space = PreferenceSpace.from_json(
                    settings["manager_preferences"], names, f"{name}: selection.manager_preferences"
                )
                settings["manager_preferences"] = space.to_json()
        except ValueError as error:
            raise BundleError(str(error)) from None

        def model(entry: Mapping[str, Any]) -> BaseAlgorithm:
            data = io.BytesIO(members[entry["file"]])
            try:
                if trusted:
                    budget.spend_model(name)
                return load_model(data, spec=entry.get("spec"), trusted=trusted, budget=budget)
            except ValueError as error:
                raise BundleError(f"{name}: cannot load {entry['file']}: {error}") from None

        workers: dict[str, Policy] = {}
        worker_meta = {}
        for worker_name in names:
            entry = manifest.workers[worker_name]
            if entry.get("kind") == "hierarchy":
                with budget.nested(name):
                    workers[worker_name] = cls.load(
                        io.BytesIO(members[entry["file"]]), trusted, allowed_env_ids, budget=budget
                    )
            else:
                workers[worker_name] = model(entry)
            worker_meta[worker_name] = {
                k: v for k, v in entry.items() if k not in ("file", "sha256", "spec", "kind")
            }
        manager_entry = manifest.manager
        try:
            return cls(
                model(manager_entry),
                workers,
                SelectionConfig(**settings),
                env_id=env_id,
                env_kwargs=env_kwargs,
                worker_meta=worker_meta,
                metadata={k: v for k, v in manager_entry.items() if k not in ("file", "sha256", "spec")},
            )
        except (BundleError, HeadlessRenderingError):
            raise
        except (ValueError, KeyError, TypeError, AttributeError) as error:
            raise BundleError(f"{name}: invalid settings in {MANIFEST}: {brief(str(error), 300)}") from None


def _shared_env(workers: Mapping[str, Policy]) -> tuple[str, dict[str, Any]] | None:
    """The shared env workers from ``load_workers`` name, if usable."""
    if isinstance(workers, Workers) and workers.env_id is not None:
        return workers.env_id, workers.env_kwargs
    return None


def _selection_config(
    manager: object, workers: Mapping[str, Policy], config: SelectionConfig | None
) -> SelectionConfig:
    """
    The selection settings of a new hierarchy: ``config``, else those of the ``WorkerSelectionWrapper`` the
    manager was trained on (if it still has its env), else the wrapper's defaults; the state components the
    workers carry are the default of ``worker_states`` either way.
    """
    if config is None:
        wrapper = _selection_wrapper(manager)
        if wrapper is not None:
            return wrapper.selection_config()
        config = SelectionConfig(preferences=check_preferences({}, list(workers)))
    carried = {name: states for name, states in states_of(workers).items() if name in workers}
    return replace(config, worker_states={**carried, **config.worker_states}) if carried else config


def _selection_wrapper(manager: object) -> WorkerSelectionWrapper | None:
    """The ``WorkerSelectionWrapper`` a manager trains on, if it still has an in-process env."""
    get_env = getattr(manager, "get_env", None)
    vec_env = get_env() if callable(get_env) else None
    env = (getattr(vec_env, "envs", None) or [None])[0]
    while isinstance(env, gym.Wrapper):
        if isinstance(env, WorkerSelectionWrapper):
            return env
        env = env.env
    return None


def infer_env(manager: object, workers: Mapping[str, Policy]) -> tuple[str, dict[str, Any]] | None:
    """
    The env a hierarchy acts in, read from its models: the manager's training env (the env under its
    ``WorkerSelectionWrapper``) if the manager still has one, else the env every worker names, if they all
    name the same (a nested hierarchy names its ``env_id``; an SB3 model its training env). Models loaded
    from files carry no env, so this may find nothing.

    :param manager: the manager.
    :param workers: name -> worker.
    :return: ``(env_id, env_kwargs)`` (kwargs beyond the registered ones), or ``None`` when the models do not
        tell or the workers disagree.
    """
    found = _training_env(manager)
    if found is not None:
        return found
    named = [_training_env(worker) for worker in workers.values()]
    known = [env for env in named if env is not None]
    if known and all(env == known[0] for env in known):
        return known[0]
    return None


def _training_env(model: object) -> tuple[str, dict[str, Any]] | None:
    """``(env_id, env_kwargs)`` of a model's training env (a hierarchy's own env), if it still has one."""
    if isinstance(model, Hierarchy):
        return model.env_id, dict(model.env_kwargs)
    get_env = getattr(model, "get_env", None)
    vec_env = get_env() if callable(get_env) else None
    if vec_env is None:
        return None
    try:
        envs = getattr(vec_env, "envs", None)  # in-process envs: read the spec without copying it
        spec = envs[0].unwrapped.spec if envs else vec_env.get_attr("spec", [0])[0]
    except Exception:  # an env in a subprocess that cannot answer: the model does not tell
        return None
    if spec is None:
        return None
    registered = gym.spec(spec.id).kwargs if spec.id in gym.registry else {}
    kwargs = {
        key: value
        for key, value in (spec.kwargs or {}).items()
        if key != "render_mode" and (key not in registered or registered[key] != value)
    }
    return spec.id, kwargs


def manager_input_of(
    config: SelectionConfig, observation_space: gym.Space, layout: StateLayout, n_workers: int
) -> ManagerInput:
    """What a manager with these selection settings observes of the shared env's ``observation_space``."""
    indices = layout.indices(config.manager_state) if config.manager_state else None
    n_preferences = n_workers if config.manager_preferences is not None else 0
    return ManagerInput(observation_space, indices, config.manager_motion, n_preferences)


def check_spaces(
    manager: Any,
    workers: Mapping[str, Policy],
    config: SelectionConfig,
    observation_space: gym.Space,
    action_space: gym.Space,
    layout: StateLayout,
    env_name: str,
) -> None:
    """
    Check that the manager and every worker that declares its spaces fit the env: the manager sees the
    env's observation (or its ``manager_state`` components) and outputs one value per worker; each worker
    sees the env's observation (or its ``worker_states`` components) and outputs the env's action.

    :param env_name: the env as named in messages.
    :raises ValueError: one line naming the model, the expected and the actual space.
    """

    def subset(components: list[str] | None) -> gym.Space:
        return subset_space(observation_space, layout.indices(components) if components else None)

    manager_action = get_selector(config.selection).action_space(len(workers))
    manager_obs = manager_input_of(config, observation_space, layout, len(workers)).observation_space
    checks = [("The manager", manager, manager_obs, manager_action, " (one per worker)")]
    checks += [
        (f"Worker {name!r}", worker, subset(config.worker_states.get(name)), action_space, "")
        for name, worker in workers.items()
    ]
    hint = "pass the env they were trained on as env_id= (and env_kwargs=)"
    for label, model, expected_obs, expected_action, action_note in checks:
        for kind, expected, actual, note in (
            ("observations", expected_obs, getattr(model, "observation_space", None), ""),
            ("actions", expected_action, getattr(model, "action_space", None), action_note),
        ):
            if actual is None or actual == expected:
                continue
            if getattr(actual, "shape", None) != getattr(expected, "shape", None):
                raise ValueError(
                    f"{label} has {kind} of shape {actual.shape}, but the hierarchy's env {env_name} needs "
                    f"{expected.shape}{note}: {hint}"
                )
            raise ValueError(
                f"{label} has {kind} of shape {actual.shape} like the hierarchy's env {env_name}, but "
                f"{space_difference(actual, expected)}: {hint}"
            )


def space_difference(actual: gym.Space, expected: gym.Space) -> str:
    """
    The first difference of two spaces of one shape, short enough for one line whatever their size: the
    type, the dtype, or the first bound that differs with its index (a Box's full arrays ran past the
    message's length and were cut, shapes and all).
    """
    if type(actual) is not type(expected):
        return f"a {type(actual).__name__} space where it needs a {type(expected).__name__}"
    if getattr(actual, "dtype", None) != getattr(expected, "dtype", None):
        return f"dtype {getattr(actual, 'dtype', None)} where it needs {getattr(expected, 'dtype', None)}"
    if isinstance(actual, gym.spaces.Box) and isinstance(expected, gym.spaces.Box):
        for bound in ("low", "high"):
            mine, theirs = getattr(actual, bound).ravel(), getattr(expected, bound).ravel()
            differs = np.flatnonzero(~((mine == theirs) | (np.isnan(mine) & np.isnan(theirs))))
            if differs.size:
                i = int(differs[0])
                return (
                    f"{bound}[{i}] = {mine[i]:g} where it needs {theirs[i]:g} ({differs.size} of {mine.size} "
                    f"{bound} bounds differ)"
                )
    shown = " ".join(f"{actual} != {expected}".split())
    return f"other bounds ({shown[:300]})"
