"""
``Hierarchy``: a trained manager with its workers, as one verifiable bundle that acts like an SB3 model.

A bundle (``hierarchy.zip``) holds ``manager.zip``, one member per worker (an SB3 zip or a nested bundle)
and ``manifest.json`` (env, selection settings, library versions, each model's rebuild spec and every
member's sha256). :meth:`Hierarchy.load` verifies every hash first and by default rebuilds each model from
its JSON spec with tensors only, so opening someone else's bundle runs none of their code. A ``Hierarchy``
can itself be a worker one level up (paper design specification 3), and saves and loads as one bundle.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from dataclasses import asdict, replace
from functools import partial
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.type_aliases import GymEnv
from stable_baselines3.common.utils import check_for_correct_spaces
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from sb3_hddpg.artifacts.io import atomic_write
from sb3_hddpg.artifacts.limits import LoadBudget, brief
from sb3_hddpg.artifacts.provenance import library_versions, sha256_bytes
from sb3_hddpg.artifacts.records import bundle_manifest
from sb3_hddpg.artifacts.spec import model_spec
from sb3_hddpg.artifacts.term_critic import TermCritic, with_term_critic
from sb3_hddpg.artifacts.workers import Workers
from sb3_hddpg.envs.contract import mix_terms
from sb3_hddpg.envs.headless import HeadlessRenderingError
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.hierarchy.bundle import (
    MANIFEST,
    BundleError,
    bundle_path,
    checked_settings,
    member_critics,
    member_model,
    model_bytes,
    read_bundle,
    sb3_refusal,
    write_bundle,
)
from sb3_hddpg.hierarchy.conditioning import WRITTEN_SLACK, PreferenceOutsideError, PreferenceSpace
from sb3_hddpg.hierarchy.fit import (
    check_spaces,
    manager_input_of,
    probe_env,
    selection_config_of,
    training_env,
)
from sb3_hddpg.hierarchy.frozen import FrozenWorker
from sb3_hddpg.hierarchy.gpi import (
    GPI_POLICIES_SELECTION,
    GPI_SELECTION,
    check_gpi_manager,
    check_gpi_preference,
    gpi_of,
)
from sb3_hddpg.hierarchy.option_end import OptionEnd
from sb3_hddpg.hierarchy.options import OptionState
from sb3_hddpg.hierarchy.selection import SelectionConfig, SimplexMap, check_preferences, get_selector
from sb3_hddpg.policy import Policy


class Hierarchy:
    """
    A manager and its workers, acting like an SB3 model: ``predict(obs, state, episode_start, deterministic)``
    returns the action of the worker the manager selects (single or batched observations, an option per env
    of a batch).

    Example, over workers from :func:`~sb3_hddpg.artifacts.manifests.load_workers` and a manager of your own::

        hierarchy = Hierarchy(manager, workers)
        hierarchy.save("my-hierarchy.zip")
        evaluate(Hierarchy.load("my-hierarchy.zip"), n_episodes=5)

    :param manager: the manager's SB3 model (trained on ``WorkerSelectionWrapper``; ``None`` for GPI).
    :param workers: name -> worker, in the manager's action order; workers from ``load_workers`` also give
        their state components, the shared env and the facts the bundle keeps about them.
    :param config: the selection settings the manager was trained with (default: those of the wrapper the
        manager still has as its env, else the wrapper's defaults).
    :param env_id: the shared env's registered id (default: the manager's or every worker's training env,
        else the workers' shared env, else ``hddpg/SnakeReach-v0``; see :func:`infer_env`).
    :param env_kwargs: its keyword arguments (default: those of the inferred env; ``{}`` with ``env_id``).
    :param worker_meta: name -> JSON-able facts about each worker (default: from the workers' manifest).
    :param metadata: JSON-able facts about the manager (metrics, seed, config...).
    :param critics: name -> per-term critic, for GPI (default: those the workers carry).
    """

    def __init__(
        self,
        manager: BaseAlgorithm | None,
        workers: Mapping[str, Policy],
        config: SelectionConfig | None = None,
        env_id: str | None = None,
        env_kwargs: dict[str, Any] | None = None,
        worker_meta: dict[str, dict[str, Any]] | None = None,
        metadata: dict[str, Any] | None = None,
        critics: Mapping[str, TermCritic] | None = None,
    ) -> None:
        self.manager = manager
        self.workers = dict(workers)
        self.names = list(self.workers)
        config = selection_config_of(manager, workers, config)
        self.critics = dict(critics if critics is not None else getattr(workers, "critics", {}))  # GPI's
        check_gpi_manager(manager, config.selection)
        if env_id is None:
            # The models' training envs say which env it is (a default env would fail only in evaluate).
            shared = (
                (workers.env_id, workers.env_kwargs)
                if isinstance(workers, Workers) and workers.env_id
                else None
            )
            env_id, inferred_kwargs = infer_env(manager, self.workers) or shared or (SNAKE_REACH_ENV_ID, {})
            env_kwargs = inferred_kwargs if env_kwargs is None else env_kwargs
        self.env_id = env_id
        self.env_kwargs = dict(env_kwargs or {})
        if worker_meta is None and isinstance(workers, Workers):
            worker_meta = workers.bundle_meta()
        self.worker_meta = dict(worker_meta or {})
        self.metadata = dict(metadata or {})
        layout, self.observation_space, self.action_space = probe_env(env_id, self.env_kwargs)
        name = f"{env_id!r}" + (f" with env_kwargs {self.env_kwargs}" if self.env_kwargs else "")
        check_spaces(manager, self.workers, config, self.observation_space, self.action_space, layout, name)
        self._frozen = [
            FrozenWorker(w, layout.indices(config.worker_states[n]) if n in config.worker_states else None)
            for n, w in self.workers.items()
        ]
        #: The preferences a conditioned manager was trained over (``None`` for a manager of one preference).
        self.preference_space = (
            PreferenceSpace.from_json(config.manager_preferences, self.names)
            if config.manager_preferences is not None
            else None
        )
        self._preference_obs: np.ndarray | None = None
        if self.preference_space is not None:
            config = replace(config, preferences=self.preference_space.check(config.preferences))
            self._preference_obs = self.preference_space.weights(config.preferences).astype(np.float32)
        self._manager_input = manager_input_of(config, self.observation_space, layout, len(self.names))
        # The manager's input is built here (its state, motion and weights), so its frozen copy sees it all.
        self._manager = FrozenWorker(manager) if manager is not None else None
        self._gpi = (
            gpi_of(self._frozen, self.critics, self.names, config.selection) if manager is None else None
        )
        if self._gpi is not None:
            config = replace(config, preferences=check_gpi_preference(config.preferences, self._gpi.terms))
        self.config = config
        self.simplex = SimplexMap(len(self.names), temperature=config.temperature, floor=config.floor)
        self._selector = get_selector(config.selection) if manager is not None else None
        self._rng = np.random.default_rng(0)
        self._band = OptionEnd.from_json(config.option_end).bind(layout) if config.option_end else None
        #: The options of the observations ``predict`` sees without a ``state`` (one stream per env of a batch).
        self._stream: OptionState | None = None
        #: The env set by :meth:`set_env` or ``load(env=...)``, or ``None`` (see :meth:`make_env`).
        self.env: VecEnv | None = None
        self.last_selection: str | None = None
        #: Whether the last ``predict`` made a new decision (``False`` inside an option; of the last env in a batch).
        self.last_decided = False
        #: The manager actor's output at the last decision (in [-1, 1]; how saturated the manager is).
        self.last_manager_action: np.ndarray | None = None
        self.last_probabilities: dict[str, float] = {}
        #: Per env of the last ``predict``'s batch (one for a single observation), the worker in charge and
        #: the manager's output at that env's last decision.
        self.last_selections: list[str] = []
        self.last_manager_actions: list[np.ndarray | None] = []

    @classmethod
    def gpi(
        cls,
        workers: Mapping[str, Policy],
        preference: Mapping[str, float] | None = None,
        env_id: str | None = None,
        env_kwargs: dict[str, Any] | None = None,
        critics: Mapping[str, TermCritic] | None = None,
        over_actions: bool = True,
    ) -> Hierarchy:
        """
        A hierarchy that acts by generalized policy improvement (:mod:`~sb3_hddpg.hierarchy.gpi`), with no
        manager: ``Hierarchy.gpi(load_workers("runs/w"), {"goal": 0.7, "avoid": 0.3})``.

        :param workers: the workers, each with a per-term critic (``load_workers`` gives both).
        :param preference: term -> weight (see :func:`~sb3_hddpg.hierarchy.gpi.check_gpi_preference`);
            :meth:`set_preference` changes it at any time, without training.
        :param env_id: the shared env (default: the workers').
        :param env_kwargs: its keyword arguments.
        :param critics: name -> per-term critic (default: the critics the workers carry).
        :param over_actions: with discrete workers, GPI over actions (``selection="gpi"``); ``False``: the
            action of the worker whose critic values its own action most (``"gpi-policies"``).
        """
        selection = GPI_SELECTION if over_actions else GPI_POLICIES_SELECTION
        config = SelectionConfig(preferences=dict(preference or {}), selection=selection)
        return cls(None, workers, config, env_id=env_id, env_kwargs=env_kwargs, critics=critics)

    def make_env(self, **overrides: object) -> gym.Env:
        """
        The shared env this hierarchy acts in: ``gym.make(env_id, **env_kwargs)``.

        :param overrides: keyword arguments over ``env_kwargs`` (e.g. ``render_mode="rgb_array"``).
        """
        return gym.make(self.env_id, **{**self.env_kwargs, **overrides})

    def set_env(self, env: GymEnv) -> None:
        """
        Give the hierarchy an env to act in, as SB3's ``set_env`` (a single env is wrapped in a ``DummyVecEnv``).

        :param env: a gymnasium env or a VecEnv with this hierarchy's observation and action spaces.
        """
        vec_env = env if isinstance(env, VecEnv) else DummyVecEnv([lambda: env])
        check_for_correct_spaces(vec_env, self.observation_space, self.action_space)
        self.env = vec_env

    def get_env(self) -> VecEnv | None:
        """The env given by :meth:`set_env` or ``load(env=...)``, as SB3's ``get_env``."""
        return self.env

    @property
    def reward_spec(self) -> dict[str, float]:
        """This hierarchy's reward as a worker one level up, the preference-weighted mix of its workers' terms."""
        if self._gpi is not None:  # the preference weighs the terms themselves
            return dict(self.config.preferences)
        specs = {name: self.config.reward_terms.get(name, name) for name in self.names}
        return mix_terms(specs, self.config.preferences)

    @property
    def preferences(self) -> dict[str, float]:
        """The preference the hierarchy acts at (worker name -> factor)."""
        return dict(self.config.preferences)

    def set_preference(self, preferences: Mapping[str, float] | None = None, **factors: float) -> None:
        """
        Tell a preference-conditioned manager the trade-off to act at, e.g.
        ``hierarchy.set_preference(goal=0.4, avoid=1.6)``: only the ratio matters, names not given get the
        unweighted factor. A GPI hierarchy (:meth:`gpi`) takes any weighting of the env's terms.

        :param preferences: worker name -> factor; or give the factors as keywords.
        :raises PreferenceOutsideError: for a preference outside those the manager was trained over, or any
            other than its own for a manager trained for one preference.
        """
        given = {**dict(preferences or {}), **factors}
        if self._gpi is not None:
            self.config = replace(self.config, preferences=check_gpi_preference(given, self._gpi.terms))
            return
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
        if self._stream is not None:
            self._stream.end_options()

    def reset_episode(self) -> None:
        """Forget the options of ``predict`` without a ``state`` (call at an episode start)."""
        if self._stream is not None:
            self._stream.reset()
        for worker in self._frozen:
            worker.reset_episode()

    def seed(self, seed: int) -> None:
        """Seed the generator used to sample workers in stochastic prediction and to break exact ties."""
        self._rng = np.random.default_rng(seed)

    def initial_state(self, n_envs: int = 1) -> OptionState:
        """The options of ``n_envs`` envs at their episodes' start (what ``predict`` takes as ``state``)."""
        nested = {j: w.worker for j, w in enumerate(self._frozen) if isinstance(w.worker, Hierarchy)}
        return OptionState.initial(
            n_envs, len(self.names), lambda: {j: h.initial_state() for j, h in nested.items()}
        )

    def predict(
        self,
        observation: np.ndarray,
        state: OptionState | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, OptionState]:
        """
        The action of the selected worker, like a recurrent SB3 policy's ``predict`` (the state is the option
        each env is in).

        :param observation: the shared state, or a batch of them (one row per env of a VecEnv).
        :param state: the options returned by the previous call (see :meth:`initial_state`), updated in place;
            ``None``: the hierarchy's own, kept from call to call (a new batch size starts afresh).
        :param episode_start: one flag per env; a true entry ends that env's option, as at an episode's start.
        :param deterministic: the most probable worker, or one sampled from the probabilities (SB3's default).
            An exact tie is drawn from the hierarchy's generator either way (see :meth:`seed`).
        :return: the env action(s) and the state to pass at the next step.
        """
        obs = np.asarray(observation, dtype=np.float32)
        # One observation has the env's own shape (a matrix for highway-env's Kinematics); one more axis is a batch.
        single_ndim = len(getattr(self.observation_space, "shape", None) or (0,))
        batched = obs.ndim == single_ndim + 1
        rows = obs if batched else obs[None]
        if state is None:
            if self._stream is None or self._stream.n_envs != len(rows):
                self._stream = self.initial_state(len(rows))
            state = self._stream
        elif state.n_envs != len(rows):
            raise ValueError(
                f"Expected a state for {len(rows)} envs (one per row of the observation), actually for {state.n_envs}"
            )
        if episode_start is not None:
            self._start_episodes(state, episode_start)
        actions = [self._act(row, deterministic, state, i) for i, row in enumerate(rows)]
        self.last_selections = [self.names[int(choice)] for choice in state.choice]
        self.last_manager_actions = list(state.manager_action)
        return (np.stack(actions) if batched else actions[0]), state

    def _start_episodes(self, state: OptionState, episode_start: np.ndarray) -> None:
        starts = np.asarray(episode_start, dtype=bool).reshape(-1)
        if starts.size not in (1, state.n_envs):
            raise ValueError(
                f"Expected `episode_start` to hold {state.n_envs} flags, actually: {starts.size}"
            )
        for index in np.flatnonzero(np.broadcast_to(starts, (state.n_envs,))):
            state.reset(int(index))
        if starts.any():
            # Stateful workers other than hierarchies (the HAM switch) keep one stream of their own.
            for worker in self._frozen:
                if not isinstance(worker.worker, Hierarchy):
                    worker.reset_episode()

    def _act(self, obs: np.ndarray, deterministic: bool, state: OptionState, env: int) -> np.ndarray:
        for index, nested in state.workers[env].items():
            self._frozen[index].state = nested
        if self._gpi is not None:  # GPI decides anew at every step
            chosen, action = self._gpi.select(obs, self.config.preferences)
            state.choice[env] = chosen
            state.probabilities[env] = np.eye(len(self.names))[chosen]
            self.last_decided = True
        else:
            assert self._manager is not None and self._selector is not None  # every other mode has both
            band = self._band(obs) if self._band is not None else None
            self.last_decided = state.left[env] <= 0 or band != state.band[env]
            if self.last_decided:
                state.band[env] = band
                state.manager_action[env] = self._manager.act(
                    self._manager_input(obs, state.previous[env], self._preference_obs)
                )
                probabilities = self._selector.probabilities(self.simplex, state.manager_action[env])
                state.probabilities[env] = probabilities
                state.choice[env] = self._selector.choose(probabilities, self._rng, deterministic)
                state.left[env] = self.config.option_steps
            state.left[env] -= 1
            if self._manager_input.motion:
                state.previous[env] = obs.copy()
            chosen = int(state.choice[env])
            self.last_manager_action = state.manager_action[env]
            action = np.asarray(self._selector.act(state.probabilities[env], chosen, self._frozen, obs))
        self.last_selection = self.names[chosen]
        self.last_probabilities = dict(zip(self.names, state.probabilities[env].tolist()))
        # A discrete worker's action stays an index; a continuous one is the float32 of the env's Box.
        return action if np.issubdtype(action.dtype, np.integer) else action.astype(np.float32)

    def probabilities(self, observation: np.ndarray) -> dict[str, float]:
        """The manager's worker probabilities for one observation (for a manager that observes motion: with
        nothing moving); GPI's choice as probability 1."""
        if self._gpi is not None:
            chosen, _ = self._gpi.select(np.asarray(observation, np.float32), self.config.preferences)
            return {name: float(i == chosen) for i, name in enumerate(self.names)}
        assert self._manager is not None and self._selector is not None
        obs = np.asarray(observation, np.float32)
        action = self._manager.act(self._manager_input(obs, None, self._preference_obs))
        return dict(zip(self.names, self._selector.probabilities(self.simplex, action)))

    def to_bytes(self) -> bytes:
        """The bundle as zip bytes (see :meth:`save`)."""
        members: dict[str, bytes] = {}
        manager_entry: dict[str, Any] | None = None
        if self.manager is not None:  # a GPI hierarchy has none
            members["manager.zip"] = manager_bytes = model_bytes(self.manager)
            manager_entry = {
                "file": "manager.zip",
                "sha256": sha256_bytes(manager_bytes),
                "spec": model_spec(self.manager),
                **self.metadata,
            }
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
                if name in self.critics:  # inside the worker's zip, as train-workers writes it
                    members[member] = with_term_critic(members[member], self.critics[name])
                    meta["term_critic"] = {"terms": list(self.critics[name].spec.terms)}
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
            manager_entry,
            workers_manifest,
            library_versions(),
        )
        # An SB3 class pointed at the bundle reads this entry and says what the file is (see sb3_refusal).
        members["data"] = sb3_refusal(self.observation_space, self.action_space)
        return write_bundle(manifest, members)

    def save(self, path: str | Path) -> Path:
        """
        Write the bundle atomically, as SB3's ``save`` names files: ``path`` without a suffix gets ``.zip``.

        :param path: the bundle's file (``"hierarchy"`` writes ``hierarchy.zip``).
        :return: the file written.
        """
        data = self.to_bytes()
        path = Path(path)
        return atomic_write(
            path if path.suffix else path.with_name(f"{path.name}.zip"), lambda tmp: tmp.write_bytes(data)
        )

    @classmethod
    def load(
        cls,
        path: str | Path | io.BytesIO,
        env: GymEnv | None = None,
        device: str = "auto",
        trusted: bool = False,
        allowed_env_ids: Sequence[str] | None = None,
        *,
        budget: LoadBudget | None = None,
    ) -> Hierarchy:
        """
        Load and verify a bundle, as SB3's ``load`` opens a model.

        :param path: a ``hierarchy.zip`` or its bytes (without a suffix, ``.zip`` is tried, as SB3 does).
        :param env: an env to act in (see :meth:`set_env`); ``None``: :meth:`make_env` makes the bundle's own.
        :param device: the torch device of the models (``"auto"``: CUDA when available, as SB3).
        :param trusted: ``False`` (default): rebuild every model from its JSON spec and load only tensors, so
            no code from the file runs. ``True``: SB3's full loader, which unpickles objects stored in the
            model zips (only for files you trust), and any registered env id.
        :param allowed_env_ids: registered env ids the bundle may name besides this package's own.
        :param budget: what the load may spend (see :mod:`sb3_hddpg.artifacts.limits`); nested bundles share it.
        :return: the hierarchy; raises :class:`BundleError` naming the problem otherwise.
        """
        path = bundle_path(path)
        name = str(path) if not isinstance(path, io.BytesIO) else "<bytes>"
        budget = budget if budget is not None else LoadBudget()
        manifest, members = read_bundle(path, budget=budget)
        env_id, env_kwargs, settings = checked_settings(manifest, name, trusted, allowed_env_ids, env)
        model = partial(member_model, members, name=name, trusted=trusted, device=device, budget=budget)

        workers: dict[str, Policy] = {}
        worker_meta = {}
        for worker_name in manifest.worker_names:
            entry = manifest.workers[worker_name]
            if entry.get("kind") == "hierarchy":
                with budget.nested(name):
                    workers[worker_name] = cls.load(
                        io.BytesIO(members[entry["file"]]),
                        device=device,
                        trusted=trusted,
                        allowed_env_ids=allowed_env_ids,
                        budget=budget,
                    )
            else:
                workers[worker_name] = model(entry)
            worker_meta[worker_name] = {
                k: v for k, v in entry.items() if k not in ("file", "sha256", "spec", "kind")
            }
        manager_entry = manifest.manager
        try:
            hierarchy = cls(
                model(manager_entry) if manager_entry is not None else None,
                workers,
                SelectionConfig(**settings),
                env_id=env_id,
                env_kwargs=env_kwargs,
                worker_meta=worker_meta,
                metadata={
                    k: v for k, v in (manager_entry or {}).items() if k not in ("file", "sha256", "spec")
                },
                critics=member_critics(manifest, members, name),
            )
        except (BundleError, HeadlessRenderingError):
            raise
        except (ValueError, KeyError, TypeError, AttributeError) as error:
            raise BundleError(f"{name}: invalid settings in {MANIFEST}: {brief(str(error), 300)}") from None
        if env is not None:
            hierarchy.set_env(env)
        return hierarchy


def infer_env(manager: object, workers: Mapping[str, Policy]) -> tuple[str, dict[str, Any]] | None:
    """
    The env a hierarchy acts in, read from its models: the manager's training env if it still has one, else
    the env every worker names (a nested hierarchy its ``env_id``, an SB3 model its training env).

    :return: ``(env_id, env_kwargs)`` (kwargs beyond the registered ones), or ``None`` when the models do not
        tell (models loaded from files carry no env) or the workers disagree.
    """

    def env_of(model: object) -> tuple[str, dict[str, Any]] | None:
        return (model.env_id, dict(model.env_kwargs)) if isinstance(model, Hierarchy) else training_env(model)

    found = env_of(manager)
    if found is not None:
        return found
    known = [env for env in map(env_of, workers.values()) if env is not None]
    return known[0] if known and all(env == known[0] for env in known) else None
