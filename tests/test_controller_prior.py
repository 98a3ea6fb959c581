"""The actor's prior towards a hand-written controller (ControllerPrior): term, config key, its pull, both backends."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import DDPG

from sb3_hddpg.callbacks import ActionL2Penalty, ControllerPrior, apply_action_l2
from sb3_hddpg.callbacks.actor_terms import actor_terms
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.envs.snake.controllers import FieldAvoider, IKReacher, make_controller
from sb3_hddpg.training.backends import sbx_installed
from sb3_hddpg.training.config import parse_block
from sb3_hddpg.training.config_values import ConfigError

PATH = "sb3_hddpg.callbacks.ControllerPrior"
GOAL_VIEW = ["joint_positions", "ee_to_goal", "goal_touched"]


def _env():
    return gym.make("hddpg/SnakeGoal-v0", observe=GOAL_VIEW)


def _model(cls=DDPG, seed=0):
    return cls(
        "MlpPolicy", _env(), policy_kwargs={"net_arch": [32, 32]}, learning_starts=100, batch_size=64,
        gamma=0.7, seed=seed, device="cpu",
    )  # fmt: skip


def _ik_distance(model, observations):
    """Mean squared distance of the model's deterministic actions to the IK reacher's commands."""
    layout = state_layout_of(_env()).view(GOAL_VIEW)
    actions, _ = model.predict(observations, deterministic=True)
    return float(np.mean((actions - IKReacher(layout).predict(observations)[0]) ** 2))


def test_the_view_layout_feeds_the_controller_the_components_it_reads():
    layout = state_layout_of(_env())
    view = layout.view(GOAL_VIEW)
    assert view.size == 15 and view["ee_to_goal"] == slice(12, 14) and view["goal_touched"] == slice(14, 15)
    with pytest.raises(ValueError, match="reads \\['ee_to_goal'\\]"):
        make_controller("ik", layout.view(["joint_positions"]))
    with pytest.raises(ValueError, match="Unknown controller"):
        make_controller("pid", view)
    with pytest.raises(ValueError, match="field controller reads \\['joint_obstacle_vectors'"):
        make_controller("field", view)
    avoid_view = layout.view(["joint_positions", "joint_obstacle_vectors", "joint_obstacle_distances"])
    assert isinstance(make_controller("field", avoid_view), FieldAvoider)


def test_the_prior_is_a_term_of_the_actor_objective_beside_the_action_penalty():
    model = _model()
    prior = ControllerPrior("ik", coefficient=3.0)
    prior.init_callback(model)
    prior.on_training_start({}, {})
    apply_action_l2(model, 0.5)
    assert set(actor_terms(model)) == {"controller", "action_l2"}
    env = _env()
    obs = torch.as_tensor(np.array([env.reset(seed=s)[0] for s in range(8)]), dtype=torch.float32)
    actions = torch.rand(8, 6) * 2 - 1
    target = torch.as_tensor(IKReacher(state_layout_of(_env()).view(GOAL_VIEW)).predict(obs.numpy())[0])
    apply_action_l2(model, 0.0)
    original = model.critic._sb3_hddpg_q1_forward(obs, actions).detach()
    expected = original - 3.0 * (actions - target).pow(2).mean(-1, keepdim=True)
    torch.testing.assert_close(model.critic.q1_forward(obs, actions).detach(), expected)


@pytest.mark.parametrize("backend", ["sb3", "sbx"])
def test_the_prior_pulls_the_actor_towards_the_controller(backend):
    if backend == "sbx" and not sbx_installed():
        pytest.skip("SBX is not installed")
    if backend == "sbx":
        import sbx

        cls = sbx.DDPG
    else:
        cls = DDPG
    models = {}
    for coefficient in (0.0, 50.0):
        models[coefficient] = _model(cls)
        models[coefficient].learn(1500, callback=ControllerPrior("ik", coefficient=coefficient))
    assert set(actor_terms(models[50.0])) == {"controller"} and not actor_terms(models[0.0])
    # Both actors on the observations the prior was trained on.
    observations = models[50.0].replay_buffer.observations[:1500, 0]
    distances = {c: _ik_distance(model, observations) for c, model in models.items()}
    assert distances[50.0] < 0.5 * distances[0.0], distances


def test_the_config_key_builds_the_prior_and_refuses_bad_entries():
    block = {"n_timesteps": 10, "callback": [{PATH: {"controller": "ik", "coefficient": 5}}, ActionL2Penalty.__module__.rpartition(".")[0] + ".ActionL2Penalty"]}  # fmt: skip
    parsed = parse_block(block, DDPG)
    assert parsed.controller_prior == ("ik", 5.0) and parsed.action_l2 == 0.1
    assert [type(c).__name__ for c in parsed.callbacks()] == ["ActionL2Penalty", "ControllerPrior"]
    assert (
        parse_block({"n_timesteps": 10, "callback": [{PATH: {"coefficient": 0}}]}, DDPG).controller_prior
        is None
    )
    for entry, message in (
        ({"controller": "pid"}, "Unknown controller"),
        ({"coefficient": -1}, "coefficient"),
        ({"margin": 1.0}, "take only"),
    ):
        with pytest.raises(ConfigError, match=message):
            parse_block({"n_timesteps": 10, "callback": [{PATH: entry}]}, DDPG)


def test_another_env_is_refused_in_one_line():
    model = DDPG("MlpPolicy", gym.make("Pendulum-v1"), policy_kwargs={"net_arch": [8]}, seed=0, device="cpu")
    with pytest.raises(ValueError, match="no snake state layout"):
        model.learn(10, callback=ControllerPrior("ik", coefficient=1.0))
    with pytest.raises(ValueError, match="coefficient"):
        ControllerPrior("ik", coefficient=float("nan"))
