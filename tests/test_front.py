"""The front scenario: fronts over preferences and thresholds, pymoo hypervolumes, statistics, table and figure."""

import json
import subprocess
import sys

import gymnasium as gym
import numpy as np
import pytest

from hddpg_zoo.agent_settings import horizon_gamma
from hddpg_zoo.benchmark import (
    REFERENCE_POINTS,
    SWEEP,
    BenchmarkSettings,
    FrontPoint,
    front_results,
    hypervolume,
    run_benchmark,
)
from hddpg_zoo.benchmark.front import decision_dependence
from hddpg_zoo.benchmark.front_points import PLANES, env_front, member_fields, sweep_labels
from hddpg_zoo.benchmark.methods import METHOD_REGISTRY
from hddpg_zoo.benchmark.report import markdown_report
from hddpg_zoo.benchmark.tasks import comparison_pairs
from hddpg_zoo.model_export import export_models
from hddpg_zoo.records import BenchmarkResults
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.training.backends import sbx_installed
from sb3_hddpg.training.config import MANAGER_KEY
from sb3_hddpg.training.manager_setup import manager_hyperparams
from tests.cli_runner import run_cli


def _point(touch, contacts, goal=0.5, avoid=0.5, reach=340.0):
    values = {
        "goal_touch_rate": touch,
        "contacts_per_episode": contacts,
        "mean_reach_reward": reach,
        "goal_term": goal,
        "avoid_term": avoid,
    }
    return FrontPoint("p", values)


def test_hypervolume_is_the_dominated_area_against_the_fixed_reference():
    reference = REFERENCE_POINTS["hddpg/SnakeReach-v0"]
    assert reference == {"outcomes": (0.0, 20.0), "terms": (0.0, 0.0)}
    # One point: the rectangle to the reference. Touch is maximised, contacts minimised.
    outcomes, terms = PLANES["outcomes"], PLANES["terms"]
    assert hypervolume([_point(0.5, 10.0)], outcomes, reference["outcomes"]) == pytest.approx(0.5 * 10.0)
    # Two points: the union of their rectangles; a dominated third adds nothing.
    two = [_point(0.5, 10.0), _point(0.2, 2.0)]
    union = 0.5 * 10.0 + 0.2 * 8.0
    assert hypervolume(two, outcomes, reference["outcomes"]) == pytest.approx(union)
    assert hypervolume([*two, _point(0.1, 15.0)], outcomes, reference["outcomes"]) == pytest.approx(union)
    assert hypervolume([_point(0, 0, 0.4, 0.5)], terms, reference["terms"]) == pytest.approx(0.2)
    assert hypervolume([], terms, reference["terms"]) == 0.0


def test_another_envs_front_has_a_terms_plane_and_a_returns_plane_in_as_many_dimensions_as_terms():
    spec = env_front(
        ["speed", "lane", "collision"], {"speed": (0, 1), "lane": (0, 1), "collision": (-1, 0)}, 40
    )
    assert spec.members == ("conditioned", "per-preference", "speed", "lane", "collision")
    assert spec.references == {"terms": (0.0, 0.0, 0.0), "returns": (0.0, 0.0, -40.0)}
    assert len(spec.sweep.points) == 10 and {round(sum(p), 9) for p in spec.sweep.points} == {3.0}
    summary = {
        "mean_speed_reward": 20.0, "mean_lane_reward": 10.0, "mean_collision_reward": -1.0,
        "mean_length": 40.0, "mean_reach_reward": 70.0,
    }  # fmt: skip
    point = FrontPoint.of("p", summary, {"speed": (0, 1), "lane": (0, 1), "collision": (-1, 0)}, spec.terms)
    assert point.values["speed_term"] == 0.5 and point.values["collision_term"] == pytest.approx(1 - 1 / 40)
    assert point.values["collision_return"] == -1.0 and "goal_touch_rate" not in point.values
    # The box from the reference: 0.5 * 0.25 * (39/40) in the terms plane, 20 * 10 * 39 in the returns plane.
    fields = member_fields([point], spec)
    assert fields["hypervolume"]["terms"] == pytest.approx(0.5 * 0.25 * 39 / 40)
    assert fields["hypervolume"]["returns"] == pytest.approx(20 * 10 * 39)
    assert fields["points"] == [{"label": "p", **point.values}]
    # Episodes of unknown length give no returns plane; a front needs two terms.
    assert list(env_front(["a", "b"], {"a": (0, 1), "b": (0, 1)}, None).planes) == ["terms"]
    with pytest.raises(ValueError, match="at least two terms"):
        env_front(["a"], {"a": (0, 1)}, 10)


def test_the_sweep_has_at_least_seven_preferences_with_one_sum():
    assert len(SWEEP.points) >= 7
    assert {round(sum(p), 9) for p in SWEEP.points} == {2.0}


def _with_front(front):
    """A benchmark's results holding only the front scenario's figures (what the front tables read)."""
    return BenchmarkResults(settings={}, scenario="front", metric="", methods={}, front=front)


def _front_record(members):
    """A seed's front record on the snake arm, from each member's points."""
    reference = REFERENCE_POINTS["hddpg/SnakeReach-v0"]
    return {
        "front": {name: member_fields(points) for name, points in members.items()},
        "references": {k: list(v) for k, v in reference.items()},
        "decides_by_state": {},
    }


def test_front_results_compare_members_by_seed():
    def record(shift):
        return _front_record(
            {
                "conditioned": [_point(0.5 + shift, 5.0), _point(0.3, 1.0), _point(0.2, 2.0, reach=345.0)],
                "ham": [_point(0.4, 6.0)],
                "per-preference": [_point(0.45, 6.0)],
                "goal": [_point(0.6, 14.0)],
                "avoid": [_point(0.1, 0.5)],
            }
        )

    results = front_results({0: record(0.0), 1: record(0.05), 2: record(0.02)})
    comparison = results["comparisons"]["conditioned vs ham"]["planes"]["outcomes"]
    assert comparison["wins"] == 3 and comparison["difference"] > 0
    assert results["hypervolume"]["ham"]["outcomes"]["mean"] == pytest.approx(0.4 * 14.0)
    one = front_results({0: record(0.0)})
    assert one["comparisons"] == {}  # one seed makes no paired interval
    # The safe end: the most touch with <= 2 contacts per seed, None where no point of the front is that safe.
    safe = results["safe_touch"]
    assert safe["contacts"] == 2.0
    assert safe["per_seed"]["conditioned"] == {"0": 0.3, "1": 0.3, "2": 0.3}
    assert safe["per_seed"]["ham"] == {"0": None, "1": None, "2": None}
    assert safe["per_seed"]["avoid"]["0"] == 0.1
    # Its reward: the safe point of highest reach reward (not the one of most touch), and that point's touch.
    assert safe["best_reach"]["conditioned"]["1"] == {"reach": 345.0, "touch": 0.2}
    assert safe["best_reach"]["ham"]["0"] is None
    # The generated pages' tables (hddpg-cli report): the front and the decides-by-state table.
    from hddpg_zoo.benchmark.pages import render_page

    results["decides_by_state"] = {"0": {"goal=1,avoid=1": None}}
    page = "<!-- generated:run/front -->\n<!-- /generated:run/front -->\n"
    text, written = render_page(page, "run", _with_front(results))
    assert written == ["front"] and "| conditioned |" in text and "Reference points" in text
    assert "better in 3 of 3 seeds" in text
    assert (
        "- conditioned: most goal touch 30.0 % (reached in 3 of 3 seeds); highest reach reward 345.0, with 20.0 %"
        in text
    )
    assert "- ham: most goal touch - (reached in 0 of 3" in text

    # In short: a seed a row, a preference a column, bold where the interval's lower end is at least 2.
    def figure(ratio, interval):
        shares = {"near_share": 0.3, "clear_share": 0.1, "near_decisions": 10, "clear_decisions": 30}
        return {"ratio": ratio, "ratio_ci": interval, **shares}

    results["decides_by_state"] = {
        "0": {"goal=1.6,avoid=0.4": figure(0.5, [0.2, 0.9]), "goal=1,avoid=1": figure(3.0, [2.1, 4.0])},
        "1": {"goal=1.6,avoid=0.4": figure(None, None), "goal=1,avoid=1": figure(2.5, [1.5, 3.5])},
    }
    ratios = "<!-- generated:run/front-decides-ratios -->\n<!-- /generated:run/front-decides-ratios -->\n"
    text, _ = render_page(ratios, "run", _with_front(results))
    assert "| seed | 4:1 | 1:1 |" in text
    assert "| 0 | 0.5 | **3** |" in text and "| 1 | - | 2.5 |" in text
    # The run's results.md holds the whole table.
    full = markdown_report(_with_front(results))
    assert (
        "decisions by state" in full
        and "| 0 | `goal=1,avoid=1` | 30.0% | 10.0% | 3.00 [2.10, 4.00] | 10 / 30 |" in full
    )
    text, _ = render_page(
        "<!-- generated:run/front -->\n<!-- /generated:run/front -->\n", "run", _with_front(None)
    )
    assert "(not a front run)" in text


def test_the_fronts_figure_draws_a_rule_that_keeps_another_number_of_thresholds_in_each_seed(tmp_path):
    from hddpg_zoo.benchmark.front_pages import front_figure

    def record(ham_points):
        return _front_record(
            {
                "conditioned": [_point(0.5, 5.0), _point(0.3, 1.0)],
                "ham": ham_points,
                "goal": [_point(0.6, 14.0)],
            }
        )

    # HAM keeps the thresholds not dominated on each seed's curve episodes: three in one seed, one in the other.
    results = front_results(
        {0: record([_point(0.4, 6.0), _point(0.3, 2.0), _point(0.1, 0.5)]), 1: record([_point(0.4, 6.0)])}
    )
    path = front_figure(results, tmp_path / "fronts.png")
    assert path.stat().st_size > 0


def test_settings_refuse_a_front_scenario_with_other_methods():
    with pytest.raises(ValueError, match="front scenario runs"):
        BenchmarkSettings(methods=["hddpg"], scenario="front")
    with pytest.raises(ValueError, match="cannot learn a given preference"):
        BenchmarkSettings(methods=["hddpg-front"], scenario="transfer", preferences=["goal=2,avoid=1"])
    # One run of record may measure the fronts beside the standard methods, on the snake arm.
    beside = BenchmarkSettings(methods=["hddpg", "ham-tuned", "goal-only", "ddpg", "hddpg-front"])
    assert beside.methods == ["hddpg", "ham-tuned", "goal-only", "ddpg", "hddpg-front"]
    # There its conditioned manager, tested at the unweighted preference, is paired with every baseline and
    # with hddpg, as a challenger is; hddpg is not paired with it.
    pairs = comparison_pairs(beside)
    assert {("hddpg-front", b) for b in ("ham-tuned", "goal-only", "ddpg", "hddpg")} <= set(pairs)
    assert ("hddpg", "hddpg-front") not in pairs


def test_the_fronts_managers_are_of_one_algorithm_and_budget():
    default = BenchmarkSettings(methods=["hddpg-front"], timesteps=1000, scenario="front")
    assert default.front_manager == "ddpg"
    assert default.front_run_options(3) == default.manager_run_options(3)
    settings = BenchmarkSettings(
        methods=["hddpg-front"], timesteps=1000, scenario="front", front_manager="DQN", front_timesteps=16_000,
        eval_freq=4000,
    )  # fmt: skip
    assert settings.front_manager == "dqn"  # the registry's name
    run = settings.front_run_options(3)
    steps = settings.option_steps_of("dqn")
    assert (run.timesteps, run.eval_freq, run.seed) == (16_000 // steps, 4000 // steps, 3)
    assert settings.flat_budget == default.flat_budget  # a flat agent's budget does not follow the front's
    assert (default.front_env_steps, settings.front_env_steps) == (default.manager_env_steps, 16_000)
    # The scheduler's cost and the record's blocks are the front's managers', not the DDPG manager's.
    front = METHOD_REGISTRY["hddpg-front"]
    assert front.cost(settings) == (1 + len(SWEEP.points)) * 16_000
    assert list(front.config_blocks(settings)) == [f"dqn.yml[{MANAGER_KEY}]"]
    assert list(front.config_blocks(default)) == [f"ddpg.yml[{MANAGER_KEY}]"]
    if sbx_installed():  # SBX has no DQN here: the front's DQN managers train on SB3, the others on SBX
        on_sbx = BenchmarkSettings(
            methods=["hddpg-front"], scenario="front", front_manager="dqn", backend="sbx"
        )
        assert (on_sbx.front_run_options(0).backend, on_sbx.manager_run_options(0).backend) == ("sb3", "sbx")
        assert on_sbx.manager_run_options(0, "dqn").backend == "sb3"  # the benchmark's hddpg-dqn too
    with pytest.raises(ValueError, match="front's manager among"):
        BenchmarkSettings(methods=["hddpg-front"], scenario="front", front_manager="ppo2")
    with pytest.raises(ValueError, match="front_timesteps"):
        BenchmarkSettings(methods=["hddpg-front"], scenario="front", front_timesteps=0)


def test_the_fronts_sweep_and_motion_are_checked_and_priced():
    wide = BenchmarkSettings(
        methods=["hddpg-front"], scenario="front", front_timesteps=1000, front_sweep="ratio-sweep:16", front_motion=20
    )  # fmt: skip
    assert (
        METHOD_REGISTRY["hddpg-front"].cost(wide) == (1 + 9) * 1000
    )  # 16:1 ... 1:16, and the conditioned one
    assert wide.front_motion == 20.0
    alone = BenchmarkSettings(methods=["hddpg-front"], scenario="front", front_timesteps=1000,
                              front_sweep="ratio-sweep:16", front_per_preference=False)  # fmt: skip
    assert METHOD_REGISTRY["hddpg-front"].cost(alone) == 1000  # the conditioned manager alone
    with pytest.raises(ValueError, match="front_per_preference"):
        BenchmarkSettings(methods=["hddpg-front"], scenario="front", front_per_preference="no")
    for bad in ({"front_sweep": "ratio-sweep:3"}, {"front_sweep": "dirichlet"}, {"front_motion": -1.0},
                {"front_motion": float("nan")}, {"front_option_steps": 0},
                {"front_option_steps": 10**6}):  # fmt: skip
        with pytest.raises(ValueError, match=r"sweep|motion|option steps"):
            BenchmarkSettings(methods=["hddpg-front"], scenario="front", **bad)


def test_the_fronts_option_steps_set_its_managers_decisions_at_the_same_env_steps():
    common = {
        "methods": ["hddpg-front"],
        "scenario": "front",
        "front_manager": "dqn",
        "front_timesteps": 4000,
    }
    # The DQN manager block holds each choice for 4 env steps; deciding every step makes 4 times the decisions.
    assert BenchmarkSettings(**common).front_run_options(0).timesteps == 1000
    assert BenchmarkSettings(**common, front_option_steps=1).front_run_options(0).timesteps == 4000


def test_shorter_options_keep_the_manager_blocks_horizon_in_env_steps():
    # DQN's manager block: gamma 0.9 over 4-step options, about 40 env steps ahead.
    assert horizon_gamma(4, "dqn") == pytest.approx(0.9)
    assert horizon_gamma(1, "dqn") == pytest.approx(0.9**0.25)
    assert horizon_gamma(1, "dqn") ** 4 == pytest.approx(horizon_gamma(4, "dqn"))
    # Any block: its own options give its own discount, twice as long ones its square.
    ddpg_block = manager_hyperparams("ddpg")
    steps, gamma = ddpg_block.wrapper_kwargs["option_steps"], ddpg_block.algo_kwargs["gamma"]
    assert horizon_gamma(steps, "ddpg") == pytest.approx(gamma)
    assert horizon_gamma(2 * steps, "ddpg") == pytest.approx(gamma**2)


def test_benchmark_cli_refuses_an_unknown_front_manager_in_one_line(tmp_path):
    result = run_cli(
        "benchmark", "--scenario", "front", "--front-manager", "ppo2", "--out", str(tmp_path / "b")
    )
    assert result.returncode == 2 and "front's manager among" in result.stdout + result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "b").exists()


def test_benchmark_cli_refuses_zero_option_steps_in_one_line(tmp_path):
    result = run_cli(
        "benchmark", "--scenario", "front", "--front-option-steps", "0", "--out", str(tmp_path / "b")
    )
    assert result.returncode == 2 and "option steps in [1," in result.stdout + result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "b").exists()


@pytest.mark.slow
def test_a_front_of_dqn_managers_records_its_algorithm_and_budget(tmp_path):
    settings = BenchmarkSettings(
        methods=["hddpg-front"], seeds=[0], timesteps=120, worker_timesteps=200, eval_episodes=1,
        test_episodes=1, scenario="front", front_manager="dqn", front_timesteps=400,
        front_sweep="ratio-sweep:16", front_motion=20.0, front_option_steps=2,
    )  # fmt: skip
    results = run_benchmark(settings, tmp_path)
    record = json.loads((tmp_path / "records" / "hddpg-front" / "seed-0.json").read_text())
    # Half the block's 4-step options: the discount's square root keeps its horizon in env steps.
    assert record["manager"].pop("gamma") == pytest.approx(0.9**0.5)
    assert record["manager"] == {
        "algo": "dqn", "env_steps": 400, "backend": "sb3", "sweep": "ratio-sweep:16", "motion": 20.0,
        "per_preference": True, "option_steps": 2,
    }  # fmt: skip
    assert results["front"]["manager"] == {**record["manager"], "gamma": pytest.approx(0.9**0.5)}
    assert (
        "DQN (SB3), 400 env steps each, deciding every 2 env steps (discount 0.949 a decision), over "
        "ratio-sweep:16, seeing motion (x20)" in (tmp_path / "results.md").read_text()
    )
    # The sweep's extremes, 16:1 and 1:16, are points of the conditioned manager's front.
    labels = [p["label"] for p in record["front"]["conditioned"]["points"]]
    assert len(labels) == 9 and labels[0] == "goal=1.882,avoid=0.1176"
    bundle = Hierarchy.load(tmp_path / "seed-0" / "hddpg-front" / "conditioned" / "hierarchy.zip")
    assert type(bundle.manager).__name__ == "DQN"
    assert bundle.config.manager_motion == 20.0
    assert bundle.config.option_steps == 2
    assert bundle.observation_space.shape[0] * 2 + 2 == bundle.manager.observation_space.shape[0]


@pytest.mark.slow
def test_the_front_scenario_runs_end_to_end_at_a_tiny_budget(tmp_path):
    settings = BenchmarkSettings(
        methods=["hddpg-front"], seeds=[0, 1], timesteps=120, worker_timesteps=200, eval_episodes=1,
        test_episodes=1, scenario="front",
    )  # fmt: skip
    results = run_benchmark(settings, tmp_path)
    front = results["front"]
    assert set(front["members"]) == {"conditioned", "per-preference", "ham", "goal", "avoid", "gpi"}
    record = json.loads((tmp_path / "records" / "hddpg-front" / "seed-0.json").read_text())
    assert len(record["front"]["conditioned"]["points"]) == len(SWEEP.points)
    # GPI over the same workers, at every preference of the sweep, with no manager of its own.
    assert [p["label"] for p in record["front"]["gpi"]["points"]] == sweep_labels()
    assert "conditioned vs gpi" in front["comparisons"]
    assert len(record["front"]["per-preference"]["points"]) == len(SWEEP.points)
    assert record["front"]["ham"]["points"]
    # HAM's thresholds come from the curve episodes, never the test episodes.
    assert record["rule"] == "ham" and all("threshold" in t for t in record["rule_thresholds"])
    assert record["references"] == {"outcomes": [0.0, 20.0], "terms": [0.0, 0.0]}
    for plane in ("outcomes", "terms"):
        assert front["hypervolume_per_seed"]["conditioned"][plane].keys() == {"0", "1"}
    assert "conditioned vs ham" in front["comparisons"]
    assert (tmp_path / "fronts.png").stat().st_size > 0
    assert "The front" in (tmp_path / "results.md").read_text()
    dependence = next(iter(record["decides_by_state"].values()))
    assert dependence is None or dependence["unit"] == "decisions"
    # The conditioned bundle of the run acts at every swept preference.
    bundle = Hierarchy.load(tmp_path / "seed-0" / "hddpg-front" / "conditioned" / "hierarchy.zip")
    for point in SWEEP.points:
        bundle.set_preference(dict(zip(SWEEP.names, point)))
    # Exported: the conditioned bundle with the space it was trained over, every per-preference manager
    # with its preference; a fresh process loads the exported conditioned bundle and acts at any of them.
    export = tmp_path.parent / f"{tmp_path.name}-export"
    index = export_models(tmp_path, export)
    conditioned = [e for e in index if e["method"] == "hddpg-conditioned"]
    per_preference = [e for e in index if e["method"] == "hddpg-preference"]
    assert [e["seed"] for e in conditioned] == [0, 1]
    assert all(e["manager_preferences"]["points"] for e in conditioned)
    assert len(per_preference) == 2 * len(SWEEP.points)
    gpi = [e for e in index if e["method"] == "hddpg-gpi"]
    assert [e["seed"] for e in gpi] == [0, 1]
    assert Hierarchy.load(export / gpi[0]["path"]).manager is None
    assert {e["preference"] for e in per_preference} == set(sweep_labels())
    script = (
        "import sys, gymnasium as gym, sb3_hddpg\n"
        "from sb3_hddpg.hierarchy.hierarchy import Hierarchy\n"
        "h = Hierarchy.load(sys.argv[1])\n"
        "env = gym.make('hddpg/SnakeReach-v0'); obs, _ = env.reset(seed=900)\n"
        "for goal in (1.6, 1.0, 0.4):\n"
        "    h.set_preference({'goal': goal, 'avoid': 2 - goal}); h.predict(obs, deterministic=True)\n"
        "print('acted')\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(export / conditioned[0]["path"])], capture_output=True, text=True
    )
    assert done.returncode == 0 and "acted" in done.stdout, done.stderr[-2000:]


def test_decisions_are_counted_once_per_option(tmp_path):
    pytest.importorskip("pymoo")
    from sb3_hddpg.training.manager import train_manager
    from sb3_hddpg.training.workers import train_workers

    train_workers(tmp_path / "w", seed=1, timesteps=200, eval_freq=0, eval_episodes=1)
    hierarchy = train_manager(tmp_path / "w", tmp_path / "m", option_steps=4, seed=1, timesteps=60,
                                 eval_freq=0, eval_episodes=1).hierarchy  # fmt: skip
    env = gym.make("hddpg/SnakeReach-v0")
    figure = decision_dependence(hierarchy, env, range(15_000, 15_002))
    assert figure is not None and figure["unit"] == "decisions"
    steps = 2 * env.spec.max_episode_steps
    # A decision every 4 env steps: at most a quarter of the steps fall in either band.
    assert figure["near_decisions"] + figure["clear_decisions"] <= np.ceil(steps / 4)


def test_benchmark_cli_refuses_methods_outside_the_front_scenario(tmp_path):
    result = run_cli("benchmark", "--scenario", "front", "--methods", "hddpg", "--out", str(tmp_path / "b"))
    assert result.returncode == 2 and "front scenario runs" in result.stdout + result.stderr


@pytest.mark.slow
def test_the_support_method_grows_a_support_with_critics_and_starts_its_manager_from_gpi(tmp_path_factory):
    tmp_path = tmp_path_factory.mktemp("support-benchmark")
    preferences = ";".join(
        ("goal=2,avoid=0.5,mix-goal50-avoid50=0.5", "goal=0.5,avoid=2,mix-goal50-avoid50=0.5",
         "goal=0.5,avoid=0.5,mix-goal50-avoid50=2")
    )  # fmt: skip
    settings = BenchmarkSettings(
        methods=["hddpg-support"], seeds=[0], timesteps=120, worker_timesteps=200, eval_episodes=1,
        test_episodes=1, scenario="front", front_manager="dqn", front_timesteps=200, front_sweep=preferences,
        front_support="goal=0.5,avoid=0.5", front_start="gpi", front_critic_steps=150,
        front_per_preference=False, backend="sb3",
    )  # fmt: skip
    run_benchmark(settings, tmp_path)
    record = json.loads((tmp_path / "records" / "hddpg-support" / "seed-0.json").read_text())
    assert record["manager"]["start"] == "gpi" and record["manager"]["backend"] == "sb3"
    assert record["manager"]["workers"] == ["goal", "avoid", "mix-goal50-avoid50"]
    # Three workers of 200 steps, and each one's critic fitted on 150 env steps of its rollouts.
    assert record["worker_timesteps"] == 3 * 200 + 3 * 150
    front = record["front"]
    assert {"conditioned", "ham", "goal", "avoid", "mix-goal50-avoid50", "gpi"} <= set(front)
    assert len(front["conditioned"]["points"]) == len(front["gpi"]["points"]) == 3
    bundle = Hierarchy.load(tmp_path / "seed-0" / "hddpg-support" / "conditioned" / "hierarchy.zip")
    assert bundle.names == ["goal", "avoid", "mix-goal50-avoid50"] and "init_from_gpi" in bundle.metadata
    exported_to = tmp_path_factory.mktemp("support-export") / "models"
    exported = {entry["method"] for entry in export_models(tmp_path, exported_to)}
    assert {"hddpg-support", "hddpg-support-gpi", "ham-threshold", "worker:goal"} <= exported
    # Only the models the docs re-evaluate: GPI's bundle and HAM, whose per-term workers go with it.
    chosen = tmp_path_factory.mktemp("support-chosen") / "models"
    index = export_models(tmp_path, chosen, ["hddpg-support-gpi", "ham-threshold"])
    assert sorted(entry["method"] for entry in index) == ["ham-threshold", "hddpg-support-gpi"]
    assert (chosen / "seed-0" / "workers" / "goal.zip").is_file()
    assert not (chosen / "seed-0" / "hddpg-support" / "conditioned").exists()
    with pytest.raises(ValueError, match="also \\['hddpg-nope'\\]"):
        export_models(tmp_path, chosen, ["hddpg-nope"])
    # The seed's own workers are untouched: the support is a copy.
    manifest = json.loads((tmp_path / "seed-0" / "workers" / "manifest.json").read_text())
    assert list(manifest["workers"]) == ["goal", "avoid"]
    with pytest.raises(ValueError, match="gpi or none"):
        BenchmarkSettings(methods=["hddpg-support"], scenario="front", front_start="ham")
    with pytest.raises(ValueError, match="front-support"):
        BenchmarkSettings(methods=["hddpg-front"], scenario="front", front_sweep=preferences)


def test_a_resumed_support_fits_only_the_workers_still_without_a_rollout_critic(tmp_path, monkeypatch):
    from pathlib import Path
    from types import SimpleNamespace

    from hddpg_zoo.benchmark import front_support

    shipped = Path(__file__).resolve().parents[1] / "docs" / "results" / "cheetah" / "seed-0" / "workers"
    manifest = json.loads((shipped / "manifest.json").read_text())
    # Interrupted after the first worker's critic: speed's is fitted on 40 rollout steps, energy's is not.
    manifest["workers"]["speed"]["term_critic"] = {"kind": "state_value", "env_steps": 40}
    workers = tmp_path / front_support.SUPPORT_METHOD / "support" / "workers"
    workers.mkdir(parents=True)
    (workers / "manifest.json").write_text(json.dumps(manifest))
    calls = []
    monkeypatch.setattr(front_support, "fit_state_critics", lambda *args, **kwargs: calls.append(args))
    settings = SimpleNamespace(front_support=None, front_critic_steps=40)
    front_support.support_folder(SimpleNamespace(seed=0), settings, tmp_path)
    assert [list(args[1]) for args in calls] == [["energy"]]
    # Every worker fitted on as many steps: nothing is fitted again.
    manifest["workers"]["energy"]["term_critic"] = {"kind": "state_value", "env_steps": 40}
    (workers / "manifest.json").write_text(json.dumps(manifest))
    front_support.support_folder(SimpleNamespace(seed=0), settings, tmp_path)
    assert len(calls) == 1
