"""The examples and the studies run as their docstrings say, on tiny trained workers."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_bad_input import TINY_CONFIG

ROOT = Path(__file__).resolve().parents[1]
#: Users' examples, and the studies behind the docs' figures.
EXAMPLES, STUDIES = ROOT / "examples", ROOT / "studies"


def run_example(
    script: str, args: list[str], timeout: float = 600, folder: Path = EXAMPLES
) -> subprocess.CompletedProcess[str]:
    """Run an example (or a study) as its docstring does, in a fresh interpreter, and check that it exits 0."""
    # One torch thread: the test machine's cores are shared by the test processes.
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    result = subprocess.run(
        [sys.executable, str(folder / script), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    return result


@pytest.fixture(scope="module")
def tiny_workers(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """
    A ``train-workers`` folder of TINY_CONFIG's goal and avoid workers (150 steps each), trained once for
    the examples that only read it.
    """
    from sb3_hddpg.training.workers import train_workers

    root = tmp_path_factory.mktemp("tiny-workers")
    config = root / "tiny.yml"
    config.write_text(TINY_CONFIG)
    train_workers(root / "w", config=config, timesteps=150, eval_freq=0, eval_episodes=1)
    return root / "w"


def test_preference_landscape_scores_every_policy_and_names_the_best(tiny_workers):
    args = ["--workers", str(tiny_workers), "--episodes", "1", "--bias", "0.15", "3"]
    result = run_example("preference_landscape.py", args, folder=STUDIES)
    table = [line for line in result.stdout.splitlines() if line.startswith("│")]
    rows = [line for line in table if "mixture" in line or "HAM threshold" in line]
    assert len(rows) == 12, result.stdout  # 5 mixtures + 7 thresholds
    verdicts = [line for line in result.stdout.splitlines() if line.startswith("bias ")]
    assert [v.split(":")[0] for v in verdicts] == ["bias 0.15", "bias 3"], result.stdout
    assert all("goal-preferred best =" in v and "avoid-preferred best =" in v for v in verdicts)


def test_worker_study_trains_with_every_setting_and_saves_a_plain_sb3_zip(tmp_path):
    import json

    from stable_baselines3 import DDPG

    args = ["--steps", "300", "--eval-every", "300", "--curve-episodes", "1", "--test-episodes", "1"]
    args += [
        "--observe",
        "goal",
        "--relabel",
        "0.8",
        "--action-l2",
        "0.5",
        "--save",
        str(tmp_path / "goal.zip"),
    ]
    result = run_example("worker_study.py", args, folder=STUDIES)
    lines = [json.loads(line) for line in result.stdout.splitlines() if line.startswith("{")]
    assert lines[0]["steps"] == 300 and "test" in lines[-1]
    assert 0.0 <= lines[-1]["goal_touch_rate"] <= 1.0
    assert DDPG.load(tmp_path / "goal.zip", device="cpu").observation_space.shape == (15,)


def test_manager_study_reports_the_state_dependence(tiny_workers):
    import json

    args = ["--workers", str(tiny_workers), "--steps", "200", "--action-l2", "0.5", "--test-episodes", "1"]
    result = run_example("manager_study.py", args, folder=STUDIES)
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["args"]["action_l2"] == 0.5 and 0.0 <= report["action_saturation"] <= 1.0
    assert report["state_dependence"]["worker"] == "avoid"


@pytest.mark.slow  # ten tiny studies and two tiny workers
def test_equal_effort_tuning_gives_every_method_the_same_share_from_its_bundled_config(tmp_path):
    import json

    args = ["--n-trials", "2", "--budget-fraction", "0.001", "--n-evaluations", "2", "--eval-episodes", "1"]
    args += ["--worker-timesteps", "100", "--front-manager", "dqn", "--front-timesteps", "20000"]
    args += ["--out", str(tmp_path)]
    result = run_example("equal_effort_tuning.py", args, timeout=1800, folder=STUDIES)
    summary = json.loads((tmp_path / "summary.json").read_text())
    names = ["goal", "avoid", "ddpg", "sac", "ddpg-her", "sac-her", "hddpg", "hddpg-front", "ham"]
    assert [entry["study"] for entry in summary] == names
    budgets = {entry["study"]: entry["final_budget"] for entry in summary}
    assert budgets["goal"] == budgets["avoid"] == 100  # the benchmark's worker budget
    assert budgets["ddpg"] == budgets["sac-her"] == 40_000 + 2 * 100  # the hierarchy's env steps
    assert (budgets["hddpg"], budgets["hddpg-front"], budgets["ham"]) == (40_000, 20_000, None)
    for entry in summary:
        assert sum(entry["trials"].values()) == 2, entry
        if entry["study"] != "ham":  # the same share of every method's final budget
            assert entry["budget_fraction"] == 0.001
            assert entry["env_steps_per_trial"] == max(2, round(0.001 * entry["final_budget"]))
        assert entry["base_value"] is not None and entry["best_value"] >= entry["base_value"]
        # Ranked by each trial's best evaluation; the pick by the last evaluation is reported beside it.
        assert entry["rank_by"] == "peak" and entry["best_last_value"] >= entry["base_last_value"]
        assert entry["base_sampled_outside_space"] == []  # each bundled block is a point of its space
        export = json.loads((tmp_path / "studies" / f"{entry['study']}.json").read_text())
        assert len(export["trials"]) == 2  # every study's trials are shipped
    for file in ("ddpg.yml", "sac.yml", "dqn.yml"):
        assert (tmp_path / file).is_file()
    # The managers and HAM were tuned over workers trained from the tuned worker blocks.
    manifest = json.loads((tmp_path / "workers" / "workers" / "manifest.json").read_text())
    # Recorded relative to the workers' run folder: no record holds a path of this machine.
    assert {entry["config"]["file"] for entry in manifest["workers"].values()} == {"../workers.yml"}
    assert "| goal | " in result.stdout


def test_equal_effort_tuning_runs_only_the_named_studies(tmp_path):
    import json

    args = ["--n-trials", "1", "--budget-fraction", "0.001", "--n-evaluations", "1", "--eval-episodes", "1"]
    args += ["--flat", "ddpg", "--only", "ddpg", "--out", str(tmp_path)]
    result = run_example("equal_effort_tuning.py", args, timeout=600, folder=STUDIES)
    # One study ran; no worker was trained and no summary of a partial run is written.
    assert [p.stem for p in (tmp_path / "studies").glob("*.json")] == ["ddpg"]
    assert len(json.loads((tmp_path / "studies" / "ddpg.json").read_text())["trials"]) == 1
    assert not (tmp_path / "workers").exists() and not (tmp_path / "summary.json").exists()
    assert "| ddpg | " in result.stdout


def test_equal_effort_tuning_refuses_an_unknown_study_name(tmp_path):
    import subprocess

    result = subprocess.run(
        [
            sys.executable,
            str(STUDIES / "equal_effort_tuning.py"),
            "--only",
            "goal,nope",
            "--out",
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2 and "--only: expected study names" in result.stderr
    assert "Traceback" not in result.stderr and not any(tmp_path.iterdir())


def test_goal_holding_measures_a_worker_and_the_reference_reachers(tiny_workers):
    worker = str(tiny_workers / "workers" / "goal.zip")
    result = run_example("goal_holding.py", [worker, "ik", "random", "--episodes", "2"], folder=STUDIES)
    cells = [
        [cell.strip() for cell in line.strip("│").split("│")]
        for line in result.stdout.splitlines()
        if line.startswith("│")
    ]
    # One row per policy, in order; a long path folds onto lines of its own with the other cells empty.
    measured = [row[1:] for row in cells if row[1]]
    assert len(measured) == 3, result.stdout
    rows = dict(zip([worker, "ik", "random"], measured))
    # The IK reacher holds the goal within the touch radius far more often than a random arm, and closer.
    within_radius = {name: float(cells[0].rstrip(" %")) for name, cells in rows.items()}
    median_distance = {name: float(cells[4]) for name, cells in rows.items()}
    assert within_radius["ik"] > within_radius["random"] + 30, result.stdout
    assert median_distance["ik"] < median_distance["random"], result.stdout


def test_own_manager_runs_the_readme_snippet_over_loaded_workers(tmp_path):
    from sb3_hddpg import Hierarchy, load_workers
    from sb3_hddpg.training import train_workers

    config = tmp_path / "tiny.yml"
    # As the quickstart's goal worker: trained on part of the state.
    view = "  env_kwargs:\n    observe: ['joint_positions', 'ee_to_goal', 'goal_touched']\n"
    config.write_text(TINY_CONFIG + "hddpg/SnakeGoal-v0:\n  <<: *tiny\n" + view)
    train_workers(tmp_path / "w", config=config, timesteps=200, eval_freq=0, eval_episodes=1)
    workers = load_workers(tmp_path / "w")
    assert any(workers.states.values()), "the quickstart's workers see part of the state"
    assert not list((tmp_path / "w").rglob("*.lock")), "a finished run leaves no lock files"
    out = tmp_path / "mine.zip"
    args = [str(tmp_path / "w"), "--timesteps", "150", "--episodes", "1", "--out", str(out)]
    result = run_example("own_manager.py", args)
    assert result.stdout.startswith("1 episodes"), result.stdout
    assert (
        "reward (the env's own) = return (normalised terms)" in result.stdout
        and "mean_reward" not in result.stdout
    ), result.stdout
    bundle = Hierarchy.load(out)
    assert bundle.env_id == workers.env_id
    assert bundle.config.worker_states == workers.states
    assert {name: meta["source_sha256"] for name, meta in bundle.worker_meta.items()} == {
        name: entry["sha256"] for name, entry in workers.manifest["workers"].items()
    }


@pytest.mark.parametrize(
    ("budget", "variants"),
    [
        ("env-40k", "dqn,dqn-ham,box"),
        ("env-160k", "dqn,dqn-ham,dqn-long,dqn-step"),
        ("settled-workers", "dqn,dqn-motion,dqn-wide,dqn-wide-motion,dqn-wide-motion-50,dqn-wide-motion-k2"),
    ],
)
def test_the_shipped_conditioned_manager_study_reports_regenerate_from_their_records(
    tmp_path, budget, variants
):
    import shutil

    shipped = STUDIES.parent / "docs" / "results" / "manager-study" / budget
    copy = tmp_path / budget
    shutil.copytree(shipped, copy)
    (copy / "report.md").unlink()
    args = ["--variants", variants, "--seeds", "5", "--out", str(copy), "--report-only"]
    run_example("conditioned_manager_study.py", args, folder=STUDIES)
    assert (copy / "report.md").read_text() == (shipped / "report.md").read_text()


def test_hand_written_measures_the_controllers_and_the_shipped_table_regenerates(tmp_path):
    import importlib.util
    import json

    result = run_example("hand_written.py", ["--episodes", "1", "--out", str(tmp_path)], folder=STUDIES)
    record = json.loads((tmp_path / "hand_written.json").read_text())
    thresholds = [point["threshold"] for point in record["switch"]]
    assert thresholds == [0.25 * k for k in range(1, 25)] and record["switch_threshold"] in thresholds
    # The switch below every reachable clearance sum never hands over: it is the IK reacher alone.
    assert record["switch"][0]["mean_reach_reward"] == record["ik"]["mean_reach_reward"]
    assert "| IK reacher alone |" in result.stdout
    spec = importlib.util.spec_from_file_location("hand_written", STUDIES / "hand_written.py")
    assert spec is not None and spec.loader is not None
    study = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(study)
    shipped = ROOT / "docs" / "results" / "hand_written"
    record = json.loads((shipped / "hand_written.json").read_text())
    assert study.report(record) + "\n" == (shipped / "report.md").read_text()


def test_confirm_pick_trains_both_blocks_and_reports_the_seed_pairs(tmp_path):
    import json

    import yaml

    from sb3_hddpg.training.config import default_config

    # The pick: the bundled flat DDPG block with another learning rate, as a study writes it.
    config = yaml.safe_load(default_config("ddpg").read_text())
    config["hddpg/SnakeReach-v0"]["learning_rate"] = 3e-4
    pick = tmp_path / "ddpg.yml"
    pick.write_text(yaml.safe_dump(config))
    out = tmp_path / "confirm"
    args = ["--method", "ddpg", "--pick", str(pick), "--seeds", "1", "--timesteps", "200", "--backend", "sb3"]
    result = run_example("confirm_pick.py", [*args, "--n-jobs", "2", "--out", str(out)], folder=STUDIES)
    records = {
        arm: json.loads((out / arm / "seed-0" / "record.json").read_text()) for arm in ("base", "pick")
    }
    assert records["pick"]["config"] == pick.name and records["base"]["config"] is None
    assert {r["test_episode_set"]["name"] for r in records.values()} == {"development"}
    assert "| 0 |" in result.stdout and "seed pairs and" in result.stdout
    # The report regenerates from the records alone.
    again = run_example(
        "confirm_pick.py", ["--method", "ddpg", "--report-only", "--out", str(out)], folder=STUDIES
    )
    assert again.stdout == result.stdout


def test_confirm_pick_trains_a_managers_block_over_given_workers(tiny_workers, tmp_path):
    import json

    import yaml

    from sb3_hddpg.training.config import default_config

    # The pick: the bundled DQN manager block with another learning rate, as the front's study writes it.
    dqn = yaml.safe_load(default_config("dqn").read_text())
    dqn["manager"]["learning_rate"] = 3e-4
    base_steps = dqn["manager"]["wrapper_kwargs"]["option_steps"]
    dqn["manager"]["wrapper_kwargs"]["option_steps"] = 2 * base_steps
    pick = tmp_path / "dqn.yml"
    pick.write_text(yaml.safe_dump(dqn))
    out = tmp_path / "confirm"
    args = ["--method", "hddpg-front", "--pick", str(pick), "--workers", str(tiny_workers), "--seeds", "1"]
    options = ["--timesteps", "200", "--front-motion", "20", "--backend", "sb3", "--out", str(out)]
    result = run_example("confirm_pick.py", [*args, *options], folder=STUDIES)
    for arm in ("base", "pick"):
        record = json.loads((out / arm / "seed-0" / "record.json").read_text())
        assert record["env_steps"] == 200 and record["test_episode_set"]["name"] == "development"
    from sb3_hddpg.hierarchy.loading import load_policy

    loaded = load_policy(out / "pick" / "seed-0" / "manager" / "hierarchy.zip")
    assert type(loaded.policy.manager).__name__ == "DQN"
    assert loaded.policy.manager.learning_rate == 3e-4
    # Both arms get the same env steps: the pick's longer options make half as many decisions.
    decisions = {
        arm: json.loads((out / arm / "seed-0" / "manager" / "evaluations" / "manager.json").read_text())[-1]
        for arm in ("base", "pick")
    }
    # SB3 rounds a run up to whole rollouts of train_freq decisions: the env steps match to within one.
    assert decisions["base"]["timesteps"] * base_steps == pytest.approx(200, rel=0.15)
    assert decisions["pick"]["timesteps"] * 2 * base_steps == pytest.approx(200, rel=0.15)
    assert "seed pairs and" in result.stdout
    # A manager without its workers is a usage error, before anything trains.
    script = str(STUDIES / "confirm_pick.py")
    refused = subprocess.run(
        [sys.executable, script, "--method", "hddpg", "--pick", str(pick), "--out", str(tmp_path / "x")],
        capture_output=True,
        text=True,
    )
    assert refused.returncode == 2 and "--workers" in refused.stderr and not (tmp_path / "x").exists()


def test_confirm_pick_refuses_what_its_arms_cannot_use_before_any_arm_runs(tmp_path):
    import json

    script = str(STUDIES / "confirm_pick.py")
    flat = tmp_path / "flat.yml"
    flat.write_text("hddpg/SnakeReach-v0:\n  n_timesteps: 3000\n  policy: MlpPolicy\n  batch_size: -5\n")
    manager = tmp_path / "manager.yml"
    manager.write_text(
        "manager:\n  n_timesteps: 3000\n  policy: MlpPolicy\n  wrapper_kwargs:\n    option_steps: -3\n"
    )
    good = tmp_path / "good.yml"
    good.write_text("hddpg/SnakeReach-v0:\n  n_timesteps: 3000\n  policy: MlpPolicy\n")
    (tmp_path / "w").mkdir()
    runs = [
        # The bundled block's arm trained for the whole budget, then the pick's arm failed: a traceback, exit 1.
        ["--method", "sac", "--pick", str(flat), "--timesteps", "200"],
        ["--method", "hddpg", "--pick", str(manager), "--workers", str(tmp_path / "w")],
        ["--method", "sac", "--pick", str(good), "--backend", "nosuch"],
    ]
    environment = {**os.environ, "PYTHONPATH": str(ROOT)}  # this checkout's package, as the tests import it
    for args in runs:
        out = tmp_path / "out"
        done = subprocess.run(
            [sys.executable, script, *args, "--seeds", "1", "--out", str(out)],
            capture_output=True,
            text=True,
            env=environment,
        )
        assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
        assert not out.exists()
    # A record read back (kept, or shipped with a report) that lacks its score: one line, no report written.
    record = tmp_path / "kept" / "base" / "seed-0" / "record.json"
    record.parent.mkdir(parents=True)
    record.write_text(json.dumps({"development": {"mean_reach_reward": "high"}}))
    args = ["--method", "sac", "--report-only", "--seeds", "1", "--out", str(tmp_path / "kept")]
    done = subprocess.run([sys.executable, script, *args], capture_output=True, text=True, env=environment)
    assert done.returncode == 2 and "record.json" in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "kept" / "report.md").exists()


def test_the_shipped_confirmations_regenerate_from_their_records(tmp_path):
    import shutil

    for shipped in sorted((ROOT / "docs" / "results" / "record" / "confirmations").iterdir()):
        copy = tmp_path / shipped.name
        shutil.copytree(shipped, copy)
        seeds = len(list((copy / "base").glob("seed-*")))
        args = ["--method", shipped.name, "--report-only", "--seeds", str(seeds), "--out", str(copy)]
        run_example("confirm_pick.py", args, folder=STUDIES)
        assert (copy / "report.md").read_text() == (shipped / "report.md").read_text(), shipped.name
