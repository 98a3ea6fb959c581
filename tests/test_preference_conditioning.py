"""One manager for every preference: the preference space, the conditioned wrapper, relabelling, bundles, CLI."""

import json
import re
import subprocess
import sys
import zipfile

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from sb3_hddpg.artifacts.limits import LimitError
from sb3_hddpg.hierarchy import WorkerSelectionWrapper
from sb3_hddpg.hierarchy.bundle import BundleError
from sb3_hddpg.hierarchy.conditioning import PreferenceOutsideError, PreferenceSpace
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.relabeling import PreferenceRelabelingReplayBuffer
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.workers import train_workers
from tests.cli_batch import run_batch

TINY = {"timesteps": 300, "eval_freq": 150, "eval_episodes": 1}
NAMES = ["goal", "avoid"]


@pytest.fixture(scope="module")
def workers(tmp_path_factory):
    root = tmp_path_factory.mktemp("conditioned")
    train_workers(root / "w", seed=5, **TINY)
    return root


@pytest.fixture(scope="module")
def conditioned(workers):
    result = train_manager(workers / "w", workers / "m", manager_preferences="ratio-sweep", seed=5, **TINY)
    hierarchy, outcome = result.hierarchy, result.outcome
    return workers / "m" / "hierarchy.zip", hierarchy, outcome


def test_ratio_sweep_keeps_the_sum_and_varies_the_ratio():
    space = PreferenceSpace.parse("ratio-sweep", NAMES)
    assert len(space.points) == 7
    assert all(sum(p) == pytest.approx(2.0) for p in space.points)
    ratios = sorted(round(p[0] / p[1], 3) for p in space.points)
    assert ratios == [0.25, 0.333, 0.5, 1.0, 2.0, 3.0, 4.0]
    assert space.check({"goal": 0.4, "avoid": 1.6}) == pytest.approx({"goal": 0.4, "avoid": 1.6})
    # Only the ratio is observed: 1:4 at any scale is 0.4:1.6 at the trained sum.
    assert space.check({"goal": 1, "avoid": 4}) == pytest.approx({"goal": 0.4, "avoid": 1.6})
    # Between trained points is inside, beyond the extremes is not.
    assert space.check({"goal": 0.5, "avoid": 1.25})["goal"] == pytest.approx(2 * 0.5 / 1.75)
    with pytest.raises(PreferenceOutsideError, match="outside those the manager was trained over"):
        space.check({"goal": 0.1, "avoid": 1.9})


def test_a_wider_sweep_doubles_its_ratios_and_takes_its_own_rounded_labels():
    from hddpg_zoo.benchmark.front_points import label_factors, sweep_labels

    space = PreferenceSpace.parse("ratio-sweep:16", NAMES)
    ratios = sorted(round(p[0] / p[1], 4) for p in space.points)
    assert ratios == [0.0625, 0.125, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0]
    assert all(sum(p) == pytest.approx(2.0) for p in space.points)
    # Every label, as tables print it (4 significant digits), is a preference the manager was trained over.
    for label, point in zip(sweep_labels(space), space.points):
        assert space.check(label_factors(label)) == pytest.approx(dict(zip(NAMES, point)), rel=1e-3)
    with pytest.raises(PreferenceOutsideError):
        space.check({"goal": 1.9, "avoid": 0.1})  # 19:1, beyond 16:1
    for text in ("ratio-sweep:3", "ratio-sweep:1", "ratio-sweep:2048", "ratio-sweep:x"):
        with pytest.raises(ValueError, match="power of two"):
            PreferenceSpace.parse(text, NAMES)


def test_lists_must_share_their_sum_and_dirichlet_draws_within_its_floor():
    with pytest.raises(ValueError, match="must sum to 2"):
        PreferenceSpace.parse("goal=1,avoid=1;goal=1,avoid=4", NAMES)
    listed = PreferenceSpace.parse("goal=1.6,avoid=0.4;goal=0.4,avoid=1.6", NAMES)
    assert listed.total == pytest.approx(2.0) and len(listed.points) == 2
    space = PreferenceSpace.parse("dirichlet:0.5", NAMES)
    weights = space.sample_weights(np.random.default_rng(0), 1000)
    np.testing.assert_allclose(weights.sum(axis=1), 1.0)
    assert weights.min() >= space.floor - 1e-12 and weights.max() <= 1 - space.floor + 1e-12
    assert sum(space.sample(np.random.default_rng(1)).values()) == pytest.approx(2.0)
    with pytest.raises(ValueError, match="dirichlet:ALPHA"):
        PreferenceSpace.parse("dirichlet:x", NAMES)


@pytest.mark.parametrize(
    "data",
    [
        "ratio",
        {"kind": "set", "total": 2.0, "points": [{"goal": 1.0}]},
        {"kind": "set", "total": 2.0, "points": [{"goal": 1.0, "avoid": 1.0}, {"goal": "x", "avoid": 1}]},
        {"kind": "cone", "total": 2.0},
        {"kind": "dirichlet", "total": -1.0},
        {"kind": "set", "total": 2.0, "points": [], "extra": 1},
    ],
)
def test_a_hostile_recorded_space_is_refused_in_one_line(data):
    with pytest.raises(LimitError) as error:
        PreferenceSpace.from_json(data, NAMES)
    assert "\n" not in str(error.value)


class _Constant:
    def __init__(self, value):
        self.value = value

    def predict(self, obs, deterministic=True):
        return np.full(6, self.value, np.float32), None


def _wrapper(space):
    env = gym.make("hddpg/SnakeReach-v0")
    return WorkerSelectionWrapper(
        env, {"goal": _Constant(0.1), "avoid": _Constant(-0.1)}, manager_preferences=space, option_steps=2
    )


def test_the_conditioned_wrapper_observes_and_draws_preferences_and_reports_worker_rewards():
    space = PreferenceSpace.parse("ratio-sweep", NAMES)
    wrapper = _wrapper(space)
    state_size = gym.make("hddpg/SnakeReach-v0").observation_space.shape[0]
    assert wrapper.observation_space.shape == (state_size + 2,)
    seen = set()
    for episode in range(12):
        obs, _ = wrapper.reset(seed=episode)
        assert obs[-2:] == pytest.approx(space.weights(wrapper.preferences))
        seen.add(round(wrapper.preferences["goal"], 3))
        obs, reward, *_, info = wrapper.step(np.array([1.0, -1.0], np.float32))
        # The reward is linear in the workers' own rewards: any preference's reward is known from them.
        factors = np.array([wrapper.preferences[n] for n in NAMES])
        assert reward == pytest.approx(float(factors @ info["worker_rewards"]), rel=1e-6)
    assert len(seen) > 2
    # A bundle made while drawing acts at the unweighted preference, not at the last draw.
    assert wrapper.selection_config().preferences == {"goal": 1.0, "avoid": 1.0}
    wrapper.set_preference(goal=0.4, avoid=1.6)
    assert wrapper.selection_config().preferences == pytest.approx({"goal": 0.4, "avoid": 1.6})
    for episode in range(3):
        obs, _ = wrapper.reset(seed=100 + episode)
        assert obs[-2:] == pytest.approx([0.2, 0.8])
    with pytest.raises(PreferenceOutsideError):
        wrapper.set_preference(goal=0.1, avoid=1.9)
    assert wrapper.selection_config().manager_preferences == space.to_json()


def test_a_matrix_observation_is_flattened_before_the_weights():
    from sb3_hddpg.hierarchy.manager_input import with_preference_space

    matrix = spaces.Box(-2.0, 2.0, (5, 5), np.float32)  # e.g. highway-env's Kinematics observation
    space = with_preference_space(matrix, 3)
    assert space.shape == (28,) and space.low[0] == -2.0 and space.low[-1] == 0.0 and space.high[-1] == 1.0
    with pytest.raises(ValueError, match="needs a Box observation"):
        with_preference_space(spaces.Discrete(4), 3)


def test_relabelling_rewrites_the_preference_and_recomputes_the_reward():
    space = PreferenceSpace.parse("ratio-sweep", NAMES)
    obs_space = spaces.Box(-1, 1, (5,), np.float32)
    buffer = PreferenceRelabelingReplayBuffer(
        64, obs_space, spaces.Box(-1, 1, (2,), np.float32), device="cpu", names=NAMES,
        space=space.to_json(), relabel_fraction=1.0, seed=0,
    )  # fmt: skip
    rng = np.random.default_rng(0)
    for _ in range(40):
        terms = rng.random(2)
        obs = np.concatenate([rng.random(3), [0.5, 0.5]]).astype(np.float32)[None]
        buffer.add(obs, obs, rng.random((1, 2)), np.array([2 * 0.5 * terms.sum()]), np.array([False]),
                   [{"worker_rewards": terms}])  # fmt: skip
    batch = buffer.sample(32)
    weights = batch.observations[:, -2:].numpy()
    np.testing.assert_allclose(weights.sum(axis=1), 1.0, rtol=1e-6)
    assert len({tuple(np.round(w, 3)) for w in weights}) > 1  # fresh preferences, not the stored one
    np.testing.assert_array_equal(batch.next_observations[:, -2:].numpy(), weights)
    # Each reward is the stored worker rewards weighted by the new preference at the trained sum.
    stored = {
        tuple(np.round(o, 5)): r
        for o, r in zip(buffer.observations[:40, 0, :3], buffer.worker_rewards[:40, 0])
    }
    for obs, w, reward in zip(batch.observations.numpy(), weights, batch.rewards.numpy()[:, 0]):
        terms = stored[tuple(np.round(obs[:3], 5))]
        assert reward == pytest.approx(2.0 * float(w @ terms), rel=1e-5)
    buffer.relabel_fraction = 0.0
    plain = buffer.sample(16)
    np.testing.assert_allclose(plain.observations[:, -2:].numpy(), 0.5)
    with pytest.raises(ValueError, match="worker_rewards"):
        buffer.add(obs[None], obs[None], rng.random((1, 2)), np.array([0.0]), np.array([False]), [{}])


def test_a_conditioned_bundle_records_its_preferences_and_acts_at_any_of_them_in_a_fresh_process(
    conditioned, tmp_path
):
    path, hierarchy, outcome = conditioned
    assert isinstance(outcome.model.replay_buffer, PreferenceRelabelingReplayBuffer)
    with zipfile.ZipFile(path) as archive:
        manifest = json.loads(archive.read("manifest.json"))
    recorded = manifest["selection"]["manager_preferences"]
    assert recorded["kind"] == "set" and len(recorded["points"]) == 7
    obs = np.stack([gym.make("hddpg/SnakeReach-v0").reset(seed=s)[0] for s in range(6)])
    np.save(tmp_path / "obs.npy", obs)
    preferences = [{"goal": 1.6, "avoid": 0.4}, {"goal": 0.4, "avoid": 1.6}, {"goal": 1.0, "avoid": 1.0}]
    expected = []
    for preference in preferences:
        hierarchy.set_preference(preference)
        hierarchy.seed(0)
        manager_obs = [hierarchy._manager_input(row, None, hierarchy._preference_obs) for row in obs]
        expected.append(np.stack([hierarchy._manager.act(row) for row in manager_obs]))  # the raw actor
    # The preference is an input: the manager's output depends on it.
    assert not np.allclose(expected[0], expected[1])
    script = (
        "import json, numpy as np; from sb3_hddpg import Hierarchy;"
        f"h = Hierarchy.load({str(path)!r}); obs = np.load({str(tmp_path / 'obs.npy')!r}); out = [];"
        f"prefs = json.loads({json.dumps(json.dumps(preferences))});"
        "[(h.set_preference(p), out.append([h.probabilities(o) for o in obs]), h.predict(obs)) for p in prefs];"
        f"json.dump(out, open({str(tmp_path / 'out.json')!r}, 'w'))"
    )
    subprocess.run([sys.executable, "-c", script], check=True)
    out = json.loads((tmp_path / "out.json").read_text())
    for preference, rows in zip(preferences, out):
        hierarchy.set_preference(preference)
        for row, o in zip(rows, obs):
            assert row == pytest.approx(hierarchy.probabilities(o))
    loaded = Hierarchy.load(path)
    with pytest.raises(PreferenceOutsideError):
        loaded.set_preference(goal=5.0, avoid=0.1)


def test_a_per_preference_manager_refuses_another_preference(workers):
    hierarchy = train_manager(workers / "w", workers / "plain", preferences={"goal": 0.4, "avoid": 1.6},
                                 seed=5, **TINY).hierarchy  # fmt: skip
    hierarchy.set_preference(goal=1, avoid=4)  # its own ratio
    hierarchy.set_preference(goal=0.4001, avoid=1.6)  # its own, as a table rounds it
    with pytest.raises(PreferenceOutsideError):
        hierarchy.set_preference(goal=0.41, avoid=1.6)
    with pytest.raises(
        PreferenceOutsideError, match=re.escape("trained for the preference goal=0.4,avoid=1.6 only")
    ):
        hierarchy.set_preference(goal=1, avoid=1)


def test_the_cli_takes_a_run_time_preference_and_refuses_one_outside_in_one_line(conditioned):
    path, _, _ = conditioned
    # Four command lines, one interpreter (tests/cli_batch.py): each still gets its own exit code and output.
    ok, refused, bad, scripted = run_batch(
        [
            ["evaluate", str(path), "--episodes", "1", "--preference", "goal=0.4,avoid=1.6"],
            ["evaluate", str(path), "--episodes", "1", "--preference", "goal=0.1,avoid=1.9"],
            ["plot-selection", str(path), "--preference", "goal=x"],
            ["evaluate", "random", "--episodes", "1", "--preference", "goal=1,avoid=1"],
        ]
    )
    assert ok.returncode == 0, ok.stdout + ok.stderr
    assert refused.returncode == 2
    assert "outside those the manager was trained over" in (refused.stdout + refused.stderr)
    assert "Traceback" not in (refused.stdout + refused.stderr)
    assert bad.returncode == 2 and "Traceback" not in (bad.stdout + bad.stderr)
    assert scripted.returncode == 2 and "applies to a hierarchy" in (scripted.stdout + scripted.stderr)


def test_train_manager_cli_trains_a_conditioned_manager(workers, tmp_path):
    result, bad = run_batch(
        [
            ["train-manager", "--workers", str(workers / "w"), "--out", str(tmp_path / "m"),
             "--preferences", "goal=1.5,avoid=0.5;goal=0.5,avoid=1.5", "--timesteps", "120",
             "--eval-freq", "60", "--eval-episodes", "1", "--no-progress"],
            ["train-manager", "--workers", str(workers / "w"), "--out", str(tmp_path / "n"),
             "--preferences", "goal=1,avoid=1;goal=1,avoid=3", "--timesteps", "10"],
        ]
    )  # fmt: skip
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Conditioned on 2 preferences" in (result.stdout + result.stderr)
    loaded = Hierarchy.load(tmp_path / "m" / "hierarchy.zip")
    loaded.set_preference(goal=1, avoid=1)
    assert bad.returncode == 2 and "must sum to 2" in (bad.stdout + bad.stderr)


@pytest.mark.parametrize(
    "recorded", [[1, 2], {"kind": "set", "total": 2.0, "points": [{"goal": -1, "avoid": 3}]}]
)
def test_a_bundle_with_a_hostile_preference_space_is_refused(conditioned, tmp_path, recorded):
    path, _, _ = conditioned
    out = tmp_path / "hostile.zip"
    with zipfile.ZipFile(path) as source, zipfile.ZipFile(out, "w") as target:
        for item in source.infolist():
            data = source.read(item.filename)
            if item.filename == "manifest.json":
                manifest = json.loads(data)
                manifest["selection"]["manager_preferences"] = recorded
                data = json.dumps(manifest).encode()
            target.writestr(item, data)
    with pytest.raises(BundleError, match="manager_preferences") as error:
        Hierarchy.load(out)
    assert "\n" not in str(error.value)


@pytest.mark.slow
def test_a_conditioned_manager_trains_with_sbx_too(workers, tmp_path):
    pytest.importorskip("sbx")
    outcome = train_manager(
        workers / "w", tmp_path / "m", manager_preferences="ratio-sweep", seed=5, backend="sbx", **TINY
    ).outcome
    assert outcome.backend == "sbx"
    loaded = Hierarchy.load(tmp_path / "m" / "hierarchy.zip")
    loaded.set_preference(goal=0.4, avoid=1.6)
    assert loaded.preferences == pytest.approx({"goal": 0.4, "avoid": 1.6})
