"""
What a benchmark method reads from the run's settings and from its task, as protocols.

The methods (:mod:`.methods`) run on a :class:`~.settings.BenchmarkSettings` and a :class:`~.tasks.Task`,
and the settings check their method names against the methods' registry; typing the methods against these
protocols instead of the settings' class keeps that dependency one way (settings -> methods).
"""

from __future__ import annotations

from typing import Protocol, TypedDict

from sb3_hddpg.envs.terms_env import TermsEnv
from sb3_hddpg.episode_sets import EpisodeSet
from sb3_hddpg.training.run_options import RunOptions


class EnvChoice(TypedDict):
    """Another env than the snake arm (``--env``): a :class:`~sb3_hddpg.envs.terms_env.TermsEnv`'s fields."""

    env_id: str
    env_kwargs: dict[str, object]
    terms: list[str]


class MethodSettings(Protocol):
    """The part of :class:`~.settings.BenchmarkSettings` a method's functions read."""

    @property
    def bias(self) -> float: ...

    @property
    def env(self) -> EnvChoice | None: ...

    @property
    def eval_episodes(self) -> int: ...

    @property
    def ham_threshold(self) -> float | None: ...

    @property
    def ham_hysteresis(self) -> float: ...

    @property
    def test_episodes(self) -> int | None: ...

    @property
    def terms_env(self) -> TermsEnv | None: ...

    @property
    def test_set(self) -> EpisodeSet: ...

    @property
    def test_episode_set(self) -> dict[str, int | str]: ...

    @property
    def manager_env_steps(self) -> int: ...

    @property
    def flat_budget(self) -> int: ...

    @property
    def front_env_steps(self) -> int: ...

    @property
    def morl_python(self) -> str | None: ...

    def option_steps_of(self, algo: str) -> int: ...

    @property
    def front_manager(self) -> str: ...

    @property
    def front_sweep(self) -> str: ...

    @property
    def front_motion(self) -> float: ...

    @property
    def front_option_steps(self) -> int | None: ...

    @property
    def front_per_preference(self) -> bool: ...

    @property
    def front_support(self) -> str | None: ...

    @property
    def worker_timesteps(self) -> int | None: ...

    @property
    def front_start(self) -> str | None: ...

    @property
    def front_critic_steps(self) -> int: ...

    @property
    def front_gpi(self) -> str: ...

    def manager_run_options(
        self, seed: int, algo: str = "ddpg", env_steps: int | None = None
    ) -> RunOptions: ...

    def front_run_options(self, seed: int, start: str | None = None) -> RunOptions: ...

    def run_options(self, seed: int, timesteps: int | None, budget: int) -> RunOptions: ...


class MethodTask(Protocol):
    """The part of :class:`~.tasks.Task` a method's run reads."""

    @property
    def method(self) -> str: ...

    @property
    def seed(self) -> int: ...

    @property
    def preferences(self) -> dict[str, float] | None: ...
