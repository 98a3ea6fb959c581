"""Benchmark methods as records, TD3/SAC baselines, the transfer scenario and the model export."""

from __future__ import annotations

import functools
import json
import shutil
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from hddpg_zoo import stats
from hddpg_zoo.benchmark import (
    DEFAULT_METHODS,
    METHOD_REGISTRY,
    METHODS,
    BenchmarkSettings,
    Method,
    Task,
    compute_results,
    markdown_report,
    normalised_term_sums,
    plan_tasks,
    preference_score,
    register_method,
    steps_to_fraction,
    task_cost,
    write_outputs,
)
from sb3_hddpg.artifacts.run_folder import RunFolderError
from sb3_hddpg.hierarchy.preference import PreferenceReward
from tests.cli_batch import run_batch
from tests.test_benchmark import cli, record, summary

TINY = (
    "--timesteps", "200", "--worker-timesteps", "100", "--eval-freq", "100",
    "--eval-episodes", "1", "--test-episodes", "1",
)  # fmt: skip


# ------------------------------------------------------------------------------------------------ records
def test_td3_and_sac_are_flat_records_given_the_hierarchy_total_steps():
    settings = BenchmarkSettings(
        methods=["hddpg", "td3", "sac"], seeds=[0], timesteps=1000, worker_timesteps=300
    )
    for name in ("td3", "sac"):
        method = METHOD_REGISTRY[name]
        assert name in METHODS and name not in DEFAULT_METHODS
        assert not method.needs_workers and method.baseline and method.takes_preference
        assert task_cost(Task(name, 0), settings) == settings.manager_env_steps + 2 * 300
    # The manager's 1000 decisions are option_steps env steps each.
    assert task_cost(Task("hddpg", 0), settings) == 1000 * settings.option_steps == settings.manager_env_steps
    assert task_cost(Task("workers", 0), settings) == 600
    assert METHOD_REGISTRY["td3"].colour != METHOD_REGISTRY["sac"].colour


def test_td3_and_sac_are_compared_with_hddpg_and_reported():
    settings = BenchmarkSettings(methods=["hddpg", "ddpg", "td3", "sac"], seeds=[0, 1, 2], timesteps=3000)
    records = []
    for seed in range(3):
        records.append(record("hddpg", seed, [200.0, 210.0, 220.0], 230.0 + seed))
        records.append(record("ddpg", seed, [190.0, 195.0, 200.0], 210.0 - seed))
        for name, test in (("td3", 215.0 + 2 * seed), ("sac", 225.0 - seed)):
            # A flat agent: no worker pre-training (record() offsets all but ddpg by default).
            records.append({**record("ddpg", seed, [190.0, 200.0, 205.0], test), "method": name})
    results = compute_results(settings, records)
    for name, tests in (("td3", [215.0, 217.0, 219.0]), ("sac", [225.0, 224.0, 223.0])):
        comparison = results["comparisons"][f"hddpg vs {name}"]
        interval = stats.paired_t_interval([230.0, 231.0, 232.0], tests)
        assert comparison["mean_reach_reward"]["difference"] == pytest.approx(interval["difference"])
        assert (comparison["mean_reach_reward"]["ci_low"], comparison["mean_reach_reward"]["ci_high"]) == (
            interval["ci_low"],
            interval["ci_high"],
        )
        assert results["colours"][name] == METHOD_REGISTRY[name].colour
    report = markdown_report(results)
    assert "| hddpg vs td3 | mean_reach_reward |" in report and "| sac | 3 |" in report


def test_a_new_method_is_one_record(tmp_path):
    def run(task: Task, settings: BenchmarkSettings, folder: Path) -> dict[str, Any]:
        raise AssertionError("not run in this test")

    method = Method("scripted-ik", run, lambda settings: 0, colour="black", baseline=True)
    register_method(method)
    try:
        with pytest.raises(ValueError, match="taken or reserved"):
            register_method(method)
        settings = BenchmarkSettings(methods=["hddpg", "scripted-ik"], seeds=[0, 1], timesteps=2000)
        assert [t.label for t in plan_tasks(settings)][:3] == [
            "workers/seed-0",
            "hddpg/seed-0",
            "scripted-ik/seed-0",
        ]
        records = [record("hddpg", s, [200.0, 210.0], 230.0 + s) for s in range(2)]
        records += [{**record("ham", s, [220.0], 220.0), "method": "scripted-ik"} for s in range(2)]
        results = compute_results(settings, records)
        assert "hddpg vs scripted-ik" in results["comparisons"]  # baseline=True: compared with hddpg
        assert results["colours"]["scripted-ik"] == "black"
        write_outputs(tmp_path, results, records)  # its colour reaches the plots without a table to edit
        assert (tmp_path / "learning_curves.png").stat().st_size > 0
    finally:
        METHOD_REGISTRY.pop("scripted-ik")
    with pytest.raises(ValueError, match="taken or reserved"):
        register_method(Method("workers", run, lambda settings: 0))


def test_state_dependence_per_seed_in_the_results():
    settings = BenchmarkSettings(methods=["hddpg", "ddpg"], seeds=[0, 1, 2, 3], timesteps=2000)
    choices = {
        0: ({"avoid": 30, "goal": 10}, {"avoid": 10, "goal": 90}),  # near 75 %, clear 10 %: ratio 7.5
        1: ({"avoid": 5, "goal": 15}, {"avoid": 25, "goal": 75}),  # a fixed mix: 25 % and 25 %
        2: ({"avoid": 5, "goal": 15}, {"goal": 100}),  # HAM-like: never with none in range
        3: ({"goal": 20}, {"goal": 100}),  # the avoid worker never chosen
    }
    records = []
    for seed, (near, clear) in choices.items():
        test = summary(
            230.0,
            selection_rate={"avoid": 0.5, "goal": 0.5},
            selections_near=near,
            selections_clear=clear,
            near_clearance=0.15,
            clear_clearance=0.3,
        )
        records.append({**record("hddpg", seed, [200.0, 210.0], 230.0), "test": test})
        records.append(record("ddpg", seed, [190.0, 200.0], 210.0))
    results = compute_results(settings, records)
    figures = results["methods"]["hddpg"]["state_dependence"]
    assert figures["0"]["near_share"] == 0.75 and figures["0"]["clear_share"] == 0.1
    assert figures["0"]["ratio"] == pytest.approx(7.5) and figures["1"]["ratio"] == pytest.approx(1.0)
    assert "state_dependence" not in results["methods"]["ddpg"]  # a flat agent makes no choices
    report = markdown_report(results)
    assert "| hddpg | 0 | 75.0% (40) | 10.0% (100) | 7.50 |" in report
    assert "| hddpg | 1 | 25.0% (20) | 25.0% (100) | 1.00 |" in report
    # No number for the last two, but each says why: an infinite ratio is not a fixed mix.
    assert figures["2"]["ratio"] is None and figures["3"]["ratio"] is None
    assert "| hddpg | 2 | 25.0% (20) | 0.0% (100) | inf |" in report
    assert "| hddpg | 3 | 0.0% (20) | 0.0% (100) | never chosen |" in report


# ----------------------------------------------------------------------------------------------- transfer
def test_preference_reward_is_the_weighted_sum_of_normalised_terms():
    reach = gym.make("hddpg/SnakeReach-v0")
    weighted = PreferenceReward(gym.make("hddpg/SnakeReach-v0"), {"goal": 2.0, "avoid": 0.5})
    equal = PreferenceReward(gym.make("hddpg/SnakeReach-v0"), {})
    for env in (reach, weighted, equal):
        env.reset(seed=4)
    rng = np.random.default_rng(0)
    for _ in range(30):
        action = rng.uniform(-1, 1, reach.action_space.shape).astype(np.float32)
        _, reach_reward, *_ = reach.step(action)
        _, reward, _, _, info = weighted.step(action)
        _, equal_reward, *_ = equal.step(action)
        normalised = reach.unwrapped.normalise_terms(info["reward_terms"])
        assert reward == pytest.approx(2.0 * normalised["goal"] + 0.5 * normalised["avoid"])
        assert equal_reward == pytest.approx(reach_reward)  # every factor 1: the reach reward itself
    with pytest.raises(ValueError, match="Unknown reward terms"):
        PreferenceReward(gym.make("hddpg/SnakeReach-v0"), {"speed": 1.0})
    with pytest.raises(ValueError, match="finite number > 0"):
        PreferenceReward(gym.make("hddpg/SnakeReach-v0"), {"goal": 0.0})


def test_steps_to_fraction_of_the_final_score():
    curve = [{"timesteps": 100 * (i + 1), "score": v} for i, v in enumerate([10.0, 50.0, 88.0, 92.0, 100.0])]
    score = functools.partial(lambda point: point["score"])
    assert steps_to_fraction(curve, score, 0.9) == 400  # 90 % of 100: 92 at step 400
    # From a floor of 50 (a random policy's score): 50 + 0.9 * 50 = 95, first reached at the end.
    assert steps_to_fraction(curve, score, 0.9, floor=50.0) == 500
    assert steps_to_fraction(curve, score, 0.5, floor=50.0) == 300
    assert steps_to_fraction(curve, score, 0.9, floor=100.0) is None  # no gain over the floor
    # Toward another run's final score: 90 % of the way from 50 to 90 is 86, first reached at step 300;
    # a final it never gets near gives None.
    assert steps_to_fraction(curve, score, 0.9, floor=50.0, final=90.0) == 300
    assert steps_to_fraction(curve, score, 0.9, floor=50.0, final=200.0) is None
    with pytest.raises(ValueError, match="fraction"):
        steps_to_fraction(curve, score, 1.5)


def test_preference_score_weights_the_normalised_parts():
    s = summary(200.0, mean_goal_reward=-40.0, mean_avoid_reward=30.0)
    goal, avoid = normalised_term_sums(s)
    assert preference_score(s, {"goal": 2.0, "avoid": 1.0}) == pytest.approx(2 * goal + avoid)
    assert preference_score(s, {}) == pytest.approx(goal + avoid)


def transfer_record(method: str, seed: int, goal_avoid: list[tuple[float, float]], worker_steps: int) -> dict:
    """A transfer run's record whose curve has the given normalised goal / avoid episode sums."""
    bounds = __import__("sb3_hddpg.envs", fromlist=["SnakeArmEnv"]).SnakeArmEnv().reward_bounds

    def raw(part: float, term: str) -> float:  # the raw mean whose normalised episode sum is `part`
        low, high = bounds[term]
        return part * (high - low) + 200.0 * low

    def point(goal: float, avoid: float) -> dict[str, Any]:
        return summary(
            goal + avoid, mean_goal_reward=raw(goal, "goal"), mean_avoid_reward=raw(avoid, "avoid")
        )

    return {
        "method": method,
        "seed": seed,
        "status": "done",
        "worker_timesteps": worker_steps,
        "history": [
            {"timesteps": 100 * (i + 1), "total_timesteps": 100 * (i + 1) + worker_steps, **point(g, a)}
            for i, (g, a) in enumerate(goal_avoid)
        ],
        "test": point(*goal_avoid[-1]),
        "preference": method.partition("@")[2],
        "reference": point(50.0, 150.0),  # the random policy: 2 * 50 + 150 = 250 under goal=2,avoid=1
    }


def test_transfer_ratio_per_seed_with_a_bootstrap_ci():
    settings = BenchmarkSettings(
        methods=["hddpg", "ddpg", "hddpg-sac"],
        seeds=[0, 1, 2],
        timesteps=400,
        scenario="transfer",
        preferences=["goal=2, avoid=1"],
    )
    assert settings.preferences == ["goal=2,avoid=1"]  # one spelling names the runs
    assert settings.method_keys == ["hddpg@goal=2,avoid=1", "ddpg@goal=2,avoid=1", "hddpg-sac@goal=2,avoid=1"]
    assert Task("ddpg@goal=2,avoid=1", 0).preferences == {"goal": 2.0, "avoid": 1.0}
    records = []
    for seed in range(3):
        # Manager: past 90 % of the way from 250 to its final 350 (340) at its 1st evaluation (100 steps).
        records.append(transfer_record("hddpg@goal=2,avoid=1", seed, [(96.0, 150.0), (100.0, 150.0)], 200))
        # Flat: from 250 to 330; past 322 first at evaluation 2 + seed.
        curve = [(50.0, 150.0)] * (1 + seed) + [(87.0, 150.0), (90.0, 150.0)]
        records.append(transfer_record("ddpg@goal=2,avoid=1", seed, curve, 0))
        # A SAC manager, there at its 2nd evaluation (200 steps).
        sac_curve = [(50.0, 150.0), (96.0, 150.0), (100.0, 150.0)]
        records.append(transfer_record("hddpg-sac@goal=2,avoid=1", seed, sac_curve, 200))
    results = compute_results(settings, records)
    entry = results["transfer"]["preferences"]["goal=2,avoid=1"]["ddpg"]
    assert [entry["per_seed"][str(s)]["manager_steps"] for s in range(3)] == [100, 100, 100]
    assert [entry["per_seed"][str(s)]["flat_steps"] for s in range(3)] == [200, 300, 400]
    assert entry["per_seed"]["0"]["random_score"] == pytest.approx(250.0)
    assert entry["per_seed"]["0"]["manager_final_score"] == pytest.approx(350.0)
    assert entry["ratio"] == stats.summarise([2.0, 3.0, 4.0])
    # The flat agents end at 330, below 90 % of the way to the manager's 350 (340): none gets there.
    assert entry["seeds_flat_reaches_manager"] == 0
    assert all(v["flat_steps_to_manager_final"] is None for v in entry["per_seed"].values())
    assert "hddpg@goal=2,avoid=1 vs ddpg@goal=2,avoid=1" in results["comparisons"]
    report = markdown_report(results)
    assert "| goal=2,avoid=1 | hddpg | ddpg | 3/3 | 100 | 300 | 3.00 [" in report
    assert "| 350.0 / 330.0 | 0/3 |" in report
    # Every hierarchy is compared with every flat agent; the SAC manager's entry names both.
    sac = results["transfer"]["preferences"]["goal=2,avoid=1"]["ddpg vs hddpg-sac"]
    assert (sac["manager"], sac["flat"], entry["manager"]) == ("hddpg-sac", "ddpg", "hddpg")
    assert [sac["per_seed"][str(s)]["manager_steps"] for s in range(3)] == [200, 200, 200]
    assert sac["ratio"] == stats.summarise([1.0, 1.5, 2.0])
    assert "| goal=2,avoid=1 | hddpg-sac | ddpg | 3/3 | 200 | 300 | 1.50 [" in report


def test_transfer_settings_are_checked():
    with pytest.raises(ValueError, match="cannot learn a given preference"):
        BenchmarkSettings(methods=["hddpg", "ham"], scenario="transfer", preferences=["goal=2,avoid=1"])
    with pytest.raises(ValueError, match="compares hddpg with flat agents"):
        BenchmarkSettings(methods=["ddpg", "td3"], scenario="transfer", preferences=["goal=2,avoid=1"])
    with pytest.raises(ValueError, match="finite number > 0"):
        BenchmarkSettings(methods=["hddpg", "ddpg"], scenario="transfer", preferences=["goal=-1"])
    with pytest.raises(ValueError, match="transfer scenario only"):
        BenchmarkSettings(methods=["hddpg", "ddpg"], preferences=["goal=2"])
    with pytest.raises(ValueError, match="Unknown scenario"):
        BenchmarkSettings(scenario="zero-shot")


def test_usage_errors_through_the_cli(tmp_path):
    out = str(tmp_path / "b")
    transfer, without, sideways, export = run_batch(
        [
            ["benchmark", "--scenario", "transfer", "--preference", "goal=x", "--out", out],
            ["benchmark", "--preference", "goal=2", "--out", out],
            ["benchmark", "--scenario", "sideways", "--out", out],
            ["export-models", str(tmp_path), out],
        ]
    )
    assert transfer.returncode == 2 and "'goal'" in transfer.stderr
    assert without.returncode == 2 and "--scenario transfer" in without.stderr
    assert sideways.returncode == 2 and "--scenario" in sideways.stderr
    assert export.returncode == 2 and "not a benchmark folder" in export.stderr
    for done in (transfer, without, sideways, export):
        assert "Traceback" not in done.stderr
    assert not (tmp_path / "b").exists()


@pytest.mark.slow
def test_tiny_transfer_benchmark_through_the_cli(tmp_path):
    out = tmp_path / "transfer"
    args = ("benchmark", "--scenario", "transfer", "--preference", "goal=2,avoid=1", "--seeds", "1", *TINY)
    done = cli(*args, "--flat-timesteps", "300", "--n-jobs", "2", "--out", str(out))
    assert done.returncode == 0, done.stdout + done.stderr
    results = json.loads((out / "results.json").read_text())
    assert set(results["methods"]) == {"hddpg@goal=2,avoid=1", "ddpg@goal=2,avoid=1"}
    manifest = json.loads((out / "seed-0" / "ddpg@goal=2,avoid=1" / "flat" / "manifest.json").read_text())
    assert manifest["models"]["ddpg"]["preferences"] == {"goal": 2.0, "avoid": 1.0}
    entry = results["transfer"]["preferences"]["goal=2,avoid=1"]["ddpg"]["per_seed"]["0"]
    for key in (
        "manager_steps",
        "flat_steps",
    ):  # an evaluation step of the run, or None (no gain over random)
        assert entry[key] is None or entry[key] in (100, 200, 300)
    assert "Transfer" in done.stdout and "Transfer:" in (out / "results.md").read_text()


@pytest.mark.slow  # two tiny benchmarks: ~20 s idle
def test_workers_from_another_benchmark_are_copied_checked_and_never_retrained(tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    args = ("benchmark", "--seeds", "1", "--methods", "goal-only", *TINY)
    done = cli(*args, "--out", str(first))
    assert done.returncode == 0, done.stdout + done.stderr
    reuse, other_budget, missing_seed, not_a_run, other_curve = run_batch(
        [
            [*args, "--workers-from", str(first), "--out", str(second)],
            [*args, "--worker-timesteps", "50", "--workers-from", str(first), "--out", str(tmp_path / "c")],
            ["benchmark", "--seeds", "2", "--methods", "goal-only", *TINY, "--workers-from", str(first),
             "--out", str(tmp_path / "d")],
            [*args, "--workers-from", str(tmp_path), "--out", str(tmp_path / "e")],
            [*args, "--eval-episodes", "2", "--workers-from", str(first), "--out", str(tmp_path / "f")],
        ]
    )  # fmt: skip
    assert reuse.returncode == 0, reuse.stdout + reuse.stderr
    for name in ("goal.zip", "avoid.zip", "manifest.json"):
        copied = (second / "seed-0" / "workers" / name).read_bytes()
        assert copied == (first / "seed-0" / "workers" / name).read_bytes()
    assert not (second / "seed-0" / "checkpoints").exists()  # nothing was trained again
    record = json.loads((second / "records" / "workers" / "seed-0.json").read_text())
    # Recorded relative to the benchmark's folder: the record holds no path of this machine.
    assert record["workers_from"] == "../first/seed-0"
    assert json.loads((second / "benchmark.json").read_text())["settings"]["workers_from"] == "../first"
    original = json.loads((first / "records" / "workers" / "seed-0.json").read_text())
    assert record["history"] == original["history"] and record["worker_timesteps"] == 204
    scores = [
        json.loads((run / "records" / "goal-only" / "seed-0.json").read_text())["test"]
        for run in (first, second)
    ]
    assert scores[0] == scores[1]

    # What would not be the same workers is refused before anything is written.
    assert other_budget.returncode == 2 and "worker_timesteps=100" in other_budget.stderr
    assert missing_seed.returncode == 2 and "no finished workers for seed 1" in missing_seed.stderr
    assert not_a_run.returncode == 2 and "not a benchmark folder" in not_a_run.stderr
    # Its best checkpoint was picked on curves of 1 episode: a run evaluating on 2 would pick another.
    assert other_curve.returncode == 2 and "on 1 episodes, this benchmark evaluates" in other_curve.stderr
    for refused, folder in ((other_budget, "c"), (missing_seed, "d"), (not_a_run, "e"), (other_curve, "f")):
        assert "Traceback" not in refused.stderr and not (tmp_path / folder).exists()

    # Both folders copied elsewhere (another machine): the copy resumes with the new path, its runs kept;
    # a run that trained its own workers is not resumed onto copied ones.
    moved = tmp_path / "moved"
    shutil.copytree(first, moved / "first")
    shutil.copytree(second, moved / "second")
    resumed, mixed = run_batch(
        [
            [*args, "--workers-from", str(moved / "first"), "--out", str(moved / "second"), "--resume"],
            [*args, "--workers-from", str(moved / "second"), "--out", str(moved / "first"), "--resume"],
        ]
    )
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert "started" not in resumed.stdout and resumed.stdout.count("kept") == 2
    assert mixed.returncode == 2 and "workers_from changed" in mixed.stderr


# ------------------------------------------------------------------------------- references without training
@pytest.mark.slow  # a tiny benchmark plus HAM's 24-threshold grid: ~30 s idle, minutes on a loaded machine
def test_tuned_ham_and_workers_alone_are_scored_on_the_same_episodes(tmp_path):
    from sb3_hddpg.episode_sets import DEVELOPMENT
    from sb3_hddpg.evaluation import evaluate
    from sb3_hddpg.hierarchy.loading import load_policy

    out = tmp_path / "bench"
    methods = "ham,ham-tuned,goal-only"
    done = cli("benchmark", "--seeds", "1", "--methods", methods, *TINY, "--out", str(out))
    assert done.returncode == 0, done.stdout + done.stderr
    record_of = {m: json.loads((out / "records" / m / "seed-0.json").read_text()) for m in methods.split(",")}

    # The tuned threshold is the grid's best on the learning-curve episodes, which hold HAM's default (5.5):
    # the same deterministic episodes, so the tuned switch can only score as well or better there.
    tuned, default = record_of["ham-tuned"], record_of["ham"]
    grid = tuned["threshold_grid"]
    assert [p["threshold"] for p in grid] == [0.25 * k for k in range(1, 25)]
    best = max(grid, key=lambda p: p["mean_reward"])
    assert tuned["threshold"] == best["threshold"] and default["threshold"] == 5.5
    assert tuned["history"][0]["mean_reward"] == pytest.approx(best["mean_reward"])
    assert best["mean_reward"] >= default["history"][0]["mean_reward"] - 1e-9
    assert (
        json.loads((out / "seed-0" / "ham-tuned" / "ham.json").read_text())["threshold"] == tuned["threshold"]
    )

    # The goal worker alone: its own view of the combined task, on the test episodes every method gets.
    loaded = load_policy(out / "seed-0" / "workers" / "goal.zip")
    env = loaded.make_env("hddpg/SnakeReach-v0")
    expected = evaluate(loaded.policy, env, n_episodes=1, seed=DEVELOPMENT.first_seed).summary()
    env.close()
    assert record_of["goal-only"]["test"]["mean_reach_reward"] == pytest.approx(expected["mean_reach_reward"])
    # It stands on the two workers' steps (the goal worker's 8-step updates round its 100 up to 104).
    assert record_of["goal-only"]["worker_timesteps"] == record_of["ham"]["worker_timesteps"] == 204


def test_the_hand_written_skills_are_a_method_that_trains_nothing(tmp_path):
    from sb3_hddpg.baselines import HAMSwitch
    from sb3_hddpg.envs.snake.controllers import make_controller
    from sb3_hddpg.episode_sets import DEVELOPMENT
    from sb3_hddpg.evaluation import evaluate

    out = tmp_path / "bench"
    done = cli("benchmark", "--seeds", "1", "--methods", "controllers", *TINY, "--out", str(out))
    assert done.returncode == 0, done.stdout + done.stderr
    record = json.loads((out / "records" / "controllers" / "seed-0.json").read_text())
    assert record["worker_timesteps"] == 0 and not (out / "seed-0" / "workers").exists()
    grid = record["threshold_grid"]
    assert record["threshold"] == max(grid, key=lambda p: p["mean_reward"])["threshold"]
    # The record's test is the switch over the IK reacher and the field avoider at that threshold.
    env = gym.make("hddpg/SnakeReach-v0")
    layout = env.unwrapped.state_layout
    switch = HAMSwitch(
        make_controller("ik", layout), make_controller("field", layout), layout, record["threshold"]
    )
    expected = evaluate(switch, env, n_episodes=1, seed=DEVELOPMENT.first_seed).summary()
    assert record["test"]["mean_reach_reward"] == pytest.approx(expected["mean_reach_reward"])


# ------------------------------------------------------------------------------------------------- export
@pytest.mark.slow
def test_every_method_runs_and_its_exported_models_re_evaluate(tmp_path):
    from hddpg_zoo.model_export import read_index
    from sb3_hddpg.evaluation import evaluate
    from sb3_hddpg.hierarchy.loading import load_policy

    out, models = tmp_path / "bench", tmp_path / "models"
    methods = "hddpg,hddpg-goal,hddpg-avoid,hddpg-sac,ham,ddpg,td3,sac"
    args = ("benchmark", "--seeds", "1", "--methods", methods, *TINY, "--out", str(out))
    done = cli(*args, "--export-models", str(models))
    assert done.returncode == 0, done.stdout + done.stderr
    results = json.loads((out / "results.json").read_text())
    # The hierarchy's total env steps: the manager's (200 decisions of the bundled block's option_steps)
    # + 2 x 100 for the workers, rounded up to TD3's 16-step update blocks.
    total = results["methods"]["hddpg"]["own_timesteps"] + 2 * 100
    for name in ("td3", "sac"):
        assert total <= results["methods"][name]["own_timesteps"] < total + 16
        assert f"hddpg vs {name}" in results["comparisons"]
    assert "state_dependence" in results["methods"]["hddpg"] and "State dependence" in done.stdout
    # The SAC manager: the same env steps as the DDPG manager, compared like it with every baseline and with it.
    sac_manager = results["methods"]["hddpg-sac"]
    assert sac_manager["own_timesteps"] == results["methods"]["hddpg"]["own_timesteps"]
    assert {"hddpg-sac vs ham", "hddpg-sac vs ddpg", "hddpg-sac vs hddpg"} <= set(results["comparisons"])
    assert "hddpg-sac vs hddpg-goal" not in results["comparisons"]  # a challenger, not a baseline

    index = read_index(models)  # every file present and matching its sha256
    expected = [
        "worker:goal",
        "worker:avoid",
        "hddpg",
        "hddpg-goal",
        "hddpg-avoid",
        "hddpg-sac",
        "ham",
        "ddpg",
        "td3",
        "sac",
    ]
    assert [entry["method"] for entry in index] == expected
    assert all(entry["seed"] == 0 and not Path(entry["path"]).is_absolute() for entry in index)
    # Re-evaluate from the export alone (the benchmark folder gone), on episodes of our own.
    shutil.rmtree(out)
    for entry in index:
        loaded = load_policy(models / entry["path"])
        env = loaded.make_env()
        metrics = evaluate(loaded.policy, env, n_episodes=1, seed=123).summary()
        env.close()
        assert metrics["episodes"] == 1 and np.isfinite(metrics["mean_reach_reward"]), entry
    # A file altered after the export is caught.
    (models / index[0]["path"]).write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="sha256"):
        read_index(models)


def test_export_layout_and_index_from_a_benchmark_folder(tmp_path):
    """The exporter on a benchmark folder's layout (files stand in for models: only copying is tested here)."""
    from hddpg_zoo.model_export import export_models, read_index
    from sb3_hddpg.artifacts.provenance import sha256_file

    run = tmp_path / "bench"
    files = {
        "seed-3/workers/manifest.json": "{}",
        "seed-3/workers/goal.zip": "goal",
        "seed-3/workers/avoid.zip": "avoid",
        "seed-3/hddpg/hierarchy.zip": "bundle",
        "seed-3/ham/ham.json": "ham",
        "seed-3/td3/flat/td3.zip": "td3",
        "seed-3/td3/flat/manifest.json": "{}",
        "seed-3/sac-her/flat/sac.zip": "sac with the goal worker's tricks",
        "seed-3/sac-her/flat/manifest.json": "{}",
        "seed-3/ddpg@goal=2,avoid=1/flat/ddpg.zip": "transfer",
        "seed-3/ddpg@goal=2,avoid=1/flat/manifest.json": "{}",
        "seed-3/sac/flat/sac.zip": "unfinished",
    }
    for relative, text in files.items():
        (run / relative).parent.mkdir(parents=True, exist_ok=True)
        (run / relative).write_text(text)
    records = {
        "workers": {"workers": {"goal": {}, "avoid": {}}},
        "hddpg": {},
        "ham": {},
        "td3": {},
        "sac-her": {},
        "ddpg@goal=2,avoid=1": {},
        "sac": {"status": "running"},  # not finished: not exported
    }
    for key, extra in records.items():
        path = run / "records" / key / "seed-3.json"
        path.parent.mkdir(parents=True)
        path.write_text(json.dumps({"method": key, "seed": 3, "status": "done", **extra}))

    index = export_models(run, tmp_path / "models")
    assert (
        json.loads((tmp_path / "models" / "index.json").read_text())
        == index
        == read_index(tmp_path / "models")
    )
    assert [(e["method"], e["path"]) for e in index] == [
        ("worker:goal", "seed-3/workers/goal.zip"),
        ("worker:avoid", "seed-3/workers/avoid.zip"),
        ("hddpg", "seed-3/hddpg/hierarchy.zip"),
        ("ham", "seed-3/ham/ham.json"),
        ("ddpg", "seed-3/ddpg@goal=2,avoid=1/flat/ddpg.zip"),
        ("td3", "seed-3/td3/flat/td3.zip"),
        ("sac-her", "seed-3/sac-her/flat/sac.zip"),
    ]
    assert index[4]["preference"] == "goal=2,avoid=1" and "preference" not in index[5]
    for entry in index:
        assert entry["sha256"] == sha256_file(run / entry["path"]) and entry["seed"] == 3
    # What the models open through is copied beside them.
    for relative in ("seed-3/workers/manifest.json", "seed-3/td3/flat/manifest.json"):
        assert (tmp_path / "models" / relative).is_file()
    assert not (tmp_path / "models" / "seed-3" / "sac").exists()

    escaped = [dict(index[0], path="../bench/seed-3/workers/goal.zip")]
    (tmp_path / "models" / "index.json").write_text(json.dumps(escaped))
    with pytest.raises(ValueError, match="outside"):
        read_index(tmp_path / "models")
    with pytest.raises(ValueError, match="outside the benchmark folder"):
        export_models(run, run / "models")
    with pytest.raises(FileNotFoundError, match="no records"):
        export_models(tmp_path / "models", tmp_path / "elsewhere")

    # A folder of someone's own files is never a destination: nothing of theirs may be replaced.
    theirs = tmp_path / "theirs"
    (theirs / "seed-3" / "workers").mkdir(parents=True)
    (theirs / "seed-3" / "workers" / "goal.zip").write_text("my own model")
    with pytest.raises(RunFolderError, match="holds other files"):
        export_models(run, theirs)
    assert (theirs / "seed-3" / "workers" / "goal.zip").read_text() == "my own model"
    # An earlier export is replaced in place, and so is an empty folder filled.
    (tmp_path / "models" / "index.json").write_text(json.dumps(index))
    assert export_models(run, tmp_path / "models") == index
    (tmp_path / "empty").mkdir()
    assert export_models(run, tmp_path / "empty") == index


def test_export_picks_another_envs_workers_by_their_index_method(tmp_path):
    from hddpg_zoo.model_export import export_models

    run = tmp_path / "bench"
    for relative, text in {"seed-0/workers/manifest.json": "{}", "seed-0/workers/speed.zip": "speed"}.items():
        (run / relative).parent.mkdir(parents=True, exist_ok=True)
        (run / relative).write_text(text)
    record = run / "records" / "workers" / "seed-0.json"
    record.parent.mkdir(parents=True)
    record.write_text(
        json.dumps({"method": "workers", "seed": 0, "status": "done", "workers": {"speed": {}}})
    )
    # highway's workers are indexed as worker:speed, worker:lane...: --method takes what the index names.
    index = export_models(run, tmp_path / "models", ["worker:speed"])
    assert [(e["method"], e["path"]) for e in index] == [("worker:speed", "seed-0/workers/speed.zip")]
    with pytest.raises(ValueError, match="also \\['worker:'\\]"):
        export_models(run, tmp_path / "models", ["worker:"])


def test_a_task_interrupted_and_resumed_keeps_the_time_of_both_invocations(tmp_path):
    from hddpg_zoo.benchmark.record_files import elapsed_path
    from hddpg_zoo.benchmark.run import run_task

    calls: list[int] = []

    def run(task: Task, settings: BenchmarkSettings, folder: Path) -> dict[str, Any]:
        calls.append(1)
        time.sleep(0.2)
        if len(calls) == 1:
            raise KeyboardInterrupt  # what a task sees on Ctrl-C or SIGTERM, after its checkpoint
        return {"worker_timesteps": 0, "history": [], "test": {}}

    register_method(Method("interrupted-once", run, lambda settings: 0))
    try:
        settings = BenchmarkSettings(methods=["interrupted-once"], seeds=[0])
        task = Task("interrupted-once", 0)
        with pytest.raises(KeyboardInterrupt):
            run_task(task, settings, tmp_path)
        assert json.loads(elapsed_path(tmp_path, task).read_text())["wall_time_s"] >= 0.2
        record = run_task(task, settings, tmp_path)
    finally:
        METHOD_REGISTRY.pop("interrupted-once")
    # This invocation's time, and both invocations' (each slept 0.2 s).
    assert record["wall_time_s"] >= 0.2 and record["wall_time_s_total"] >= record["wall_time_s"] + 0.2
    assert not elapsed_path(tmp_path, task).exists()  # counted once: a later --redo starts from 0


def test_worker_steps_count_each_workers_training_and_its_critics_rollouts(tmp_path):
    from hddpg_zoo.benchmark.methods import worker_steps, workers_steps

    shipped = Path(__file__).resolve().parents[1] / "docs" / "results" / "cheetah" / "seed-0" / "workers"
    manifest = json.loads((shipped / "manifest.json").read_text())
    manifest["workers"]["speed"]["term_critic"] = {"kind": "state_value", "env_steps": 40}
    (tmp_path / "workers").mkdir()
    (tmp_path / "workers" / "manifest.json").write_text(json.dumps(manifest))
    trained = {n: e["timesteps_trained"] for n, e in manifest["workers"].items()}
    assert worker_steps(tmp_path) == {"speed": trained["speed"] + 40, "energy": trained["energy"]}
    assert workers_steps(tmp_path) == sum(trained.values()) + 40
    manifest["workers"]["energy"]["timesteps_trained"] = "many"
    (tmp_path / "workers" / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(ValueError, match="no whole timesteps_trained"):
        worker_steps(tmp_path)
