"""``StepRecorder``: a wrapper that keeps, per step, what a person needs to see the manager at work."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from sb3_hddpg.evaluation import EVAL_SEED_BASE, evaluate
from sb3_hddpg.policy import Policy


@dataclass
class StepRecord:
    """
    One environment step, as seen after it.

    :param episode: the episode index (0 for the first).
    :param step: the step index within the episode (0 for the first).
    :param selected: the worker that acted (``None`` for a policy that selects no worker).
    :param probabilities: the manager's worker probabilities (empty when unknown).
    :param min_clearance: the gap between the arm and the nearest obstacle surface (0: touching).
    :param distance_to_goal: the tip-to-goal distance.
    :param goal_touched: the tip touches the goal.
    :param collision: a link touches an obstacle.
    :param reward_terms: the env's raw reward terms of the step.
    """

    episode: int
    step: int
    selected: str | None
    probabilities: dict[str, float] = field(default_factory=dict)
    min_clearance: float = float("nan")
    distance_to_goal: float = float("nan")
    goal_touched: bool = False
    collision: bool = False
    reward_terms: dict[str, float] = field(default_factory=dict)


def selected_names(policy: object) -> list[str]:
    """The worker names a policy selects among (its ``names`` or ``worker_names``), in its action order."""
    for attribute in ("names", "worker_names"):
        names = getattr(policy, attribute, None)
        if names:
            return [str(n) for n in names]
    return []


class StepRecorder(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """
    Record every step of a snake env as a :class:`StepRecord` (and optionally its rendered frame): wrap the
    env given to :func:`~sb3_hddpg.evaluation.evaluate`.

    :param env: a snake env (``render_mode="rgb_array"`` when ``on_frame`` is given).
    :param policy: the policy that will act, read for ``last_selection`` / ``last_probabilities``.
    :param on_frame: called after every step with the rendered frame and the step's record.
    """

    def __init__(
        self,
        env: gym.Env,
        policy: Policy | None = None,
        on_frame: Callable[[np.ndarray, StepRecord], None] | None = None,
    ) -> None:
        if on_frame is not None and env.render_mode != "rgb_array":
            raise ValueError(
                f'Expected an env made with render_mode="rgb_array" to record frames, actually: {env.render_mode!r}'
            )
        super().__init__(env)
        self.policy = policy
        self.on_frame = on_frame
        self.records: list[StepRecord] = []
        self._episode = -1
        self._step = 0

    def reset(
        self, *, seed: int | None = None, options: dict[str, object] | None = None
    ) -> tuple[np.ndarray, dict[str, object]]:
        self._episode += 1
        self._step = 0
        return self.env.reset(seed=seed, options=options)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        selected = info.get("selected_worker") or getattr(self.policy, "last_selection", None)
        probabilities = info.get("selection_probabilities") or getattr(
            self.policy, "last_probabilities", None
        )
        record = StepRecord(
            episode=self._episode,
            step=self._step,
            selected=selected,
            probabilities={str(k): float(v) for k, v in (probabilities or {}).items()},
            min_clearance=float(info.get("min_clearance", np.nan)),
            distance_to_goal=float(info.get("distance_to_goal", np.nan)),
            goal_touched=bool(info.get("goal_touched", False)),
            collision=bool(info.get("collision", False)),
            reward_terms={str(k): float(v) for k, v in (info.get("reward_terms") or {}).items()},
        )
        self.records.append(record)
        self._step += 1
        if self.on_frame is not None:
            self.on_frame(self.env.render(), record)  # type: ignore[arg-type]
        return obs, reward, terminated, truncated, info


def trace_episodes(
    policy: Policy, env: gym.Env, n_episodes: int = 1, seed: int | None = None, deterministic: bool = True
) -> tuple[list[StepRecord], Any]:
    """
    Run ``policy`` through :func:`~sb3_hddpg.evaluation.evaluate` and keep every step.

    :param policy: anything with SB3's ``predict``.
    :param env: a snake env (no rendering needed).
    :param n_episodes: how many episodes.
    :param seed: the first episode's seed (default: the evaluation seeds).
    :param deterministic: passed to ``predict``.
    :return: the step records and the :class:`~sb3_hddpg.evaluation.EvaluationResult`.
    """
    recorder = StepRecorder(env, policy)
    result = evaluate(
        policy,
        recorder,
        n_episodes=n_episodes,
        seed=EVAL_SEED_BASE if seed is None else seed,
        deterministic=deterministic,
    )
    return recorder.records, result
