"""The support that grows where the front gains most: the corner weights, their gains, and grow on tiny budgets."""

import json

import numpy as np
import pytest

from sb3_hddpg.artifacts.manifests import load_workers
from sb3_hddpg.artifacts.records.support import read_support_record
from sb3_hddpg.artifacts.transitions import Transitions
from sb3_hddpg.training.grow import SupportOptions, grow
from sb3_hddpg.training.linear_support import corner_weights, ranked_corners
from sb3_hddpg.training.term_critic import TermCriticOptions
from sb3_hddpg.training.workers import train_workers

CRITIC = TermCriticOptions(steps=100, batch_size=32, net_arch=(16,))
RUN = {"eval_freq": 0, "eval_episodes": 1, "seed": 5}


def test_the_corner_of_two_policies_is_where_their_values_cross():
    values = np.array([[10.0, 2.0], [3.0, 8.0]])
    corners = ranked_corners(values, [np.array([1.0, 0.0]), np.array([0.0, 1.0])])
    best = corners[0]
    # w.(10, 2) = w.(3, 8) at w = (6/13, 7/13); OLS's bound there is w.(10, 8) (each term's best).
    assert best.weights == pytest.approx((6 / 13, 7 / 13))
    assert best.value == pytest.approx(6 / 13 * 10 + 7 / 13 * 2)
    assert best.gain == pytest.approx(6 / 13 * 10 + 7 / 13 * 8 - best.value)
    assert [c.gain for c in corners[1:]] == pytest.approx([0.0, 0.0])
    # A third policy at the corner that reaches the bound leaves no gain anywhere.
    full = np.vstack([values, [10.0, 8.0]])
    visited = [np.array([1.0, 0.0]), np.array([0.0, 1.0]), np.array([6 / 13, 7 / 13])]
    assert max(c.gain for c in ranked_corners(full, visited)) == pytest.approx(0.0, abs=1e-9)


def test_corners_in_three_terms_include_the_simplex_and_the_centre():
    corners = corner_weights(np.eye(3))
    assert any(np.allclose(c, [1 / 3, 1 / 3, 1 / 3]) for c in corners)
    assert all(c.min() >= 0 and np.isclose(c.sum(), 1.0) for c in corners)


@pytest.fixture(scope="module")
def corners_trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("grow")
    train_workers(root, timesteps=300, term_critic=CRITIC, keep_transitions=True, **RUN)
    return root


#: A weighted workers' block with the avoid worker's networks, so that its parameters can start them (the
#: bundled block's [256, 256] networks cannot start from the avoid worker's [64, 64]).
SMALL_MIX_BLOCK = """
hddpg/SnakeReach-v0/mix:
  n_timesteps: 1000
  policy: 'MlpPolicy'
  learning_starts: 100
  batch_size: 32
  gamma: 0.9
  policy_kwargs: "dict(net_arch=[64, 64])"
"""


def test_grow_adds_a_warm_started_worker_at_the_corner_and_records_it(corners_trained, tmp_path):
    import shutil

    root = tmp_path / "run"
    shutil.copytree(corners_trained, root)
    config = tmp_path / "small.yml"
    config.write_text(SMALL_MIX_BLOCK)
    options = SupportOptions(size=3, budget=250, tolerance=0.0, start_states=4)
    record = grow(root, options, term_critic=CRITIC, config=config, **RUN)
    assert len(record.added) == 1 and record.stopped == "reached 3 workers"
    step = record.added[0]
    assert step.name.startswith("mix-") and step.gain > 0 and step.steps >= 250
    # The goal worker sees part of the state only: the nearest worker that fits is the avoid worker.
    assert step.warm_start == "avoid" and step.replay == 300  # the neighbour's kept transitions
    workers = load_workers(root)
    assert list(workers) == ["goal", "avoid", step.name] and step.name in workers.critics
    entry = workers.manifest.entries[step.name]
    assert entry["reward_weights"] == pytest.approx(step.weights)
    assert entry["warm_start"] == {"from": step.warm_start, "parameters": True, "replay": 300}
    assert len(Transitions.load(root / "workers" / entry["transitions"]["file"])) >= 250
    on_disk = read_support_record(root / "workers" / "support.json")
    assert on_disk.added[0].name == step.name and set(on_disk.worker_values) == set(workers)
    # Nothing is overwritten without --resume; with it, a finished support stays as it is.
    with pytest.raises(FileExistsError, match="--resume"):
        grow(root, SupportOptions(size=3, budget=250), **RUN)
    again = grow(root, SupportOptions(size=3, budget=250), resume=True, **RUN)
    assert [s.name for s in again.added] == [step.name]


def test_grow_refuses_workers_without_critics_and_bad_options(tmp_path):
    train_workers(tmp_path, timesteps=150, term_critic=None, **RUN)
    with pytest.raises(ValueError, match="per-term critic"):
        grow(tmp_path, SupportOptions(size=3, budget=100), **RUN)
    for bad in (
        {"size": 1, "budget": 10},
        {"size": 3, "budget": 0},
        {"size": 3, "budget": 10, "tolerance": -1},
    ):
        with pytest.raises(ValueError):
            SupportOptions(**bad)
    (tmp_path / "workers" / "support.json").write_text(json.dumps({"schema_version": 1, "terms": "x"}))
    with pytest.raises(ValueError, match=r"support\.json"):
        read_support_record(tmp_path / "workers" / "support.json")


def test_the_grow_command_adds_a_worker_and_refuses_bad_options(corners_trained, tmp_path):
    import shutil

    from tests.cli_batch import run_batch

    root = tmp_path / "run"
    shutil.copytree(corners_trained, root)
    tiny = ("--eval-freq", "0", "--eval-episodes", "1", "--no-progress", "--start-states", "2")
    # The four command lines in turn in one interpreter (tests/cli_batch.py), each with its own exit code and
    # output; the refusals change nothing, so the workers counted after them are those the first one grew.
    refusals = ((("--support", "1"), "--support"), (("--workers", str(tmp_path / "none")), "--workers"))
    result, *bad_ones, again = run_batch(
        [
            ["grow", "--workers", str(root), "--support", "3", "--budget", "150", "--tolerance", "0", *tiny],
            *(["grow", "--workers", str(root), "--budget", "10", *args, *tiny] for args, _ in refusals),
            ["grow", "--workers", str(root), "--support", "4", "--budget", "150", *tiny],
        ]
    )
    assert result.returncode == 0, result.stderr
    assert "reached 3 workers" in result.stdout and len(load_workers(root)) == 3
    for bad, (_, option) in zip(bad_ones, refusals, strict=True):
        assert bad.returncode == 2 and option in bad.stderr and "Traceback" not in bad.stderr
    assert again.returncode == 2 and "--resume" in again.stderr


TINY_DQN = """\
default:
  n_timesteps: 150
  policy: 'MlpPolicy'
  learning_starts: 50
  batch_size: 16
  buffer_size: 500
  policy_kwargs: "dict(net_arch=[16])"
"""


def test_a_weighted_worker_joins_a_discrete_support_as_its_kind_and_gpi_acts_over_them(tmp_path):
    pytest.importorskip("mo_gymnasium")
    import gymnasium as gym

    from sb3_hddpg.envs.terms_env import terms_env
    from sb3_hddpg.hierarchy.hierarchy import Hierarchy

    shared = terms_env("resource-gathering-v0", terms=["death", "gold", "gem"])
    config = tmp_path / "tiny.yml"
    config.write_text(TINY_DQN)
    root = tmp_path / "run"
    train_workers(
        root, config=config, env=shared, algos=dict.fromkeys(shared.terms, "dqn"), term_critic=CRITIC, **RUN
    )
    # As grow and the front's support add one: no algorithm named.
    weights = {"death": 0.2, "gold": 0.5, "gem": 0.3}
    train_workers(root, [], config, env=shared, weights=[weights], term_critic=CRITIC, **RUN)
    workers = load_workers(root)
    name = list(workers)[-1]
    # Not the default continuous worker: the support's own algorithm, with a critic over its actions.
    assert name.startswith("mix-") and workers.manifest.entries[name]["algo"] == "dqn"
    assert workers.critics[name].spec.discrete
    hierarchy = Hierarchy.gpi(workers, weights)
    env = gym.make(hierarchy.env_id, **hierarchy.env_kwargs)
    obs, _ = env.reset(seed=0)
    action, _ = hierarchy.predict(obs, deterministic=True)
    assert env.action_space.contains(int(np.asarray(action).reshape(-1)[0]))


def test_train_workers_resumed_checks_a_weighted_worker_as_the_algorithm_it_joins(tmp_path):
    """The command's checks before training plan the weighted worker as train_workers trains it: DQN here."""
    pytest.importorskip("mo_gymnasium")
    from sb3_hddpg.envs.terms_env import terms_env
    from tests.cli_batch import run_batch

    shared = terms_env("resource-gathering-v0", terms=["death", "gold", "gem"])
    config = tmp_path / "tiny.yml"
    config.write_text(TINY_DQN + "  exploration_fraction: 0.2\n")  # a key DQN takes and DDPG refuses
    root = tmp_path / "run"
    train_workers(root, config=config, env=shared, algos=dict.fromkeys(shared.terms, "dqn"), term_critic=None,
                  **RUN)  # fmt: skip
    command = ["train-workers", "--env", "resource-gathering-v0", "--terms", "death,gold,gem", "--config",
               str(config), "--out", str(root), "--resume", "--weights", "gold=0.5,gem=0.5", "--no-term-critic",
               "--eval-freq", "0", "--eval-episodes", "1", "--seed", "5"]  # fmt: skip
    (result,) = run_batch([command])
    assert result.returncode == 0, result.stderr
    assert load_workers(root).manifest.entries["mix-gold50-gem50"]["algo"] == "dqn"


def test_folder_algos_takes_the_heaviest_terms_algorithm_where_its_entry_names_one(tmp_path):
    from pathlib import Path

    from sb3_hddpg.envs.terms_env import TermsEnv
    from sb3_hddpg.training.workers import folder_algos

    shipped = Path(__file__).resolve().parents[1] / "docs" / "results" / "cheetah" / "seed-0" / "workers"
    manifest = json.loads((shipped / "manifest.json").read_text())  # two CrossQ workers
    (tmp_path / "workers").mkdir()
    cheetah = TermsEnv("mo-halfcheetah-v5", {}, ("speed", "energy"))
    weights = [{"speed": 0.7, "energy": 0.3}, {"speed": 1.0}]
    (tmp_path / "workers" / "manifest.json").write_text(json.dumps(manifest))
    assert folder_algos(tmp_path, weights, cheetah) == {"mix-speed70-energy30": "crossq"}
    assert folder_algos(tmp_path, weights, cheetah, {"mix-speed70-energy30": "sac"}) == {
        "mix-speed70-energy30": "sac"
    }
    # An entry without its algorithm (the manifest's reader allows one): the default stands, no KeyError.
    del manifest["workers"]["speed"]["algo"]
    (tmp_path / "workers" / "manifest.json").write_text(json.dumps(manifest))
    assert folder_algos(tmp_path, weights, cheetah) == {}
