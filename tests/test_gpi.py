"""Generalized policy improvement: the selector on known critics, and GPI bundles over trained workers."""

import dataclasses
import io
import json
import shutil
import subprocess
import sys
import zipfile

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import DDPG

from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.artifacts.term_critic import TERM_CRITIC_MEMBER, TermCritic, TermCriticSpec
from sb3_hddpg.hierarchy.frozen import FrozenWorker
from sb3_hddpg.hierarchy.gpi import GpiSelector
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.training.term_critic import TermCriticOptions
from sb3_hddpg.training.workers import train_workers
from tests.cli_batch import run_batch


def constant_critic(values, n_actions=0):
    """A critic whose output is ``values`` whatever its input (its last layer's bias)."""
    spec = TermCriticSpec(
        ("goal", "avoid"),
        3,
        n_actions,
        () if n_actions else (-1.0, -1.0),
        () if n_actions else (1.0, 1.0),
        (4,),
        0.9,
    )
    critic = TermCritic(spec)
    with torch.no_grad():
        last = critic.net[-1]
        last.weight.zero_()
        last.bias.copy_(torch.as_tensor(np.ravel(values), dtype=torch.float32))
    return critic


class Fixed:
    """A worker that always takes one action (an index for discrete actions)."""

    def __init__(self, action):
        self.action = np.asarray(action)

    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        return self.action.copy(), None


def test_gpi_picks_the_worker_whose_values_weigh_most():
    workers = [
        FrozenWorker(Fixed(np.float32([0.5, 0.5]))),
        FrozenWorker(Fixed(np.float32([-0.5, 0.0]))),
    ]
    gpi = GpiSelector(workers, [constant_critic([10.0, 2.0]), constant_critic([4.0, 6.0])])
    obs = np.zeros(3, dtype=np.float32)
    chosen, action = gpi.select(obs, {"goal": 0.9, "avoid": 0.1})
    assert chosen == 0 and np.allclose(action, [0.5, 0.5])
    chosen, action = gpi.select(obs, {"goal": 0.2, "avoid": 0.8})
    assert chosen == 1 and np.allclose(action, [-0.5, 0.0])


def test_gpi_over_actions_for_discrete_workers():
    workers = [
        FrozenWorker(Fixed(np.int64(0))),
        FrozenWorker(Fixed(np.int64(1))),
    ]
    # Worker 0 values action 2 most for goal; worker 1 values action 1 most for avoid.
    first = constant_critic([[0, 0], [0, 0], [5, 0]], n_actions=3)
    second = constant_critic([[0, 0], [0, 4], [1, 1]], n_actions=3)
    gpi = GpiSelector(workers, [first, second])
    obs = np.zeros(3, dtype=np.float32)
    assert gpi.select(obs, {"goal": 1.0, "avoid": 0.0}) == (0, 2)  # not worker 0's own action 0
    chosen, action = gpi.select(obs, {"goal": 0.1, "avoid": 0.9})
    assert (chosen, int(action)) == (1, 1)


def test_gpi_refuses_critics_that_do_not_fit():
    worker = FrozenWorker(Fixed(np.zeros(2, np.float32)))
    other = TermCritic(TermCriticSpec(("speed", "energy"), 3, 0, (-1.0, -1.0), (1.0, 1.0), (4,), 0.9))
    with pytest.raises(ValueError, match="terms"):
        GpiSelector([worker, worker], [constant_critic([1, 1]), other])
    other_discount = TermCritic(TermCriticSpec(("goal", "avoid"), 3, 0, (-1.0, -1.0), (1.0, 1.0), (4,), 0.5))
    with pytest.raises(ValueError, match="one discount"):
        GpiSelector([worker, worker], [constant_critic([1, 1]), other_discount])
    with pytest.raises(ValueError, match="one critic per worker"):
        GpiSelector([worker, worker], [constant_critic([1, 1])])


@pytest.fixture(scope="module")
def support(tmp_path_factory):
    root = tmp_path_factory.mktemp("support")
    critic = TermCriticOptions(steps=200, batch_size=32, net_arch=(16,))
    train_workers(
        root,
        weights=[{"goal": 1}, {"avoid": 1}, {"goal": 0.7, "avoid": 0.3}],
        seed=4,
        timesteps=300,
        eval_freq=0,
        eval_episodes=1,
        term_critic=critic,
    )
    return root


def test_a_gpi_bundle_acts_at_any_preference_in_a_fresh_process(support, tmp_path):
    workers = load_workers(support)
    gpi = Hierarchy.gpi(workers, {"goal": 0.7, "avoid": 0.3})
    assert gpi.manager is None and gpi.preferences == pytest.approx({"goal": 0.7, "avoid": 0.3})
    path = gpi.save(tmp_path / "gpi.zip")
    env = gym.make("hddpg/SnakeReach-v0")
    obs = np.stack([env.reset(seed=s)[0] for s in range(6)])
    np.save(tmp_path / "obs.npy", obs)
    expected = {}
    for text, preference in (("a", {"goal": 0.9, "avoid": 0.1}), ("b", {"goal": 0.05, "avoid": 0.95})):
        gpi.set_preference(preference)
        expected[text] = (gpi.predict(obs)[0], [gpi.probabilities(o) for o in obs])
    script = (
        "import numpy as np; from sb3_hddpg import Hierarchy;"
        f"h = Hierarchy.load({str(path)!r}); obs = np.load({str(tmp_path / 'obs.npy')!r});"
        "h.set_preference(goal=0.9, avoid=0.1); np.save('a.npy', h.predict(obs)[0]);"
        "h.set_preference({'goal': 0.05, 'avoid': 0.95}); np.save('b.npy', h.predict(obs)[0])"
    )
    subprocess.run([sys.executable, "-c", script], check=True, cwd=tmp_path)
    for text in ("a", "b"):
        np.testing.assert_allclose(np.load(tmp_path / f"{text}.npy"), expected[text][0], rtol=1e-6)
    # Each worker of the bundle is still a plain SB3 zip that carries its critic.
    with zipfile.ZipFile(path) as archive:
        for name in workers:
            member = archive.read(f"workers/{name}.zip")
            with zipfile.ZipFile(io.BytesIO(member)) as inner:
                assert TERM_CRITIC_MEMBER in inner.namelist()
            DDPG.load(io.BytesIO(member))
    loaded = Hierarchy.load(path)
    assert set(loaded.critics) == set(workers) and loaded.reward_spec == pytest.approx(
        {"goal": 0.7, "avoid": 0.3}
    )
    with pytest.raises(ValueError, match="finite number >= 0"):
        loaded.set_preference(goal=-1.0)


def test_gpi_needs_every_critic_and_no_manager(support):
    workers = load_workers(support)
    with pytest.raises(ValueError, match="per-term critic for every worker"):
        Hierarchy.gpi(workers, critics={"goal": workers.critics["goal"]})
    with pytest.raises(ValueError, match="takes no manager"):
        Hierarchy(workers["goal"], workers, Hierarchy.gpi(workers).config)


def test_evaluate_takes_a_preference_for_a_gpi_bundle(support, tmp_path):
    path = Hierarchy.gpi(load_workers(support)).save(tmp_path / "gpi.zip")
    # Both command lines in one interpreter (tests/cli_batch.py), each with its own exit code and output.
    result, refused = run_batch(
        [
            ["evaluate", str(path), "--episodes", "1", "--preference", "goal=0.2,avoid=0.8"],
            ["evaluate", str(path), "--episodes", "1", "--preference", "goal=nan"],
        ]
    )
    assert result.returncode == 0, result.stderr
    assert refused.returncode == 2 and "Traceback" not in refused.stderr


def test_gpi_over_dqn_workers_of_an_mo_gymnasium_env(tmp_path):
    """Discrete-action workers (DQN) get critics over every action; GPI acts, saves and loads over them."""
    pytest.importorskip("mo_gymnasium")
    from sb3_hddpg.envs.terms_env import terms_env

    # mo-mountaincar's time term is -1 at every step: its bounds are widened so that they have a width.
    env = terms_env("mo-mountaincar-v0", episode_steps=30, term_bounds={"obj0": [-2.0, 0.0]})
    critic = TermCriticOptions(steps=50, batch_size=16, net_arch=(8,))
    algos = dict.fromkeys(env.terms, "dqn")
    train_workers(
        tmp_path, env=env, algos=algos, timesteps=200, eval_freq=0, eval_episodes=1, term_critic=critic
    )
    workers = load_workers(tmp_path)
    assert {name: c.spec.n_actions for name, c in workers.critics.items()} == dict.fromkeys(env.terms, 3)
    gpi = Hierarchy.gpi(workers, {"obj0": 0.0, "obj1": 1.0, "obj2": 0.0})
    obs = gpi.make_env().reset(seed=0)[0]
    scores, _ = gpi._gpi.scores(obs, gpi.preferences)
    action, _ = gpi.predict(obs)
    # GPI over actions: the action of the largest w . Q_i(s, a) over every worker and action.
    assert int(action) == int(np.unravel_index(np.argmax(scores), scores.shape)[1])
    loaded = Hierarchy.load(gpi.save(tmp_path / "gpi.zip"))
    assert int(loaded.predict(obs)[0]) == int(action)


def state_critic(values, obs_dim=3):
    """A state-value critic whose output is ``values`` whatever the state."""
    critic = TermCritic(TermCriticSpec(("goal", "avoid"), obs_dim, 0, (), (), (4,), 0.9))
    with torch.no_grad():
        critic.net[-1].weight.zero_()
        critic.net[-1].bias.copy_(torch.as_tensor(values, dtype=torch.float32))
    return critic


def test_state_value_critics_see_the_full_state_and_only_the_chosen_worker_acts():
    calls = []

    class Counted(Fixed):
        def predict(self, observation, state=None, episode_start=None, deterministic=True):
            calls.append(observation.shape)
            return super().predict(observation)

    # The workers see 2 of the 3 state values; their critics see all 3.
    workers = [
        FrozenWorker(Counted(np.float32([0.5])), np.array([0, 1])),
        FrozenWorker(Counted(np.float32([-0.5])), np.array([1, 2])),
    ]
    gpi = GpiSelector(workers, [state_critic([10.0, 2.0]), state_critic([4.0, 6.0])])
    obs = np.zeros(3, dtype=np.float32)
    assert gpi.select(obs, {"goal": 0.2, "avoid": 0.8})[0] == 1 and calls == [(2,)]
    assert gpi.select(obs, {"goal": 0.9, "avoid": 0.1})[0] == 0
    with pytest.raises(ValueError, match="one kind"):
        GpiSelector(workers, [state_critic([1.0, 1.0]), constant_critic([1, 1])])
    critic = state_critic([3.0, 1.0])
    again = TermCritic.from_bytes(critic.to_bytes(), "critic")
    assert again.spec.state_value and np.allclose(again.values(obs[None]), [[3.0, 1.0]])


def test_fit_critics_gives_state_values_and_a_gpi_start(support, tmp_path):
    from sb3_hddpg.training.imitation_start import GpiStart
    from sb3_hddpg.training.manager import train_manager
    from sb3_hddpg.training.term_critic import STATE_CRITIC_OPTIONS, fit_state_critics

    folder = tmp_path / "support"
    shutil.copytree(support, folder)
    options = dataclasses.replace(STATE_CRITIC_OPTIONS, rollout_steps=250, steps=30, net_arch=(16,))
    facts = fit_state_critics(folder, options=options, seed=1)
    workers = load_workers(folder)  # the new hashes verify
    assert {n: (c.spec.state_value, c.spec.obs_dim) for n, c in workers.critics.items()} == dict.fromkeys(
        workers, (True, 39)
    )
    entry = workers.manifest.entries["goal"]["term_critic"]
    assert entry == facts["goal"] and entry["env_steps"] == 250 and entry["kind"] == "state_value"
    gpi = Hierarchy.gpi(workers, {"goal": 0.5, "avoid": 0.5})
    assert gpi.predict(gpi.make_env().reset(seed=0)[0])[0].shape == (6,)
    hierarchy = train_manager(folder, tmp_path / "m", algo="dqn", manager_preferences="dirichlet",
                              init_from_gpi=GpiStart(decisions=60, epochs=40), seed=1, timesteps=70,
                              eval_freq=0, eval_episodes=1).hierarchy  # fmt: skip
    report = hierarchy.metadata["init_from_gpi"]
    assert report["decisions"] == 60 and report["agreement"] >= 0.8
    with pytest.raises(ValueError, match="HAM or from GPI"):
        train_manager(folder, tmp_path / "n", init_from_gpi=True, init_from_ham=5.0, timesteps=10)


def test_fit_critics_gives_discrete_workers_q_over_actions_and_refuses_a_mixed_folder(support, tmp_path):
    """DQN workers trained without critics (as the highway benchmark's were) get Q over their actions."""
    pytest.importorskip("mo_gymnasium")
    from stable_baselines3 import DQN

    from sb3_hddpg.artifacts.provenance import sha256_file
    from sb3_hddpg.envs.terms_env import terms_env
    from sb3_hddpg.training.term_critic import STATE_CRITIC_OPTIONS, fit_state_critics
    from tests.test_grow import TINY_DQN

    shared = terms_env("resource-gathering-v0", terms=["death", "gold", "gem"])
    config = tmp_path / "tiny.yml"
    config.write_text(TINY_DQN)
    root = tmp_path / "run"
    algos = dict.fromkeys(shared.terms, "dqn")
    train_workers(root, config=config, env=shared, algos=algos, term_critic=None, seed=5, eval_freq=0,
                  eval_episodes=1)  # fmt: skip
    assert not load_workers(root).critics
    options = dataclasses.replace(STATE_CRITIC_OPTIONS, rollout_steps=120, steps=30, net_arch=(16,))
    facts = fit_state_critics(root, options=options, seed=1)
    workers = load_workers(root)  # the rewritten zips' hashes verify
    for name, entry in workers.manifest.entries.items():
        assert entry["term_critic"] == facts[name]
        assert (facts[name]["kind"], facts[name]["env_steps"]) == ("discrete", 120)
        assert entry["sha256"] == sha256_file(root / "workers" / entry["file"])
        assert DQN.load(root / "workers" / entry["file"]).num_timesteps >= 150  # still a plain SB3 zip
        spec = workers.critics[name].spec
        assert (spec.n_actions, spec.obs_dim, spec.gamma) == (4, 4, STATE_CRITIC_OPTIONS.gamma)
    hierarchy = Hierarchy.gpi(workers, {"death": 0.2, "gold": 0.5, "gem": 0.3})
    env = hierarchy.make_env()
    action, _ = hierarchy.predict(env.reset(seed=0)[0], deterministic=True)
    assert env.action_space.contains(int(np.asarray(action).reshape(-1)[0]))
    # GPI over the workers' own actions: the chosen worker's action, the one whose critic values it most.
    policies = Hierarchy.gpi(workers, {"death": 0.2, "gold": 0.5, "gem": 0.3}, over_actions=False)
    for seed in range(5):
        obs = np.asarray(env.reset(seed=seed)[0], dtype=np.float32)
        scores, actions = policies._gpi.scores(obs, policies.config.preferences)
        own = [int(np.asarray(a).reshape(-1)[0]) for a in actions]
        best = int(np.argmax([scores[i, a] for i, a in enumerate(own)]))
        assert int(np.asarray(policies.predict(obs, deterministic=True)[0]).reshape(-1)[0]) == own[best]
    policies.save(tmp_path / "gpi-policies.zip")
    loaded = Hierarchy.load(tmp_path / "gpi-policies.zip")
    assert loaded.config.selection == "gpi-policies" and not loaded._gpi.over_actions
    # A folder of discrete and continuous workers would end with critics of two kinds: refused in one line.
    mixed = tmp_path / "mixed"
    shutil.copytree(root, mixed)
    shutil.copy(support / "workers" / "goal.zip", mixed / "workers" / "goal.zip")
    manifest, theirs = (json.loads((f / "workers" / "manifest.json").read_text()) for f in (mixed, support))
    manifest["workers"]["goal"] = theirs["workers"]["goal"]
    (mixed / "workers" / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(
        ValueError, match=r"mixes discrete workers \['death', 'gem', 'gold'\] with continuous"
    ):
        fit_state_critics(mixed, names=["gold"], options=options)
    command = ["fit-critics", "--rollout-steps", "60", "--steps", "10", "--workers"]
    fitted, refused = run_batch([[*command, str(root)], [*command, str(mixed)]])
    assert fitted.returncode == 0 and "discrete" in fitted.stdout, fitted.stderr
    assert load_workers(root).manifest.entries["gold"]["term_critic"]["env_steps"] == 60
    assert refused.returncode == 2 and "mixes discrete workers" in refused.stderr
    assert "Traceback" not in refused.stderr
