"""Printed tables show words and one unit per quantity: no raw keys, no fractions beside percentages."""

from __future__ import annotations

import re

import gymnasium as gym
import pytest

from sb3_hddpg.baselines import JacobianReacher
from sb3_hddpg.evaluation import evaluate
from sb3_hddpg.metric_labels import METRIC_LABELS, metric_label, summary_rows


@pytest.fixture(scope="module")
def summary():
    env = gym.make("hddpg/SnakeReach-v0", max_episode_steps=30)
    result = evaluate(JacobianReacher(env.unwrapped.state_layout), env, n_episodes=2)
    summary = result.summary()
    summary["selection_rate"] = {"avoid": 0.006, "goal": 0.994}  # as a hierarchy's summary has it
    return summary


def test_every_summary_key_has_words_and_a_unit(summary):
    numeric = {k for k, v in summary.items() if isinstance(v, float)} - {"std_reward"}
    assert numeric <= set(METRIC_LABELS), sorted(numeric - set(METRIC_LABELS))
    for key in numeric:
        assert "_" not in metric_label(key).label


def test_rows_show_rates_as_percentages_with_the_unit_beside(summary):
    rows = {label: (value, unit) for label, value, unit in summary_rows(summary)}
    assert all("_" not in label for label in rows), list(rows)
    assert all("%" not in value for value, _ in rows.values())  # the unit column carries it
    touch, unit = rows["touching the goal"]
    assert unit == "% of steps" and float(touch) == pytest.approx(100 * summary["goal_touch_rate"], abs=0.05)
    assert rows["steps run by the goal worker"] == ("99.4", "% of steps")
    assert rows["steps run by the avoid worker"] == ("0.6", "% of steps")
    success, unit = rows["success: goal touched, no contact"]
    assert unit == "% of episodes" and float(success) in (0.0, 50.0, 100.0)
    # On the snake's reach env the env's reward is the return of the normalised terms: one row, both names.
    reward, unit = rows["reward (the env's own) = return (normalised terms)"]
    assert unit == "per episode" and re.fullmatch(r"-?\d+\.\d ± \d+\.\d", reward)
    # Keys added later (by another metric) still print in words, never as a raw key.
    assert summary_rows({"state_dependence": 0.25}) == [("state dependence", "0.250", "")]
