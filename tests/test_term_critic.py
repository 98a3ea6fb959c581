"""Per-term critics: TD policy evaluation per term, stored in the worker's zip without breaking SB3's loader."""

import io
import zipfile

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import DDPG, DQN

from sb3_hddpg.artifacts.limits import LimitError
from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.artifacts.provenance import sha256_file
from sb3_hddpg.artifacts.safe_load import load_model
from sb3_hddpg.artifacts.term_critic import (
    TERM_CRITIC_MEMBER,
    TermCritic,
    TermCriticSpec,
    read_term_critic,
    with_term_critic,
)
from sb3_hddpg.artifacts.transitions import Transitions
from sb3_hddpg.envs.contract import state_layout_of
from sb3_hddpg.training.term_critic import TermCriticOptions, fit_term_critic
from sb3_hddpg.training.workers import train_workers

TINY = {"timesteps": 300, "eval_freq": 0, "eval_episodes": 1}
SMALL_CRITIC = TermCriticOptions(steps=200, batch_size=32, net_arch=(16,))


def _transitions(obs, actions, terms, continues):
    n = len(obs)
    return Transitions(
        obs.astype(np.float32),
        actions,
        obs[::-1].copy().astype(np.float32),
        np.tile(np.asarray(terms, np.float32), (n, 1)),
        np.full(n, continues, np.float32),
    )


def test_td_reaches_the_discounted_sum_of_constant_terms():
    # Continuing with constant terms (0.5, 0.1): Q = r / (1 - gamma) = (1.0, 0.2) at the critic's gamma 0.5,
    # whatever pi is and whatever the worker's own discount (0.9 here).
    env = gym.make("Pendulum-v1")
    policy = DDPG("MlpPolicy", env, gamma=0.9, policy_kwargs={"net_arch": [16]}, seed=0)
    rng = np.random.default_rng(0)
    obs = rng.uniform(-1, 1, (256, 3))
    actions = rng.uniform(-1, 1, (256, 1)).astype(np.float32)
    options = TermCriticOptions(steps=1500, batch_size=64, net_arch=(32,), tau=0.1, gamma=0.5)
    critic, facts = fit_term_critic(policy, _transitions(obs, actions, (0.5, 0.1), 1.0), ["a", "b"], options)
    env_actions = rng.uniform(-2, 2, (16, 1))
    values = critic.values(obs[:16], env_actions)
    np.testing.assert_allclose(values, np.tile([1.0, 0.2], (16, 1)), atol=0.08)
    assert facts["steps"] == 1500 and facts["transitions"] == 256


def test_a_discrete_critic_values_every_action():
    # Terminal transitions: Q(s, a) = r for the stored actions.
    env = gym.make("CartPole-v1")
    policy = DQN("MlpPolicy", env, policy_kwargs={"net_arch": [16]}, seed=0)
    obs = np.random.default_rng(1).uniform(-0.05, 0.05, (128, 4))
    actions = np.zeros((128, 1), dtype=np.int64)
    options = TermCriticOptions(steps=800, batch_size=64, net_arch=(16,), tau=0.2)
    critic, _ = fit_term_critic(policy, _transitions(obs, actions, (1.0, 0.0), 0.0), ["x", "y"], options)
    values = critic.values(obs[:8])
    assert values.shape == (8, 2, 2)
    np.testing.assert_allclose(values[:, 0], np.tile([1.0, 0.0], (8, 1)), atol=0.1)


def test_every_worker_gets_a_critic_in_its_zip_that_sb3_still_opens(tmp_path):
    manifest = train_workers(
        tmp_path,
        workers=["goal"],
        weights=[{"goal": 1, "avoid": 1}],
        seed=2,
        term_critic=SMALL_CRITIC,
        **TINY,
    ).manifest
    for name in ("goal", "mix-goal50-avoid50"):
        entry = manifest["workers"][name]
        path = tmp_path / "workers" / f"{name}.zip"
        assert (
            entry["term_critic"]["terms"] == ["goal", "avoid"]
            and entry["term_critic"]["member"] == TERM_CRITIC_MEMBER
        )
        assert entry["sha256"] == sha256_file(path)  # the hash covers the critic
        with zipfile.ZipFile(path) as archive:
            assert TERM_CRITIC_MEMBER in archive.namelist()
        model = DDPG.load(path)  # SB3's own loader still opens a plain model
        assert model.num_timesteps >= 300
        load_model(path, spec=entry["spec"])  # and so does the weights-only loader
    workers = load_workers(tmp_path)
    assert set(workers.critics) == {"goal", "mix-goal50-avoid50"}
    env = workers.make_env()
    full = env.reset(seed=0)[0]
    obs = full[state_layout_of(env).indices(workers.states["goal"])] if "goal" in workers.states else full
    action, _ = workers["goal"].predict(obs, deterministic=True)
    assert workers.critics["goal"].values(obs, action).shape == (1, 2)


def test_a_tampered_critic_is_refused(tmp_path):
    critic = TermCritic(
        TermCriticSpec.for_spaces(
            ["a", "b"], gym.spaces.Box(-1, 1, (3,)), gym.spaces.Box(-1, 1, (1,)), [8], 0.9
        )
    )
    model = DDPG("MlpPolicy", gym.make("Pendulum-v1"), policy_kwargs={"net_arch": [8]})
    buffer = io.BytesIO()
    model.save(buffer)
    data = with_term_critic(buffer.getvalue(), critic)
    assert read_term_critic(data, "w.zip").spec == critic.spec
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    for bad in (b"not an npz", critic.to_bytes()[:100]):
        out = io.BytesIO()
        with zipfile.ZipFile(out, "w") as archive:
            for name, content in members.items():
                archive.writestr(name, bad if name == TERM_CRITIC_MEMBER else content)
        with pytest.raises(LimitError, match=r"w\.zip"):
            read_term_critic(out.getvalue(), "w.zip")
    other = TermCritic(critic.spec.__class__(**{**critic.spec.__dict__, "net_arch": (4,)}))
    arrays = dict(np.load(io.BytesIO(other.to_bytes())))
    arrays["spec"] = np.load(io.BytesIO(critic.to_bytes()))["spec"]  # a spec that does not build these shapes
    raw = io.BytesIO()
    np.savez(raw, **arrays)
    with pytest.raises(LimitError, match="other parameters"):
        TermCritic.from_bytes(raw.getvalue(), "w.zip")


def test_a_discrete_critic_of_a_worker_with_a_grid_observation_is_fitted_on_flat_transitions():
    # Highway's DQN workers see a 5x5 grid; transitions are stored flat, their next actions asked in its shape.
    env = gym.wrappers.ReshapeObservation(gym.make("CartPole-v1"), (2, 2))
    policy = DQN("MlpPolicy", env, policy_kwargs={"net_arch": [8]}, seed=0)
    obs = np.random.default_rng(2).uniform(-0.05, 0.05, (32, 4))
    transitions = _transitions(obs, np.ones((32, 1), dtype=np.int64), (1.0, 0.0), 1.0)
    critic, facts = fit_term_critic(
        policy, transitions, ["x", "y"], TermCriticOptions(steps=5, net_arch=(8,))
    )
    assert critic.spec.obs_dim == 4 and critic.values(obs[:3].reshape(3, 2, 2)).shape == (3, 2, 2)
    assert facts["transitions"] == 32
