"""``WorkerSelectionWrapper``: the shared environment as the manager's MDP (paper Section 2.4, Algorithm 1)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from types import SimpleNamespace
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.utils import check_for_correct_spaces

from sb3_hddpg.artifacts.workers import reward_specs_of, states_of
from sb3_hddpg.envs.contract import RewardTermsEnv, env_contract, mix_terms, state_layout_of
from sb3_hddpg.envs.layout import StateLayout
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.hierarchy.frozen import FrozenWorker
from sb3_hddpg.hierarchy.manager_input import ManagerInput, subset_space
from sb3_hddpg.hierarchy.option_end import OptionEnd
from sb3_hddpg.hierarchy.selection import (
    SelectionConfig,
    Selector,
    SimplexMap,
    check_preferences,
    check_probabilities,
    get_selector,
)
from sb3_hddpg.policy import Policy
from sb3_hddpg.threads import use_one_thread_unless_chosen

#: A worker's reward: one env term by name, or a weighted mix of normalised terms (a nested hierarchy's).
RewardSpec = str | Mapping[str, float]


class WorkerSelectionWrapper(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """
    Turn the shared env into the manager's MDP: the manager's action chooses which worker acts.

    **Action.** ``Box(-1, 1, (n_workers,))`` mapped to worker probabilities by
    :class:`~sb3_hddpg.hierarchy.selection.SimplexMap`, so SB3's noisy, clipped and warm-up actions are all
    valid; ``selection`` (a registered :class:`~sb3_hddpg.hierarchy.selection.Selector`) then runs one drawn
    worker (``"sample"``, the paper's), the most probable one (``"argmax"``) or the weighted blend (``"mix"``).

    **Reward.** ``sum_w preference[w] * normalised(term_w)``, each term min-max normalised to [0, 1] with the
    env's fixed ``reward_bounds`` (not running statistics, so a reward means the same all through training).

    **Options.** The choice is kept for ``option_steps = k`` env steps and the reward is their discounted sum
    ``sum_j option_gamma^j r_j`` (semi-MDP, paper Section 2.3). SB3 discounts the next decision by its own
    ``gamma``, not ``gamma^k``: give the manager ``gamma_env^k`` for the same horizon.

    **Observations.** The manager sees the shared state (or its ``manager_state`` components), then with
    ``manager_motion`` their change over the last env step, then a conditioned manager's preference weights
    (:class:`~sb3_hddpg.hierarchy.manager_input.ManagerInput`); each worker sees its ``worker_states`` subset,
    by default the components it was trained on (workers from ``load_workers`` carry them).

    Example, your own manager over trained workers::

        workers = load_workers("runs/quickstart/workers")
        env = WorkerSelectionWrapper(workers.make_env(), workers)
        manager = SAC("MlpPolicy", env).learn(2_000)

    Building the wrapper sets torch to one thread unless you chose its threads (:mod:`sb3_hddpg.threads`).

    **Info.** ``selected_worker``, ``selection_probabilities``, ``normalised_terms``, ``option_length``, the
    env's own info of the option's last step, and per env step of the option ``option_rewards`` (undiscounted)
    and ``option_infos``, which :func:`~sb3_hddpg.evaluation.evaluate` counts per env step.

    :param env: the shared env, which meets the env contract (:mod:`sb3_hddpg.envs.contract`).
    :param workers: the workers ``load_workers`` returns, or name -> worker (an SB3 model, a ``Hierarchy``,
        anything with SB3's ``predict``), or ``(name, worker)`` pairs.
    :param preferences: name -> preference factor (finite, > 0); missing names get 1.
    :param selection: a registered selection mode.
    :param option_steps: env steps per manager decision, >= 1.
    :param temperature: the simplex map's softmax temperature.
    :param floor: every worker's least probability.
    :param reward_terms: name -> the worker's reward: an env term, or term -> weight (normalised terms mixed
        by those weights over their sum). Default: the worker's name, or a hierarchy worker's ``reward_spec``.
    :param manager_state: state components the manager sees (``None``: all).
    :param worker_states: name -> state components that worker sees (missing: those it carries, else all).
    :param option_gamma: discount inside an option.
    :param manager_preferences: train one manager for every preference of this
        :class:`~sb3_hddpg.hierarchy.conditioning.PreferenceSpace` (or its JSON form): the manager observes
        the normalised weights, a preference is drawn at every reset (until :meth:`set_preference`), and
        ``info["worker_rewards"]`` holds each worker's discounted option reward for
        :class:`~sb3_hddpg.hierarchy.relabeling.PreferenceRelabelingReplayBuffer`.
    :param option_end: options that also end when the state leaves the band they were chosen in (an
        :class:`~sb3_hddpg.hierarchy.option_end.OptionEnd` or its JSON form; ``None``: by ``option_steps`` only).
    :param manager_motion: the manager also observes its state's change over the last env step, scaled by
        this factor and clipped to [-1, 1], to tell an obstacle coming from one going away (0: not).
    """

    def __init__(
        self,
        env: gym.Env,
        workers: Mapping[str, Policy] | Sequence[tuple[str, Policy]],
        preferences: Mapping[str, float] | None = None,
        selection: str = "sample",
        option_steps: int = 1,
        temperature: float = 0.5,
        floor: float = 0.02,
        reward_terms: Mapping[str, RewardSpec] | None = None,
        manager_state: Sequence[str] | None = None,
        worker_states: Mapping[str, Sequence[str]] | None = None,
        option_gamma: float = 0.99,
        manager_preferences: PreferenceSpace | Mapping[str, Any] | None = None,
        option_end: OptionEnd | Mapping[str, Any] | None = None,
        manager_motion: float = 0.0,
    ) -> None:
        pairs = list(workers.items()) if isinstance(workers, Mapping) else list(workers)
        names = [name for name, _ in pairs]
        selector = _checked_settings(names, selection, option_steps, option_gamma)
        super().__init__(env)
        use_one_thread_unless_chosen()  # a manager trains on this env: as fast in a script as in the CLI
        contract = env_contract(env)
        self.layout = state_layout_of(env)
        self.worker_names = names
        self.selection = selection
        self.selector = selector
        self.option_steps = int(option_steps)
        self.option_gamma = float(option_gamma)
        self.simplex = SimplexMap(len(names), temperature=temperature, floor=floor)
        if option_end is not None and not isinstance(option_end, OptionEnd):
            option_end = OptionEnd.from_json(option_end)
        self.option_end: OptionEnd | None = option_end
        self._band = option_end.bind(self.layout) if option_end is not None else None
        if manager_preferences is not None and not isinstance(manager_preferences, PreferenceSpace):
            manager_preferences = PreferenceSpace.from_json(manager_preferences, names)
        if manager_preferences is not None and list(manager_preferences.names) != names:
            raise ValueError(
                f"The preference space names workers {list(manager_preferences.names)}, the wrapper {names}"
            )
        self.preference_space: PreferenceSpace | None = manager_preferences
        self.preferences = check_preferences(dict(preferences or {}), names)
        if manager_preferences is not None:
            self.preferences = manager_preferences.check(self.preferences)
        #: Whether every reset draws a new preference (a conditioned manager in training).
        self.sample_preferences = manager_preferences is not None
        self._set_states(workers, manager_state, worker_states, manager_motion)
        # Weighted workers from load_workers carry their weights: the bundle keeps them as reward_terms.
        carried = reward_specs_of(workers) if isinstance(workers, Mapping) else {}
        self._set_workers(pairs, {**carried, **dict(reward_terms or {})}, contract)
        self._rng = np.random.default_rng()
        self._preference_rng = np.random.default_rng()
        self._last_obs: np.ndarray | None = None
        self._previous_obs: np.ndarray | None = None  # the state one env step earlier, for motion

    def _set_states(
        self,
        workers: Mapping[str, Policy] | Sequence[tuple[str, Policy]],
        manager_state: Sequence[str] | None,
        worker_states: Mapping[str, Sequence[str]] | None,
        manager_motion: float,
    ) -> None:
        """The state components the manager and each worker see (the components workers carry by default),
        what the manager observes of them, and the spaces the manager acts in."""
        names = self.worker_names
        carried = states_of(workers) if isinstance(workers, Mapping) else {}
        states = {**{n: v for n, v in carried.items() if n in names}, **dict(worker_states or {})}
        unknown_state_owners = sorted(set(states) - set(names))
        if unknown_state_owners:
            raise ValueError(f"worker_states names unknown workers {unknown_state_owners}; workers: {names}")
        self.manager_state = list(manager_state) if manager_state is not None else None
        self.worker_states = {name: list(states[name]) for name in states}
        self.manager_input = ManagerInput(
            self.env.observation_space,
            self.layout.indices(self.manager_state) if self.manager_state is not None else None,
            manager_motion,
            len(names) if self.preference_space is not None else 0,
        )
        self.observation_space = self.manager_input.observation_space
        self.action_space = self.selector.action_space(len(names))

    def _set_workers(
        self,
        pairs: list[tuple[str, Policy]],
        reward_terms: Mapping[str, RewardSpec] | None,
        contract: RewardTermsEnv,
    ) -> None:
        """The workers, each checked against the env's spaces and frozen, and the reward terms each stands for."""
        known_terms = list(contract.reward_bounds)
        self.reward_terms = dict(reward_terms or {})
        self.reward_specs: dict[str, dict[str, float]] = {}
        self.frozen: list[FrozenWorker] = []
        for name, worker in pairs:
            indices = self.layout.indices(self.worker_states[name]) if name in self.worker_states else None
            _check_worker_spaces(
                name,
                worker,
                subset_space(self.env.observation_space, indices),
                self.env.action_space,
                self.layout,
            )
            spec = self.reward_terms.get(name, getattr(worker, "reward_spec", name))
            self.reward_specs[name] = _term_weights(name, spec, known_terms)
            self.frozen.append(FrozenWorker(worker, indices))
        self.workers = dict(pairs)
        self._normalise = contract.normalise_terms
        self._known_terms = known_terms
        self._set_coefficients()
        # Each worker's own reward per term, for the per-worker rewards a relabelling buffer needs.
        self._worker_coefficients = [
            [(term, spec.get(term, 0.0)) for term in known_terms if spec.get(term, 0.0)]
            for spec in (self.reward_specs[name] for name in self.worker_names)
        ]

    # The arguments are documented once, on the class.
    __init__.__doc__ = __doc__

    def selection_config(self) -> SelectionConfig:
        """The selection settings of this wrapper, as a bundle keeps them (see ``Hierarchy``)."""
        # While preferences are drawn, the current one is random: a bundle acts at the unweighted one.
        space = self.preference_space
        preferences = (
            space.default if self.sample_preferences and space is not None else dict(self.preferences)
        )
        return SelectionConfig(
            preferences=preferences,
            selection=self.selection,
            option_steps=self.option_steps,
            temperature=self.simplex.temperature,
            floor=self.simplex.floor,
            reward_terms=dict(self.reward_terms),
            manager_state=self.manager_state,
            worker_states={name: list(states) for name, states in self.worker_states.items()},
            option_gamma=self.option_gamma,
            manager_preferences=self.preference_space.to_json() if self.preference_space else None,
            option_end=self.option_end.to_json() if self.option_end else None,
            manager_motion=self.manager_input.motion,
        )

    def set_preference(self, preferences: Mapping[str, float] | None = None, **factors: float) -> None:
        """
        Act at one preference from now on: the reward's factors, and for a conditioned manager the
        preference it observes (which must be among those it trains over). ``set_preference(None)`` on a
        conditioned wrapper resumes drawing a preference at every reset.

        :param preferences: worker name -> factor; or give the factors as keywords.
        """
        given = {**dict(preferences or {}), **factors}
        if preferences is None and not factors and self.preference_space is not None:
            self.sample_preferences = True
            return
        checked = check_preferences(given, self.worker_names)
        if self.preference_space is not None:
            checked = self.preference_space.check(given)
            self.sample_preferences = False
        self.preferences = checked
        self._set_coefficients()

    def _set_coefficients(self) -> None:
        # The reward is linear in the terms: one coefficient per term keeps a step cheap.
        coefficients = mix_terms(self.reward_specs, self.preferences)
        self._term_coefficients = [(term, coefficients.get(term, 0.0)) for term in self._known_terms]
        self._preference_obs = (
            self.preference_space.weights(self.preferences).astype(np.float32)
            if self.preference_space is not None
            else None
        )

    def _manager_obs(self, obs: np.ndarray) -> np.ndarray:
        return self.manager_input(obs, self._previous_obs, self._preference_obs)

    def worker_rewards(self, normalised: Mapping[str, float]) -> list[float]:
        """Each worker's own (unweighted) reward from the normalised terms, in worker order."""
        return [sum(w * normalised[term] for term, w in terms) for terms in self._worker_coefficients]

    def manager_reward(self, terms: Mapping[str, float]) -> tuple[float, dict[str, float]]:
        """The manager's one-step reward from the env's raw terms, and the normalised terms."""
        normalised = self._normalise(terms)
        reward = 0.0
        for term, coefficient in self._term_coefficients:
            reward += coefficient * normalised[term]
        return reward, normalised

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict]:
        if seed is not None:
            # Generators of our own: sampling workers must not consume the env's randomness.
            self._rng = np.random.default_rng([seed, 0x5E1EC7])
            self._preference_rng = np.random.default_rng([seed, 0x9EF])
        if self.sample_preferences and self.preference_space is not None:
            self.preferences = self.preference_space.sample(self._preference_rng)
            self._set_coefficients()
        obs, info = self.env.reset(seed=seed, options=options)
        for worker in self.frozen:
            worker.reset_episode()
        self._last_obs = obs
        self._previous_obs = None
        return self._manager_obs(obs), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._last_obs is None:
            raise RuntimeError("Call reset() before step()")
        probabilities = self.selector.probabilities(self.simplex, action)
        check_probabilities(probabilities, len(self.worker_names))
        chosen = self.selector.choose(probabilities, self._rng, False)
        total = 0.0
        discount = 1.0
        terminated = truncated = False
        info: dict[str, Any] = {}
        rewards: list[float] = []
        infos: list[dict[str, Any]] = []
        obs = self._last_obs
        per_worker = np.zeros(len(self.worker_names)) if self.preference_space is not None else None
        start_band = self._band(obs) if self._band is not None else None
        while len(rewards) < self.option_steps and not (terminated or truncated):
            if (
                start_band is not None
                and rewards
                and self._band is not None
                and self._band(obs) != start_band
            ):
                break  # the state left the band the option was chosen in: decide again
            env_action = self.selector.act(probabilities, chosen, self.frozen, obs)
            self._previous_obs = obs
            obs, _, terminated, truncated, info = self.env.step(env_action)
            reward, normalised = self.manager_reward(info["reward_terms"])
            total += discount * reward
            if per_worker is not None:
                per_worker += discount * np.asarray(self.worker_rewards(normalised))
            discount *= self.option_gamma
            rewards.append(reward)
            infos.append(info)
        self._last_obs = obs
        info = dict(info)  # the last step's, without a reference to itself in option_infos
        info["option_rewards"] = rewards
        info["option_infos"] = infos
        info["selected_worker"] = self.worker_names[chosen]
        info["selection_probabilities"] = dict(zip(self.worker_names, probabilities))
        info["normalised_terms"] = normalised
        info["option_length"] = len(rewards)
        if per_worker is not None:
            info["worker_rewards"] = per_worker
            info["preferences"] = dict(self.preferences)
        return self._manager_obs(obs), float(total), terminated, truncated, info


def _check_worker_spaces(
    name: str, worker: object, observation_space: gym.Space, action_space: gym.Space, layout: StateLayout
) -> None:
    """
    SB3's own check (``Observation spaces do not match: A != B``) for workers that declare spaces; a worker
    that sees a different number of values than it is given gets the fix instead (it was trained on part
    of the state, and was not loaded with its view).
    """
    if not hasattr(worker, "predict"):
        raise ValueError(f"Worker {name!r} has no predict(obs, deterministic=...) method: {worker!r}")
    if hasattr(worker, "observation_space") and hasattr(worker, "action_space"):
        seen, given = getattr(worker.observation_space, "shape", None), observation_space.shape
        if seen is not None and given is not None and len(seen) == len(given) == 1 and seen != given:
            raise ValueError(
                f"Worker {name!r} sees {seen[0]} values but the env gives {given[0]}: load workers with "
                f"sb3_hddpg.load_workers(folder), or pass worker_states={{{name!r}: [...]}} with the "
                f"components it was trained on (the env's: {list(layout)}), or use the env it was trained on"
            )
        expected = SimpleNamespace(
            observation_space=worker.observation_space, action_space=worker.action_space
        )
        try:
            check_for_correct_spaces(expected, observation_space, action_space)  # type: ignore[arg-type]
        except ValueError as error:
            raise ValueError(f"Worker {name!r} does not fit this env: {error}") from None


def _term_weights(name: str, spec: RewardSpec, known_terms: list[str]) -> dict[str, float]:
    weights = {spec: 1.0} if isinstance(spec, str) else {str(k): float(v) for k, v in dict(spec).items()}
    unknown = sorted(set(weights) - set(known_terms))
    if unknown:
        raise ValueError(
            f"Worker {name!r} has unknown reward terms {unknown}; the env's terms: {known_terms}"
        )
    total = sum(weights.values())
    if not weights or not np.isfinite(total) or total <= 0 or any(w < 0 for w in weights.values()):
        raise ValueError(
            f"Expected worker {name!r} reward weights >= 0 with a positive sum, actually: {weights}"
        )
    # Normalise the weights so that a mixed term, like a single one, stays in [0, 1].
    return {term: w / total for term, w in weights.items()}


def _checked_settings(names: list[str], selection: str, option_steps: int, option_gamma: float) -> Selector:
    """
    Check the worker names (at least two, each once) and the option settings before the env is wrapped.

    :return: the selection mode's selector.
    """
    if len(names) < 2:
        raise ValueError(f"Expected at least 2 workers, actually: {len(names)} ({names})")
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates:
        raise ValueError(f"Expected unique worker names, actually duplicated: {duplicates}")
    selector = get_selector(selection)
    if isinstance(option_steps, bool) or not isinstance(option_steps, (int, np.integer)) or option_steps < 1:
        raise ValueError(f"Expected `option_steps` to be an integer >= 1, actually: {option_steps!r}")
    if not 0.0 < option_gamma <= 1.0:
        raise ValueError(f"Expected `option_gamma` in (0, 1], actually: {option_gamma}")
    return selector
