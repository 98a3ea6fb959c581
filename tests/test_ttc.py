"""The time-to-collision switch (hddpg_zoo.baselines.ttc): the rule, its reading of highway-env's observation."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

from hddpg_zoo.baselines.ttc import DecisionStates, KinematicsScales, TTCSwitch, time_to_collision

SCALES = KinematicsScales(
    features=("presence", "x", "y", "vx", "vy"),
    x_range=(-200.0, 200.0),
    y_range=(-12.0, 12.0),
    vx_range=(-80.0, 80.0),
)


def observation(*others: tuple[float, float, float]) -> np.ndarray:
    """A normalised Kinematics observation: the ego at 25 m/s, then (dx, dy, dvx) per other car, in metres."""
    rows = np.zeros((5, 5), dtype=np.float32)
    rows[0] = [1.0, 0.5, 0.0, 25.0 / 80.0, 0.0]
    for i, (dx, dy, dvx) in enumerate(others, start=1):
        rows[i] = [1.0, dx / 200.0, dy / 12.0, dvx / 80.0, 0.0]
    return rows


class Constant:
    """A worker that always takes one discrete action."""

    def __init__(self, action: int) -> None:
        self.action = action

    def predict(self, observation, state=None, episode_start=None, deterministic=False):
        batch = np.asarray(observation).ndim == 3
        n = np.asarray(observation).shape[0] if batch else None
        return (np.full(n, self.action) if batch else np.asarray(self.action)), None


def test_time_to_collision_reads_gap_and_closing_speed_of_the_car_ahead_in_lane():
    # 25 m ahead (20 m bumper to bumper), closing at 5 m/s: 4 s; a closer car in the next lane is ignored,
    # and so are a car behind and a faster one ahead.
    obs = observation((25.0, 0.5, -5.0), (10.0, 4.0, -10.0), (-15.0, 0.0, 5.0), (12.0, -0.3, 2.0))
    assert time_to_collision(obs, SCALES)[0] == pytest.approx(4.0, rel=1e-4)
    assert math.isinf(time_to_collision(observation(), SCALES)[0])
    # Flat and batched observations read the same.
    flat = obs.reshape(-1)
    assert time_to_collision(flat, SCALES)[0] == pytest.approx(4.0, rel=1e-4)
    batch = np.stack([obs, observation((8.0, 0.0, -6.0))])
    assert time_to_collision(batch, SCALES) == pytest.approx([4.0, 0.5], rel=1e-4)


def test_switch_hands_over_below_threshold_with_hysteresis():
    switch = TTCSwitch(Constant(3), Constant(4), SCALES, threshold=2.0, hysteresis=1.0)
    far, near, middle = (
        observation((45.0, 0.0, -5.0)),
        observation((10.0, 0.0, -5.0)),
        observation((17.5, 0.0, -5.0)),
    )
    assert int(switch.predict(far)[0]) == 3 and switch.last_selection == "fast"
    assert int(switch.predict(near)[0]) == 4 and switch.last_selection == "safe"
    assert int(switch.predict(middle)[0]) == 4  # 2.5 s: within the hysteresis band, stays safe
    assert int(switch.predict(far)[0]) == 3
    actions, _ = switch.predict(np.stack([far, near]))
    assert actions.tolist() == [3, 4]
    with pytest.raises(ValueError, match="threshold"):
        switch.threshold = 0.0
    with pytest.raises(ValueError, match="lacks"):
        KinematicsScales(("presence", "x"), (-1, 1), (-1, 1), (-1, 1))


def test_decision_states_count_choices_by_time_to_collision():
    switch = TTCSwitch(Constant(3), Constant(4), SCALES, threshold=2.0)
    counted = DecisionStates(switch, SCALES, close=2.0, clear=6.0)
    for obs in (observation((10.0, 0.0, -5.0)), observation(), observation(), observation((30.0, 0.0, -5.0))):
        counted.predict(obs)
    shares = counted.shares("safe")
    assert shares["close_share"] == 1.0 and shares["clear_share"] == 0.0 and shares["ratio"] is None
    assert shares["close_decisions"] == 1 and shares["clear_decisions"] == 2  # 5 s is neither band
    assert counted.threshold == 2.0  # every other attribute is the policy's
    # By default the road is clear only with no car ahead closing in at all.
    strict = DecisionStates(TTCSwitch(Constant(3), Constant(4), SCALES), SCALES)
    for obs in (observation((30.0, 0.0, -5.0)), observation(), observation((200.0, 0.0, -1.0))):
        strict.predict(obs)
    assert strict.shares("fast")["clear_decisions"] == 1 and strict.shares("fast")["clear_seconds"] is None


class HoldingManager:
    """A hierarchy's shape: it decides (a new ``last_manager_action``) every second step and holds the choice."""

    def __init__(self) -> None:
        self.steps = 0
        self.last_manager_action: np.ndarray | None = None
        self.last_selection: str | None = None

    def predict(self, observation, state=None, episode_start=None, deterministic=False):
        if self.steps % 2 == 0:
            self.last_manager_action = np.zeros(1)
            self.last_selection = "safe" if self.steps % 4 == 0 else "fast"
        self.steps += 1
        return np.asarray(0), None


def test_decision_states_count_a_held_choice_once():
    counted = DecisionStates(HoldingManager(), SCALES, close=3.0)
    close = observation((10.0, 0.0, -5.0))
    for _ in range(8):  # four decisions, all with a car 1 s ahead
        counted.predict(close)
    assert counted.shares("safe")["close_decisions"] == 4
    assert counted.shares("safe")["close_share"] == 0.5


def test_scales_from_a_highway_env_through_the_adapter():
    pytest.importorskip("highway_env")
    from sb3_hddpg.envs.terms_env import terms_env

    shared = terms_env("mo-highway-fast-v0", terms=["speed", "lane", "collision"])
    env = gym.make(shared.env_id, **shared.env_kwargs)
    try:
        obs, _ = env.reset(seed=3)
        scales = KinematicsScales.from_env(env)
        assert scales.x_range == (-200.0, 200.0) and scales.lane_width == 4.0
        # The rule's figure agrees with the simulator's own vehicles, step after step.
        highway = env.unwrapped.inner.unwrapped
        for _ in range(4):
            obs, *_ = env.step(3)  # faster: the gap to the car ahead closes
            ego = highway.vehicle
            observed = time_to_collision(obs, scales)[0]
            if math.isfinite(observed):
                ahead = [
                    (v.position[0] - ego.position[0] - 5.0) / (ego.velocity[0] - v.velocity[0])
                    for v in highway.road.vehicles
                    if v is not ego
                    and v.position[0] - ego.position[0] > 0
                    and abs(v.position[1] - ego.position[1]) < 2.0
                    and ego.velocity[0] > v.velocity[0]
                ]
                assert min(ahead) == pytest.approx(observed, rel=1e-3)
    finally:
        env.close()
    with pytest.raises(ValueError, match="Kinematics"):
        KinematicsScales.from_env(gym.make("CartPole-v1"))
