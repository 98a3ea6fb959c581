"""The actor's action penalty (ActionL2Penalty): mechanism, config key, and its effect on a trained actor."""

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import DDPG, SAC, TD3

from sb3_hddpg.callbacks import ActionL2Penalty, apply_action_l2
from sb3_hddpg.callbacks.action_penalty import action_penalty
from sb3_hddpg.training.config import parse_block
from sb3_hddpg.training.config_values import ConfigError

PATH = "sb3_hddpg.callbacks.ActionL2Penalty"


def _model(cls=DDPG):
    return cls("MlpPolicy", gym.make("Pendulum-v1"), policy_kwargs={"net_arch": [8]}, seed=0, device="cpu")


def test_penalty_wraps_only_the_actor_objective_and_is_idempotent():
    model = _model()
    obs = torch.rand(5, 3)
    actions = torch.rand(5, 1) * 2 - 1
    plain = model.critic.q1_forward(obs, actions).detach()
    critic_values = [q.detach() for q in model.critic(obs, actions)]
    for _ in range(2):  # applying twice must not double the penalty
        apply_action_l2(model, 0.5)
    penalised = model.critic.q1_forward(obs, actions).detach()
    torch.testing.assert_close(penalised, plain - 0.5 * actions.pow(2).mean(-1, keepdim=True))
    # The critic's own values (its loss and targets) are untouched.
    for before, after in zip(critic_values, model.critic(obs, actions)):
        torch.testing.assert_close(before, after.detach())
    apply_action_l2(model, 0.0)
    torch.testing.assert_close(model.critic.q1_forward(obs, actions).detach(), plain)


def test_penalty_shrinks_a_saturating_actor():
    # Pendulum's critic early on has a steep action slope; DDPG's actor then saturates. With a large
    # penalty the same seed ends with much smaller actions.
    magnitudes = {}
    for coefficient in (0.0, 50.0):
        model = _model(TD3)
        model.learn(600, callback=ActionL2Penalty(coefficient))
        obs = np.stack([model.observation_space.sample() for _ in range(64)])
        actions, _ = model.predict(obs, deterministic=True)
        magnitudes[coefficient] = float(np.abs(actions).mean())
    assert magnitudes[50.0] < 0.5 * magnitudes[0.0], magnitudes


def test_penalty_in_sbx_adds_exactly_its_term_to_the_actor_loss_and_is_removable():
    sbx = pytest.importorskip("sbx")
    model, observations, plain_loss, penalised_loss = _sbx_actor_losses(0.5, None, times=2)  # idempotent
    assert isinstance(model, sbx.DDPG) and type(model) is not sbx.DDPG
    assert type(model).__module__.startswith("sbx")  # still told apart from SB3 models by module
    actions = np.asarray(model.policy.actor_state.apply_fn(model.policy.actor_state.params, observations))
    assert float(penalised_loss) - float(plain_loss) == pytest.approx(
        0.5 * float((actions**2).mean()), rel=1e-4
    )
    model.learn(150)  # trains with the penalised update
    apply_action_l2(model, 0.0)
    assert type(model) is sbx.DDPG


def test_a_margin_frees_the_interior_and_still_penalises_the_flat_ends():
    margin = 1.5
    inside = torch.tensor([[0.0, 0.5, -0.9, 0.905]])  # tanh(1.5) = 0.9051
    assert float(action_penalty(inside, margin)) == 0.0
    assert float(action_penalty(inside, None)) > 0.0  # the plain L2 pulls every action towards 0
    outside = torch.tensor([[0.99, -0.999]], requires_grad=True)
    value = action_penalty(outside, margin)
    expected = ((np.arctanh(0.99) - margin) ** 2 + (np.arctanh(0.999) - margin) ** 2) / 2
    assert float(value) == pytest.approx(expected, rel=1e-4)
    value.sum().backward()
    assert outside.grad is not None and outside.grad[0, 0] > 0 and outside.grad[0, 1] < 0  # towards 0
    saturated = action_penalty(torch.tensor([[1.0, -1.0]]), margin)
    assert torch.isfinite(saturated).all() and float(saturated) > 0  # exact ±1 stays finite


def test_a_margin_reaches_the_actor_loss_on_both_backends():
    model = _model()
    obs = torch.rand(4, 3)
    actions = torch.tensor([[0.2], [0.95], [-0.999], [0.0]])
    plain = model.critic.q1_forward(obs, actions).detach()
    apply_action_l2(model, 2.0, margin=1.0)
    penalised = model.critic.q1_forward(obs, actions).detach()
    torch.testing.assert_close(penalised, plain - 2.0 * action_penalty(actions, 1.0))
    assert float((plain - penalised)[0]) == 0.0 and float((plain - penalised)[3]) == 0.0
    pytest.importorskip("sbx")
    model, observations, plain_loss, penalised_loss = _sbx_actor_losses(0.5, 0.1)
    sampled = np.asarray(model.policy.actor_state.apply_fn(model.policy.actor_state.params, observations))
    expected = 0.5 * float(action_penalty(torch.as_tensor(sampled), 0.1).mean())
    assert expected > 0  # some of the untrained actor's actions lie beyond tanh(0.1)
    assert float(penalised_loss) - float(plain_loss) == pytest.approx(expected, rel=1e-3, abs=1e-7)
    model.learn(150)


def test_config_callback_key_sets_the_margin():
    parsed = parse_block({"n_timesteps": 10, "callback": [{PATH: {"coefficient": 2.0, "margin": 1.5}}]}, DDPG)
    assert (parsed.action_l2, parsed.action_l2_margin) == (2.0, 1.5)
    (callback,) = parsed.callbacks()
    assert (callback.coefficient, callback.margin) == (2.0, 1.5)
    assert parse_block({"n_timesteps": 10, "callback": PATH}, DDPG).action_l2_margin is None


def test_penalty_refuses_algorithms_without_a_deterministic_actor():
    with pytest.raises(ValueError, match="DDPG and TD3"):
        apply_action_l2(_model(SAC), 0.1)
    with pytest.raises(ValueError, match="coefficient"):
        ActionL2Penalty(-1.0)
    with pytest.raises(ValueError, match="margin"):
        ActionL2Penalty(1.0, margin=-0.5)


@pytest.mark.parametrize(
    "callback, expected",
    [
        (PATH, 0.1),
        ([{PATH: {"coefficient": 0.3}}], 0.3),
        ([{PATH: None}], 0.1),
    ],
)
def test_config_callback_key_sets_the_penalty(callback, expected):
    parsed = parse_block({"n_timesteps": 10, "callback": callback}, DDPG)
    assert parsed.action_l2 == expected
    assert isinstance(parsed.callbacks()[0], ActionL2Penalty)


@pytest.mark.parametrize(
    "callback, message",
    [
        ("os.system", "Unknown callback"),
        ([{PATH: {"coefficient": -1}}], "coefficient"),
        ([{PATH: {"coefficient": "x"}}], "coefficient"),
        ([{PATH: {"other": 1}}], "take only"),
        ([{PATH: {"coefficient": 1, "margin": 0}}], "margin"),
        ([{PATH: {"coefficient": 1, "margin": "x"}}], "margin"),
        ([42], "class paths"),
    ],
)
def test_bad_callback_entries_are_refused(callback, message):
    with pytest.raises(ConfigError, match=message):
        parse_block({"n_timesteps": 10, "callback": callback}, DDPG)


def _sbx_actor_losses(coefficient: float, margin: float | None, times: int = 1):
    """An untrained SBX DDPG on Pendulum, its actor's loss on fixed observations before and after the
    penalty was applied ``times`` times (the same parameters and key both times)."""
    import jax
    import sbx

    model = sbx.DDPG("MlpPolicy", gym.make("Pendulum-v1"), policy_kwargs={"net_arch": [8]}, seed=0)
    observations = np.stack([model.observation_space.sample() for _ in range(32)]).astype(np.float32)
    key = jax.random.PRNGKey(0)
    state = model.policy.actor_state, model.policy.qf_state
    _, _, plain_loss, _ = type(model).update_actor(*state, observations, key)
    for _ in range(times):
        apply_action_l2(model, coefficient, margin=margin)
    _, _, penalised_loss, _ = type(model).update_actor(*state, observations, key)
    return model, observations, plain_loss, penalised_loss
