"""The protocol's hddpg-gpi-raw methods: raw-objective critics, GPI over the workers' own actions, held or not."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mo_gymnasium")

from hddpg_zoo.benchmark.morl_gpi import STEP_QUANTUM
from hddpg_zoo.benchmark.morl_gpi_raw import RawGpiPolicy, train_gpi_raw
from hddpg_zoo.benchmark.morl_protocol import GAMMA
from hddpg_zoo.benchmark.morl_sides import PROTOCOL_METHODS, SideRun, play_front

ENV = "deep-sea-treasure-concave-v0"


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory):
    """hddpg-gpi-raw on deep-sea-treasure, past DQN's 1,000 learning starts for each of its two workers."""
    return train_gpi_raw(SideRun(ENV, True, GAMMA, 2402, 0, tmp_path_factory.mktemp("raw")))


def test_the_per_term_workers_share_the_budget(trained):
    share = 2402 // 2 // STEP_QUANTUM * STEP_QUANTUM
    assert trained.env_steps == {"workers/obj0": share, "workers/obj1": share, "bounds": 0}
    assert PROTOCOL_METHODS["hddpg-gpi-raw-hold"].train.keywords == {"hold": True}


def test_the_critics_value_the_raw_objectives(trained):
    selector = trained.policy.selector
    assert not selector.over_actions and selector.terms == ("obj0", "obj1")
    env = trained.env.make()
    try:
        obs, _ = env.reset(seed=0)
    finally:
        env.close()
    for worker, critic in zip(selector.workers, selector.critics):
        value = critic.values(np.asarray(obs, dtype=np.float32)[None])[0][int(worker.act(obs))]
        # Time is -1 a step, raw: its value is at most the first step's -1 (normalised it would be >= 0).
        assert value[1] <= -0.5 and value[0] >= -1.0


def test_a_held_worker_plays_the_whole_episode_and_the_next_is_chosen_anew(trained):
    held = RawGpiPolicy(trained.policy.selector, ["obj0", "obj1"], hold=True)
    held.set_weights([0.0, 1.0])
    env = trained.env.make()
    try:
        obs, _ = env.reset(seed=0)
        held.act(obs)
        chosen = held.held
        assert chosen is not None
        for _ in range(5):
            obs, *_ = env.step(int(held.act(obs)))
            assert held.held == chosen
            assert int(held.act(obs)) == int(held.selector.workers[chosen].act(obs))
    finally:
        env.close()
    held.reset_episode()
    assert held.held is None


def test_both_methods_play_the_protocols_weights(trained):
    for hold in (False, True):
        policy = RawGpiPolicy(trained.policy.selector, ["obj0", "obj1"], hold=hold)
        env = trained.env.make()
        try:
            discounted, returns = play_front(policy, env, [[1.0, 0.0], [0.0, 1.0]], 1, 0, GAMMA)
        finally:
            env.close()
        assert len(discounted) == 2 and all(r[0][1] <= -1.0 and r[0][0] >= 0.0 for r in returns)
