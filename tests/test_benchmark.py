"""The benchmark: planning, statistics on constructed records, and a tiny real run through the CLI; train-flat."""

from __future__ import annotations

import csv
import json
import os
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from stable_baselines3 import DDPG

from hddpg_zoo import stats
from hddpg_zoo.agent_settings import manager_option_steps
from hddpg_zoo.benchmark import (
    OUTPUT_FILES,
    BenchmarkSettings,
    Task,
    compute_results,
    curve_bands,
    evaluation_rows,
    normalised_term_sums,
    output_files_in,
    plan_tasks,
    task_cost,
    write_outputs,
)
from hddpg_zoo.provenance import code_provenance
from sb3_hddpg.episode_sets import DEVELOPMENT
from sb3_hddpg.evaluation import EVAL_SEED_BASE
from sb3_hddpg.training.config import MANAGER_KEY, load_hyperparams
from tests.cli_batch import run_batch
from tests.cli_runner import CLI

REPO = Path(__file__).resolve().parents[1]


def cli(*args: str, timeout: float = 600) -> subprocess.CompletedProcess[str]:
    """Run ``python -m sb3_hddpg`` in a fresh interpreter, as a user would, with this checkout first on the path."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "COLUMNS": "200", "SDL_VIDEODRIVER": "dummy"}
    return subprocess.run(
        [*CLI, *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
        cwd=REPO,
    )


# --------------------------------------------------------------------------------------- constructed data
def summary(reach: float, goal_touch: float = 0.1, collisions: float = 1.0, **extra: Any) -> dict[str, Any]:
    """An evaluation summary with the keys evaluate() produces."""
    return {
        "episodes": 20,  # the development test length: a record of the benchmark's test set
        "mean_reward": reach,
        "std_reward": 1.0,
        "mean_reach_reward": reach,
        "mean_goal_reward": -40.0,
        "mean_avoid_reward": 30.0,
        "goal_touch_rate": goal_touch,
        "goal_reached_rate": 0.5,
        "collisions_per_episode": collisions,
        "success_rate": 0.2,
        "min_clearance": 0.05,
        "mean_length": 200.0,
        **extra,
    }


def record(
    method: str, seed: int, curve: list[float], test: float, worker_steps: int = 2000
) -> dict[str, Any]:
    """A finished run's record with a curve evaluated every 1000 own steps."""
    if method == "ham":
        history = [{"timesteps": 0, "total_timesteps": worker_steps, **summary(curve[0])}]
    else:
        offset = 0 if method == "ddpg" else worker_steps
        history = [
            {"timesteps": 1000 * (i + 1), "total_timesteps": 1000 * (i + 1) + offset, **summary(value)}
            for i, value in enumerate(curve)
        ]
    return {
        "method": method,
        "seed": seed,
        "status": "done",
        "worker_timesteps": 0 if method == "ddpg" else worker_steps,
        "history": history,
        "test": summary(test),
        "wall_time_s": 1.0,
    }


@pytest.fixture
def per_step_manager(monkeypatch: pytest.MonkeyPatch) -> None:
    """
    Managers deciding every env step (``option_steps`` 1), whatever the bundled manager block holds: the
    constructed records' curves and the budget arithmetic below count one env step per decision.
    """
    from hddpg_zoo.benchmark import settings as settings_module

    monkeypatch.setattr(settings_module, "_manager_option_steps", lambda: 1)


@pytest.fixture
def constructed(per_step_manager: None) -> tuple[BenchmarkSettings, list[dict[str, Any]]]:
    methods = ["hddpg", "ham", "ddpg", "hddpg-goal", "hddpg-avoid"]
    settings = BenchmarkSettings(methods=methods, seeds=[0, 1, 2], timesteps=3000)
    records = []
    for seed in range(3):
        records.append(record("hddpg", seed, [200 + seed, 210 + seed, 220 + seed], 230.0 + seed))
        records.append(record("hddpg-goal", seed, [200.0, 205.0, 215.0], 225.0))
        records.append(record("hddpg-avoid", seed, [200.0, 201.0, 202.0], 220.0))
        records.append(record("ham", seed, [205.0], 205.0 + 2 * seed))
        # ddpg trains longer (flat budget): points beyond the 3000-step window must not count.
        records.append(record("ddpg", seed, [190.0, 195.0, 200.0 + seed, 400.0], 210.0 - seed))
    return settings, records


def test_figure10_is_not_drawn_without_the_snakes_managers(constructed, tmp_path):
    """Figure 10 compares the snake's managers: a run without any writes no empty figure."""
    _, records = constructed
    flat = [r for r in records if not r["method"].startswith("hddpg")]
    results = compute_results(
        BenchmarkSettings(methods=["ham", "ddpg"], seeds=[0, 1, 2], timesteps=3000), flat
    )
    write_outputs(tmp_path, results, flat)
    assert not (tmp_path / "figure10.png").exists()
    assert "figure10.png" not in output_files_in(tmp_path) and "figure9.png" in output_files_in(tmp_path)


def test_plan_trains_workers_once_per_seed_only_when_needed():
    tasks = plan_tasks(BenchmarkSettings(methods=["hddpg", "ham", "ddpg"], seeds=[0, 1]))
    assert [t.label for t in tasks] == [
        "workers/seed-0",
        "hddpg/seed-0",
        "ham/seed-0",
        "ddpg/seed-0",
        "workers/seed-1",
        "hddpg/seed-1",
        "ham/seed-1",
        "ddpg/seed-1",
    ]
    assert all(
        t.method != "workers" for t in plan_tasks(BenchmarkSettings(methods=["ddpg", "td3"], seeds=[0]))
    )
    assert Task("hddpg-goal", 0).needs_workers and not Task("sac", 0).needs_workers


def test_settings_reject_unknown_methods_and_default_to_equal_total_steps(per_step_manager):
    with pytest.raises(ValueError, match="Unknown methods"):
        BenchmarkSettings(methods=["hddpg", "a2c"])
    settings = BenchmarkSettings(timesteps=1000, worker_timesteps=300)
    assert settings.flat_budget == 1600  # the hierarchy's manager + two workers
    assert settings.eval_freq_for(1600) == settings.eval_freq_for(1000) == 100


def test_settings_default_to_the_configs_budgets():
    # The bundled config: goal and avoid worker 150k each, the manager 5000 decisions of 8 env steps (40k env
    # steps); a flat agent gets the sum.
    settings = BenchmarkSettings(methods=["hddpg", "ddpg"])
    assert settings.timesteps == 5_000 and settings.option_steps == 8 and settings.worker_timesteps is None
    assert settings.manager_env_steps == 40_000 and task_cost(Task("hddpg", 0), settings) == 40_000
    assert settings.workers_budget == 300_000 and settings.flat_budget == 340_000
    assert task_cost(Task("workers", 0), settings) == 300_000


def test_statistics_use_the_stats_module_on_per_seed_values(constructed):
    settings, records = constructed
    results = compute_results(settings, records)
    hddpg, ddpg, ham = (results["methods"][m] for m in ("hddpg", "ddpg", "ham"))

    assert hddpg["stats"]["mean_reach_reward"] == stats.summarise([230.0, 231.0, 232.0])
    assert hddpg["stats"]["mean_reach_reward"]["iqm"] == pytest.approx(stats.iqm([230.0, 231.0, 232.0]))
    # The curve statistics only count own steps <= the manager's budget (the window every method shares).
    assert ddpg["per_seed"]["1"]["curve_mean"] == pytest.approx(np.mean([190.0, 195.0, 201.0]))
    assert ddpg["per_seed"]["1"]["slope"] == pytest.approx(
        stats.trend_slope([1, 2, 3], [190.0, 195.0, 201.0])
    )
    assert hddpg["per_seed"]["0"]["slope"] == pytest.approx(10.0)  # +10 per 1000 steps
    assert ham["per_seed"]["0"]["slope"] == 0.0  # HAM does not learn: a single, flat point

    comparison = results["comparisons"]["hddpg vs ddpg"]
    a, b = [230.0, 231.0, 232.0], [210.0, 209.0, 208.0]
    assert comparison["seeds"] == [0, 1, 2]
    interval = stats.paired_t_interval(a, b)
    reach = comparison["mean_reach_reward"]
    assert reach["difference"] == pytest.approx(interval["difference"])
    assert (reach["ci_low"], reach["ci_high"]) == (interval["ci_low"], interval["ci_high"])
    # The table compares hddpg with m baselines under Holm: each interval at its Holm-consistent level, between
    # 1 - 0.05 and 1 - 0.05 / m, wider than the unadjusted one, same centre, and it excludes 0 exactly where
    # the Holm-adjusted p-value is below 0.05.
    m = results["comparison_families"]["hddpg"]["comparisons"]["mean_reach_reward"]
    assert m == sum(1 for pair in results["comparisons"] if pair.startswith("hddpg vs ")) >= 2
    assert 0.95 <= reach["confidence_adjusted"] <= 1 - 0.05 / m
    assert reach["ci_low_adjusted"] <= reach["ci_low"] < reach["ci_high"] <= reach["ci_high_adjusted"]
    assert reach["p_holm"] >= reach["p_value"]
    assert reach["seeds_higher"] == 3 and reach["equivalence_margin"] == pytest.approx(0.01 * np.mean(b))
    for entry in (c["mean_reach_reward"] for c in results["comparisons"].values()):
        excludes = entry["ci_low_adjusted"] > 0 or entry["ci_high_adjusted"] < 0
        assert excludes == (entry["p_holm"] < 0.05)
    # rliable's aggregates over the per-seed scores (these records hold no episodes).
    aggregate = results["aggregates"]
    assert aggregate["unit"] == "seed" and aggregate["tasks"] == 1
    iqm = aggregate["intervals"]["hddpg"]["iqm"]
    assert iqm["value"] == pytest.approx(stats.iqm([230.0, 231.0, 232.0]))
    assert iqm["ci_low"] <= iqm["value"] <= iqm["ci_high"]
    assert aggregate["probability_of_improvement"]["hddpg vs ddpg"]["value"] == 1.0
    assert comparison["mean_reach_reward"]["relative_gain"] == pytest.approx(np.mean(a) / np.mean(b) - 1)
    assert comparison["mean_reach_reward"]["probability_of_improvement"] == stats.probability_of_improvement(
        a, b
    )
    ddpg_slopes = [stats.trend_slope([1, 2, 3], [190.0, 195.0, 200.0 + s]) for s in range(3)]
    assert comparison["slope_ratio"] == pytest.approx(10.0 / np.mean(ddpg_slopes))
    assert results["comparisons"]["hddpg vs ham"]["slope_ratio"] is None  # HAM's slope is 0


def test_curves_on_own_and_total_steps(constructed):
    _, records = constructed
    own = curve_bands(records, "timesteps")
    total = curve_bands(records, "total_timesteps")
    assert own["hddpg"]["x"] == [1000.0, 2000.0, 3000.0]
    assert total["hddpg"]["x"] == [3000.0, 4000.0, 5000.0]  # shifted by the workers' 2000 steps
    assert total["ddpg"]["x"] == own["ddpg"]["x"]  # a flat agent has no pre-training
    assert total["ham"]["x"] == [2000.0]  # HAM sits at its workers' steps
    assert own["hddpg"]["mean"][0] == pytest.approx(201.0)
    assert all(
        lo <= m <= hi for lo, m, hi in zip(own["hddpg"]["low"], own["hddpg"]["mean"], own["hddpg"]["high"])
    )


def test_normalised_term_sums_match_the_env_normalisation():
    import gymnasium as gym

    env = gym.make("hddpg/SnakeReach-v0")
    env.reset(seed=0)
    goal_sum = avoid_sum = raw_goal = raw_avoid = 0.0
    for _ in range(20):
        _, _, _, _, info = env.step(env.action_space.sample())
        terms = info["reward_terms"]
        normalised = env.unwrapped.normalise_terms(terms)
        goal_sum, avoid_sum = goal_sum + normalised["goal"], avoid_sum + normalised["avoid"]
        raw_goal, raw_avoid = raw_goal + terms["goal"], raw_avoid + terms["avoid"]
    s = {"mean_goal_reward": raw_goal, "mean_avoid_reward": raw_avoid, "mean_length": 20.0}
    assert normalised_term_sums(s) == pytest.approx((goal_sum, avoid_sum))


def test_outputs_from_constructed_records(constructed, tmp_path):
    settings, records = constructed
    results = compute_results(settings, records)
    write_outputs(tmp_path, results, records)
    # Every output but the front's figure: these records hold no front.
    assert output_files_in(tmp_path) == [name for name in OUTPUT_FILES if name != "fronts.png"]
    for name in output_files_in(tmp_path):
        assert (tmp_path / name).stat().st_size > 0, name
    rows = list(csv.DictReader((tmp_path / "evaluations.csv").read_text().splitlines()))
    assert len(rows) == len(evaluation_rows(records)) == 3 * 3 * (3 + 1) + 3 * (1 + 1) + 3 * (4 + 1)
    assert {r["kind"] for r in rows} == {"curve", "test"}


# ------------------------------------------------------------------------------------------ real, tiny
# One job process: on a machine whose cores the other test processes share, a second process adds its start-up
# and nothing else (the runner's own tests cover several processes).
TINY = (
    "--timesteps", "200", "--worker-timesteps", "100", "--eval-freq", "100",
    "--eval-episodes", "1", "--test-episodes", "1", "--n-jobs", "1",
)  # fmt: skip


def test_tiny_benchmark_through_the_cli_and_resume(tmp_path):
    out = tmp_path / "bench"
    args = ("benchmark", "--seeds", "2", "--methods", "hddpg,ham,ddpg", *TINY, "--out", str(out))
    done = cli(*args)
    assert done.returncode == 0, done.stdout + done.stderr
    # Every output but the front's figure (no front here), and the last lines name the ones written.
    for name in ("benchmark.json", *(name for name in OUTPUT_FILES if name != "fronts.png")):
        assert (out / name).exists(), name
    assert not (out / "fronts.png").exists() and "fronts.png" not in done.stdout
    assert "figure10.png" in done.stdout
    results = json.loads((out / "results.json").read_text())
    assert set(results["methods"]) == {"hddpg", "ham", "ddpg"}
    assert all(entry["seeds"] == [0, 1] for entry in results["methods"].values())
    assert results["test_seeds"][0] == DEVELOPMENT.first_seed and results["curve_seeds"][0] == EVAL_SEED_BASE
    # Every test episode is shipped, and the per-seed figures are their means.
    from hddpg_zoo.benchmark.episodes import read_episodes_csv

    rows = read_episodes_csv(out / "episodes.csv")
    assert sorted((r["method"], r["seed"], r["episode_seed"]) for r in rows) == sorted(
        (m, s, DEVELOPMENT.first_seed) for m in ("hddpg", "ham", "ddpg") for s in (0, 1)
    )
    hddpg_row = next(r for r in rows if r["method"] == "hddpg" and r["seed"] == 0)
    assert results["methods"]["hddpg"]["per_seed"]["0"]["mean_reach_reward"] == pytest.approx(
        hddpg_row["reach_reward"]
    )
    # The seed is the unit of the aggregates' intervals, whatever the records hold.
    assert results["aggregates"]["unit"] == "seed" and results["test_episode_set"]["name"] == "development"
    # Equal total steps: the manager's 200 decisions of k env steps (the bundled block's options) + 2 x 100.
    k = manager_option_steps()
    assert results["methods"]["ddpg"]["own_timesteps"] == 200 * k + 200
    # What the workers' manifest records: the goal worker collects 8 steps per update call
    # (train_freq 8), so its 100 requested steps become 104; the avoid worker's stay 100.
    assert results["methods"]["hddpg"]["worker_timesteps"] == 204
    assert "hddpg vs ddpg" in results["comparisons"] and "hddpg vs ham" in results["comparisons"]
    for entry in results["methods"].values():  # the deciding network's saturation, a fraction
        assert 0.0 <= entry["stats"]["action_saturation"]["mean"] <= 1.0
    assert "saturated actions" in (out / "results.md").read_text()
    assert "norm. return (test)" in done.stdout
    rows = list(csv.DictReader((out / "evaluations.csv").read_text().splitlines()))
    hddpg_curve = [r for r in rows if r["method"] == "hddpg" and r["kind"] == "curve" and r["seed"] == "0"]
    # A point every 100 env steps, i.e. every 100 // k decisions, and one at the end (training always ends
    # with an evaluation), each offset by the workers' steps. SB3 runs whole rollouts of train_freq decisions:
    # the 200 decisions end at the first rollout at or past them.
    rollout = int(load_hyperparams(MANAGER_KEY, DDPG, manager=True).algo_kwargs["train_freq"])
    decisions = -(-200 // rollout) * rollout
    offsets = [int(r["total_timesteps"]) - int(r["timesteps"]) for r in hddpg_curve]
    assert offsets == [204] * -(-decisions // max(100 // k, 1))

    # Resume: finished runs are kept, a missing one is redone. The command lines between two edits of the
    # folder run in one interpreter (tests/cli_batch.py): each still gets its own exit code and output.
    (out / "records" / "ddpg" / "seed-1.json").unlink()
    kept_mtime = (out / "records" / "hddpg" / "seed-0.json").stat().st_mtime_ns
    grown = ("benchmark", "--seeds", "2", "--methods", "hddpg,ham,ddpg,goal-only", *TINY, "--out", str(out))
    resumed, grown_resumed, refused, changed = run_batch(
        [
            [*args, "--resume"],
            # More methods (or seeds) on resume: only the new runs start, on the same workers and episodes.
            [*grown, "--resume"],
            # An occupied folder is refused without --resume or --force.
            list(args),
            # Resuming with other settings would mix budgets: refused.
            [*args[:-2], "--timesteps", "300", "--out", str(out), "--resume"],
        ]
    )
    assert resumed.returncode == 0, resumed.stdout + resumed.stderr
    assert resumed.stdout.count("started") == 1 and "started  ddpg/seed-1" in resumed.stdout
    assert resumed.stdout.count("kept") == 7  # 2 x (workers + 3 methods) - 1
    assert (out / "records" / "hddpg" / "seed-0.json").stat().st_mtime_ns == kept_mtime
    # Each invocation's wall time is kept, and the total over them reported.
    invocations = json.loads((out / "benchmark.json").read_text())["invocations"]
    # The third is the grown resume below, run in the same batch before this folder is read.
    assert [(i["runs_kept"], i["runs_to_do"], i["runs_done"]) for i in invocations] == [
        (0, 8, 8),
        (7, 1, 1),
        (8, 2, 2),
    ]
    assert all(i["wall_time_s"] > 0 and not i["interrupted"] for i in invocations)
    # Each invocation keeps the code it ran; both ran this checkout's commit, so nothing was mixed.
    codes = {(i["code"]["version"], i["code"]["commit"]) for i in invocations}
    assert codes == {code_provenance().code_id} and not any(i["mixed_commits"] for i in invocations)
    total = json.loads((out / "results.json").read_text())["wall_time_s_all_invocations"]
    assert total == pytest.approx(sum(i["wall_time_s"] for i in invocations))
    assert "over its 2 invocations" in resumed.stdout

    assert grown_resumed.returncode == 0, grown_resumed.stdout + grown_resumed.stderr
    assert grown_resumed.stdout.count("started") == 2 and grown_resumed.stdout.count("kept") == 8
    assert set(json.loads((out / "results.json").read_text())["methods"]) == {
        "hddpg",
        "ham",
        "ddpg",
        "goal-only",
    }

    assert refused.returncode == 2 and "--resume" in refused.stderr
    assert changed.returncode == 2 and "different settings" in changed.stderr

    # A kept run made from another config block than the bundled one now (here: its record says it trained
    # at another learning rate) is refused, named; --redo runs that method again and keeps the old runs aside.
    path = out / "records" / "ddpg" / "seed-0.json"
    record = json.loads(path.read_text())
    (block,) = record["config_blocks"]
    record["config_blocks"][block]["learning_rate"] = 0.5
    path.write_text(json.dumps(record))
    stale, without_resume, not_a_method, redone = run_batch(
        [
            [*grown, "--resume"],
            [*grown, "--redo", "ddpg"],
            [*grown, "--resume", "--redo", "td3"],
            [*grown, "--resume", "--redo", "ddpg"],
        ]
    )
    assert stale.returncode == 2 and "Traceback" not in stale.stderr
    assert "ddpg/seed-0" in stale.stderr and "--redo ddpg" in stale.stderr and block in stale.stderr
    assert without_resume.returncode == 2  # --redo without --resume
    assert not_a_method.returncode == 2  # not among the methods
    assert redone.returncode == 0, redone.stdout + redone.stderr
    assert redone.stdout.count("started") == 2 and "started  ddpg/seed-0" in redone.stdout
    (aside,) = out.glob("replaced-*")
    assert (
        json.loads((aside / "records" / "ddpg" / "seed-0.json").read_text())["config_blocks"][block][
            "learning_rate"
        ]
        == 0.5
    )
    assert (aside / "seed-1" / "ddpg").is_dir()
    assert json.loads(path.read_text())["config_blocks"][block]["learning_rate"] != 0.5

    # HAM's threshold is HAM's alone: changing it is refused with the way out, and allowed with --redo ham,
    # which runs HAM again at the new threshold and nothing else.
    other_threshold = (*grown, "--ham-threshold", "1.5")
    refused, rethresholded = run_batch(
        [[*other_threshold, "--resume"], [*other_threshold, "--resume", "--redo", "ham"]]
    )
    assert refused.returncode == 2 and "ham_threshold" in refused.stderr and "--redo ham" in refused.stderr
    assert rethresholded.returncode == 0, rethresholded.stdout + rethresholded.stderr
    assert rethresholded.stdout.count("started") == 2 and "started  ham/seed-0" in rethresholded.stdout
    assert json.loads((out / "records" / "ham" / "seed-1.json").read_text())["threshold"] == 1.5


def test_train_flat_writes_a_model_that_opens_with_ddpg_load(tmp_path):
    from stable_baselines3 import DDPG

    from sb3_hddpg.artifacts.provenance import sha256_file
    from sb3_hddpg.hierarchy.loading import load_policy

    out = tmp_path / "flat-run"
    done = cli(
        "train-flat",
        "--timesteps",
        "200",
        "--eval-freq",
        "100",
        "--eval-episodes",
        "1",
        "--out",
        str(out),
        "--no-progress",
    )
    assert done.returncode == 0, done.stdout + done.stderr
    zip_path = out / "flat" / "ddpg.zip"
    model = DDPG.load(zip_path, device="cpu")
    assert model.policy.actor.mu[0].out_features == 64  # the config's net_arch, equal to the workers'
    manifest = json.loads((out / "flat" / "manifest.json").read_text())
    entry = manifest["models"]["ddpg"]
    assert entry["sha256"] == sha256_file(zip_path)
    assert entry["env_id"] == "hddpg/SnakeReach-v0" and entry["algo"] == "ddpg"
    assert entry["spec"] and entry["metrics"]["mean_reach_reward"] > 0
    assert entry["timesteps_trained"] == 200 and "versions" in entry and entry["seed"] == 0
    loaded = load_policy(zip_path)  # the weights-only path, through the manifest
    assert loaded.kind == "flat"
    obs = np.zeros(loaded.policy.observation_space.shape, dtype=np.float32)
    np.testing.assert_allclose(
        loaded.policy.predict(obs)[0], model.predict(obs, deterministic=True)[0], atol=1e-6
    )


# TD3's block is its equal-effort study's pick (docs/TUNING.md); SAC's study kept DDPG's values, and TQC has none.
@pytest.mark.parametrize("algo", ["sac", "tqc"])
def test_flat_configs_give_every_algorithm_the_same_care(algo):
    from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
    from sb3_hddpg.training.backends import algo_class
    from sb3_hddpg.training.config import default_config, load_hyperparams

    ddpg = load_hyperparams(SNAKE_REACH_ENV_ID, algo_class("ddpg"), default_config("ddpg"))
    other = load_hyperparams(SNAKE_REACH_ENV_ID, algo_class(algo), default_config(algo))
    assert other.n_timesteps == ddpg.n_timesteps
    assert other.algo_kwargs["policy_kwargs"]["net_arch"] == ddpg.algo_kwargs["policy_kwargs"]["net_arch"]
    for key in (
        "learning_rate",
        "buffer_size",
        "learning_starts",
        "batch_size",
        "tau",
        "gamma",
        "train_freq",
    ):
        assert other.algo_kwargs[key] == ddpg.algo_kwargs[key], key


def test_a_managers_budget_and_curve_are_counted_in_env_steps_with_options(tmp_path, monkeypatch):
    # With options of k env steps a manager's `timesteps` are decisions: k times as many env steps, which the
    # flat agents' equal budget, the curve window and the curve points must count.
    from hddpg_zoo.agent_settings import read_history
    from hddpg_zoo.benchmark import settings as settings_module

    monkeypatch.setattr(settings_module, "_manager_option_steps", lambda: 4)
    settings = BenchmarkSettings(methods=["hddpg", "ddpg"], timesteps=1000, worker_timesteps=300)
    assert settings.manager_env_steps == 4000 and settings.flat_budget == 4600
    assert task_cost(Task("hddpg", 0), settings) == 4000
    assert settings.eval_freq_for(settings.flat_budget) == 400  # a tenth of the manager's env steps
    assert settings.manager_run_options(0).eval_freq == 100  # the same env steps, in decisions
    assert settings.manager_run_options(0).timesteps == 1000

    # Another algorithm's manager gets the same env steps in decisions of its own option_steps.
    monkeypatch.setattr(settings_module, "manager_option_steps", lambda algo: {"sac": 2}[algo])
    assert settings.option_steps_of("sac") == 2
    assert settings.manager_run_options(0, "sac").timesteps == 2000
    assert settings.manager_run_options(0, "sac").eval_freq == 200

    path = tmp_path / "manager.json"
    path.write_text(json.dumps([{"timesteps": 100, "mean_reach_reward": 1.0}]))
    assert read_history(path, 4, offset=600) == [
        {"timesteps": 400, "decisions": 100, "total_timesteps": 1000, "mean_reach_reward": 1.0}
    ]
    assert read_history(path, offset=600) == [
        {"timesteps": 100, "total_timesteps": 700, "mean_reach_reward": 1.0}
    ]


def test_an_interrupted_benchmark_keeps_the_time_it_spent(tmp_path):
    """
    SIGTERM mid-run: the invocation is logged as interrupted, and the task keeps the time it spent, for the
    --resume that finishes it to add.
    """
    from hddpg_zoo.benchmark.record_files import elapsed_path
    from tests.helpers import sigterm_once_written

    out = tmp_path / "bench"
    args = (
        "benchmark", "--seeds", "1", "--methods", "ddpg", "--flat-timesteps", "200000", "--eval-freq", "1000",
        "--eval-episodes", "1", "--test-episodes", "1", "--out", str(out),
    )  # fmt: skip
    process = subprocess.Popen(
        [*CLI, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONPATH": str(REPO), "SDL_VIDEODRIVER": "dummy"},
        cwd=REPO,
    )
    curve = out / "seed-0" / "ddpg" / "evaluations" / "flat-ddpg.json"
    stdout, stderr = sigterm_once_written(process, curve, "the flat agent's first evaluation")
    assert process.returncode == 143, stdout + stderr  # 128 + SIGTERM
    assert "the same command with --resume continues it" in stdout and "Traceback" not in stderr
    (invocation,) = json.loads((out / "benchmark.json").read_text())["invocations"]
    assert invocation["interrupted"] and invocation["runs_done"] is None and invocation["wall_time_s"] > 0
    task_time = json.loads(elapsed_path(out, Task("ddpg", 0)).read_text())["wall_time_s"]
    assert 0 < task_time <= invocation["wall_time_s"]


def test_a_curve_evaluated_off_the_grid_is_interpolated_not_dropped():
    # Seed 2 was resumed between evaluations before the grid was kept across resumes: its later points sit
    # 500 steps off the others'. The mean curve keeps the shared grid and reads seed 2 between its points.
    def record(seed, steps, values):
        history = [
            {"timesteps": x, "total_timesteps": x, "mean_reach_reward": v} for x, v in zip(steps, values)
        ]
        return {"method": "ddpg", "seed": seed, "history": history}

    grid = [1000, 2000, 3000, 4000]
    records = [
        record(0, grid, [200.0, 210.0, 220.0, 230.0]),
        record(1, grid, [202.0, 212.0, 222.0, 232.0]),
        record(2, [1000, 2000, 2500, 3500, 4000], [201.0, 211.0, 216.0, 226.0, 231.0]),
    ]
    band = curve_bands(records, "timesteps")["ddpg"]
    assert band["x"] == [1000.0, 2000.0, 3000.0, 4000.0]
    assert band["mean"][2] == pytest.approx((220.0 + 222.0 + 221.0) / 3)  # seed 2 halfway from 216 to 226
