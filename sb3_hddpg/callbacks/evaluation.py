"""Periodic evaluation with the environment's own metrics, keeping the best model (SB3's EvalCallback, extended)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, EvalCallback

from sb3_hddpg.artifacts.io import atomic_write, atomic_write_json
from sb3_hddpg.evaluation import EVAL_SEED_BASE, evaluate


class MetricsEvalCallback(EvalCallback):
    """
    SB3's :class:`~stable_baselines3.common.callbacks.EvalCallback` with the env's metrics: every
    ``eval_freq`` calls it runs :func:`sb3_hddpg.evaluation.evaluate` on the same fixed seeds, logs every
    metric under ``eval/``, appends them to a JSON history, and saves the best model atomically.

    :param eval_env: a single (not vectorised) environment with the snake env's ``info``.
    :param n_eval_episodes: episodes per evaluation.
    :param eval_freq: evaluate every this many calls (steps of the vectorised env), from the run's first step.
    :param eval_seed: seed of the first evaluation episode.
    :param best_model_save_path: where ``best_model.zip`` goes (``None``: not saved).
    :param history_path: a JSON file for the evaluation history (``None``: not written).
    :param callback_on_new_best: called when the mean reward improves.
    :param callback_after_eval: called after every evaluation.
    :param deterministic: evaluate the deterministic policy.
    :param history: evaluations already made (when resuming), as written to ``history_path``.
    :param best_mean_reward: the best mean reward so far (when resuming).
    """

    def __init__(
        self,
        eval_env: gym.Env,
        n_eval_episodes: int = 5,
        eval_freq: int = 5000,
        eval_seed: int = EVAL_SEED_BASE,
        best_model_save_path: str | Path | None = None,
        history_path: str | Path | None = None,
        callback_on_new_best: BaseCallback | None = None,
        callback_after_eval: BaseCallback | None = None,
        deterministic: bool = True,
        history: list[dict[str, Any]] | None = None,
        best_mean_reward: float = -np.inf,
        verbose: int = 0,
    ) -> None:
        super().__init__(
            eval_env,
            callback_on_new_best=callback_on_new_best,
            callback_after_eval=callback_after_eval,
            n_eval_episodes=n_eval_episodes,
            eval_freq=eval_freq,
            best_model_save_path=None,
            deterministic=deterministic,
            warn=False,
            verbose=verbose,
        )
        self.single_eval_env = eval_env
        self.eval_seed = eval_seed
        self.best_model_path = Path(best_model_save_path) / "best_model.zip" if best_model_save_path else None
        self.history_path = Path(history_path) if history_path else None
        self.history: list[dict[str, Any]] = list(history or [])
        self.best_mean_reward = float(best_mean_reward)
        self.last_summary: dict[str, Any] = {}

    def _init_callback(self) -> None:
        pass  # EvalCallback's own compares env types and makes folders this one does not use

    def _on_step(self) -> bool:
        # Calls counted from the run's first step, not this learn() call's: a resumed run keeps evaluating on
        # the same grid, so the curves of different seeds share their points.
        calls = self.num_timesteps // self.model.n_envs
        if self.eval_freq > 0 and calls % self.eval_freq == 0:
            return self.run_evaluation()
        return True

    def run_evaluation(self) -> bool:
        """Evaluate now; return whether training should continue."""
        result = evaluate(
            self.model,
            self.single_eval_env,
            n_episodes=self.n_eval_episodes,
            seed=self.eval_seed,
            deterministic=self.deterministic,
        )
        self.last_summary = summary = result.summary()
        self.last_mean_reward = summary["mean_reward"]
        for key, value in summary.items():
            if isinstance(value, float):
                self.logger.record(f"eval/{key}", value)
            elif isinstance(value, dict):
                for name, rate in value.items():
                    self.logger.record(f"eval/{key}/{name}", rate)
        # The model's own count: the callback's copy is only updated inside learn().
        steps = int(self.model.num_timesteps)
        self.logger.record("time/total_timesteps", steps, exclude="tensorboard")
        self.logger.dump(steps)
        updates = model_updates(self.model)
        self.history.append(
            {"timesteps": steps, **summary, **({} if updates is None else {"updates": updates})}
        )
        if self.history_path is not None:
            atomic_write_json(self.history_path, self.history)

        continue_training = True
        # A model not updated yet is its random initialisation, whatever it scored: never the best.
        trained = updates is None or updates > 0
        if (
            trained
            and math.isfinite(summary["mean_reward"])
            and summary["mean_reward"] > self.best_mean_reward
        ):
            self.best_mean_reward = summary["mean_reward"]
            if self.best_model_path is not None:
                atomic_write(self.best_model_path, lambda tmp: self.model.save(tmp))
            if self.callback_on_new_best is not None:
                continue_training = self.callback_on_new_best.on_step()
        if self.callback is not None:
            continue_training = continue_training and self._on_event()
        return continue_training


def model_updates(model: object) -> int | None:
    """The gradient updates an SB3 (or SBX) model has made so far (``None``: the model does not count them)."""
    updates = getattr(model, "_n_updates", None)
    return int(updates) if isinstance(updates, (int, np.integer)) else None


def best_entry(history: list[dict[str, Any]]) -> dict[str, Any]:
    """
    The evaluation whose model a run keeps as its best: the highest mean reward among those taken after at
    least one update, else the last.

    :param history: the evaluations, as :class:`MetricsEvalCallback` records them.
    """
    trained = [entry for entry in history if entry.get("updates", 1) > 0]
    return max(trained, key=lambda h: h["mean_reward"]) if trained else history[-1]
