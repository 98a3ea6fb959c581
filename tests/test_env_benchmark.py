"""The benchmark on environments no one here wrote: highway-env's methods, and MORL-baselines beside it."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hddpg_zoo.baselines.ttc import TTC_GRID
from tests.cli_batch import run_batch
from tests.cli_runner import REPO, run_cli

HIGHWAY = {
    "env_id": "hddpg/MultiObjective-v0",
    "env_kwargs": {"env_id": "mo-highway-fast-v0", "terms": ["speed", "lane", "collision"]},
    "terms": ["speed", "lane", "collision"],
}
MORL_SCRIPT = REPO / "hddpg_zoo" / "benchmark" / "morl_runner.py"
MOUNTAIN_CAR = ["--env", "mo-mountaincarcontinuous-v0", "--terms", "time,fuel", "--episode-steps", "30"]


def test_env_methods_are_checked_against_the_env():
    pytest.importorskip("highway_env")
    from hddpg_zoo.benchmark import BenchmarkSettings, default_env_methods
    from sb3_hddpg.envs.terms_env import TermsEnv

    shared = TermsEnv(HIGHWAY["env_id"], HIGHWAY["env_kwargs"], tuple(HIGHWAY["terms"]))
    assert default_env_methods(shared) == (
        "hddpg-dqn",
        "term1-only",
        "term2-only",
        "term3-only",
        "dqn",
        "ppo",
        "ttc-tuned",
    )
    settings = BenchmarkSettings(
        methods=list(default_env_methods(shared)), seeds=[0], timesteps=8, env=HIGHWAY
    )
    assert settings.worker_algos == {"speed": "dqn", "lane": "dqn", "collision": "dqn"}
    assert BenchmarkSettings(
        methods=["hddpg"], timesteps=8, env=HIGHWAY, worker_algo="QRDQN"
    ).worker_algos == {"speed": "qrdqn", "lane": "qrdqn", "collision": "qrdqn"}
    with pytest.raises(ValueError, match=r"\['ddpg'\] cannot act"):
        BenchmarkSettings(methods=["hddpg", "ddpg"], timesteps=8, env=HIGHWAY)
    with pytest.raises(ValueError, match="worker algorithm"):
        BenchmarkSettings(methods=["hddpg"], timesteps=8, env=HIGHWAY, worker_algo="sac")
    with pytest.raises(ValueError, match="another env than the snake"):
        BenchmarkSettings(methods=["hddpg", "ttc-tuned"], timesteps=8)


def test_discrete_methods_refused_on_continuous_actions():
    pytest.importorskip("mo_gymnasium")
    from hddpg_zoo.benchmark import BenchmarkSettings

    car = {
        "env_id": "hddpg/MultiObjective-v0",
        "env_kwargs": {"env_id": "mo-mountaincarcontinuous-v0", "terms": ["time", "fuel"]},
        "terms": ["time", "fuel"],
    }
    with pytest.raises(ValueError, match=r"\['hddpg-dqn', 'dqn'\] cannot act"):
        BenchmarkSettings(methods=["hddpg-dqn", "dqn"], timesteps=8, env=car)
    assert BenchmarkSettings(methods=["hddpg"], timesteps=8, env=car).worker_algos == {
        "time": "ddpg",
        "fuel": "ddpg",
    }


@pytest.mark.slow
def test_benchmark_on_highway_end_to_end(tmp_path):
    pytest.importorskip("highway_env")
    out = tmp_path / "bench"
    methods = "hddpg-dqn,term1-only,term3-only,dqn,ttc-tuned"
    done = run_cli(
        "benchmark",
        "--env",
        "mo-highway-fast-v0",
        "--terms",
        "speed,lane,collision",
        "--methods",
        methods,
        "--seeds",
        "2",
        "--timesteps",
        "24",
        "--worker-timesteps",
        "24",
        "--eval-episodes",
        "1",
        "--test-episodes",
        "2",
        "--n-jobs",
        "1",
        "--out",
        str(out),
    )
    assert done.returncode == 0, done.stdout + done.stderr
    results = json.loads((out / "results.json").read_text())
    assert set(results["methods"]) == set(methods.split(","))
    record = json.loads((out / "records" / "ttc-tuned" / "seed-0.json").read_text())
    assert record["workers"] == {"fast": "speed", "safe": "collision"}
    assert [p["threshold"] for p in record["threshold_grid"]][:2] == [0.5, 1.0]
    assert record["threshold"] in [p["threshold"] for p in record["threshold_grid"]]
    # The rule's own choices, counted by the time to collision: never the safe worker with the road clear.
    shares = record["decisions_by_ttc"]["collision"]
    assert shares["clear_share"] in (0.0, None)
    manager = json.loads((out / "records" / "hddpg-dqn" / "seed-0.json").read_text())
    assert set(manager["decisions_by_ttc"]) == {"speed", "lane", "collision"}
    assert manager["worker_timesteps"] == 72  # three workers of 24 env steps
    alone = json.loads((out / "records" / "term3-only" / "seed-0.json").read_text())
    assert alone["worker"] == "collision" and "decisions_by_ttc" not in alone
    flat = json.loads((out / "records" / "dqn" / "seed-0.json").read_text())
    assert flat["config_blocks"] and "decisions_by_ttc" not in flat
    # The models export with index.json like the snake's: the hierarchy, the flat agent and every worker.
    exported = run_cli("export-models", str(out), str(tmp_path / "models"))
    assert exported.returncode == 0, exported.stderr
    index = json.loads((tmp_path / "models" / "index.json").read_text())
    assert {e["method"] for e in index} == {
        "hddpg-dqn",
        "dqn",
        "worker:speed",
        "worker:lane",
        "worker:collision",
    }
    # The docs' tables regenerate from the records, in the env's own terms (no snake columns).
    page = tmp_path / "page.md"
    blocks = ("methods", "comparisons-hddpg-dqn", "decides-ttc")
    page.write_text("".join(f"<!-- generated:bench/{b} -->\n<!-- /generated:bench/{b} -->\n" for b in blocks))
    reported = run_cli("report", str(out), "--page", str(page))
    assert reported.returncode == 0, reported.stdout + reported.stderr
    text = page.read_text()
    assert (
        "| method | seeds | norm. return: mean [95 % CI] |" in text
        and "| collision (normalised sum) |" in text
    )
    assert "| hddpg-dqn vs | norm. return: difference [CI] |" in text and "`ttc-tuned`" in text
    assert "goal touch" not in text and "| hddpg-dqn | 0 | collision |" in text
    refused = run_cli("benchmark", "--methods", "hddpg,ttc", "--seeds", "1", "--out", str(tmp_path / "s"))
    assert refused.returncode == 2 and "another env" in refused.stderr and "Traceback" not in refused.stderr


@pytest.mark.slow
def test_the_front_on_highway_sweeps_the_time_to_collision_switch(tmp_path):
    pytest.importorskip("highway_env")
    out = tmp_path / "front"
    env = ["--env", "mo-highway-fast-v0", "--terms", "speed,lane,collision", "--episode-steps", "8"]
    tiny = ["--seeds", "1", "--timesteps", "8", "--worker-timesteps", "16", "--front-manager", "dqn"]
    tiny += ["--front-timesteps", "16", "--eval-episodes", "1", "--test-episodes", "1", "--n-jobs", "1"]
    done = run_cli("benchmark", *env, "--scenario", "front", *tiny, "--out", str(out))
    assert done.returncode == 0, done.stdout + done.stderr
    record = json.loads((out / "records" / "hddpg-front" / "seed-0.json").read_text())
    assert list(record["front"]) == ["conditioned", "per-preference", "ttc", "speed", "lane", "collision"]
    # The switch's thresholds come from its grid on the curve episodes, the non-dominated ones kept.
    assert record["rule"] == "ttc" and record["rule_thresholds"]
    assert {t["threshold"] for t in record["rule_thresholds"]} <= set(TTC_GRID)
    assert len(record["front"]["ttc"]["points"]) == len(record["rule_thresholds"])
    assert len(record["front"]["conditioned"]["points"]) == 10  # three workers: 1 + 3 x 3 preferences
    assert record["manager"]["algo"] == "dqn" and record["references"]["terms"] == [0.0, 0.0, 0.0]
    assert "decisions_by_ttc" in record  # the conditioned manager at the unweighted preference


# ------------------------------------------------------------------------ MORL-baselines beside it
def _morl_python() -> str | None:
    """The python of a virtual environment with MORL-baselines (``MORL_PYTHON``), else ``None``."""
    python = os.environ.get("MORL_PYTHON")
    return python if python and Path(python).is_file() else None


def test_morl_runner_says_where_morl_baselines_must_be(tmp_path):
    # sb3-hddpg's own environment has no MORL-baselines (it pins its own torch): a one-line error, exit 2.
    if subprocess.run([sys.executable, "-c", "import morl_baselines"], capture_output=True).returncode == 0:
        pytest.skip("MORL-baselines is installed in this environment")
    front = tmp_path / "front.json"
    front.write_text(json.dumps({"front": [[1.0, -1.0]]}))
    done = subprocess.run(
        [sys.executable, str(MORL_SCRIPT), "score", "--front", str(front), "--out", str(tmp_path / "o.json")],
        capture_output=True,
        text=True,
    )
    assert (
        done.returncode == 2
        and "MORL-baselines environment" in done.stderr
        and "Traceback" not in done.stderr
    )


def test_morl_runner_scores_a_given_front(tmp_path):
    python = _morl_python()
    if python is None:
        pytest.skip("set MORL_PYTHON to the python of a virtual environment with morl-baselines")
    front = tmp_path / "front.json"
    # (2, 1) dominates (1, 1): the hypervolume from (0, 0) is that of (2, 1) and (1, 3): 2 + 1*2 = 4.
    front.write_text(json.dumps({"front": [[1.0, 1.0], [2.0, 1.0], [1.0, 3.0]], "method": "hierarchy"}))
    out = tmp_path / "scored.json"
    done = subprocess.run(
        [python, str(MORL_SCRIPT), "score", "--front", str(front), "--ref-point", "0,0", "--out", str(out)],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    record = json.loads(out.read_text())
    assert record["hypervolume"] == pytest.approx(4.0)
    assert sorted(record["non_dominated"]) == [[1.0, 3.0], [2.0, 1.0]] and record["method"] == "hierarchy"
    assert 1.0 < record["expected_utility"] < 3.0
    bad = subprocess.run(
        [python, str(MORL_SCRIPT), "score", "--front", str(front), "--ref-point", "0,0,0", "--out", str(out)],
        capture_output=True,
        text=True,
    )
    assert bad.returncode != 0 and "Traceback" not in bad.stderr
    # A benchmark's front record: one member's points in its returns plane.
    record = tmp_path / "seed-0.json"
    points = [
        {"label": "a=1,b=3", "a_return": 1.0, "b_return": 3.0},
        {"label": "a=3,b=1", "a_return": 2.0, "b_return": 1.0},
    ]
    record.write_text(
        json.dumps(
            {
                "planes": {"returns": [["a_return", True], ["b_return", True]]},
                "front": {"conditioned": {"points": points}},
            }
        )
    )
    scored = subprocess.run(
        [
            python,
            str(MORL_SCRIPT),
            "score",
            "--record",
            str(record),
            "--ref-point=0,0",
            "--out",
            str(out),
            "--force",
        ],
        capture_output=True,
        text=True,
    )
    assert scored.returncode == 0, scored.stderr
    assert json.loads(out.read_text())["hypervolume"] == pytest.approx(4.0)
    missing = subprocess.run(
        [
            python,
            str(MORL_SCRIPT),
            "score",
            "--record",
            str(record),
            "--member",
            "ham",
            "--out",
            str(out),
            "--force",
        ],
        capture_output=True,
        text=True,
    )
    assert missing.returncode != 0 and "member 'ham'" in missing.stderr and "Traceback" not in missing.stderr


def test_morl_runner_refuses_what_it_cannot_score_in_one_line(tmp_path):
    python = _morl_python()
    if python is None:
        pytest.skip("set MORL_PYTHON to the python of a virtual environment with morl-baselines")

    def score(front: object, *options: str, out: str = "o.json") -> subprocess.CompletedProcess:
        path = tmp_path / "front.json"
        path.write_text(front if isinstance(front, str) else json.dumps(front))
        args = ["score", "--front", str(path), "--ref-point=0,0", "--out", str(tmp_path / out), *options]
        return subprocess.run([python, str(MORL_SCRIPT), *args], capture_output=True, text=True)

    # A given front's own fields never stand in for the scores computed from it (they used to win).
    done = score({"front": [[1.0, 2.0], [2.0, 1.0]], "hypervolume": 1e9, "kind": "x", "method": "m"})
    assert done.returncode == 0, done.stderr
    record = json.loads((tmp_path / "o.json").read_text())
    assert record["hypervolume"] == pytest.approx(3.0) and record["kind"] == "sb3-hddpg-morl-front"
    assert record["method"] == "m"
    # Each was a traceback, a NaN written into the output's JSON, or 20 GB for MORL-baselines' Pareto filter.
    refused = [
        score('{"front": [[NaN, 2.0], [2.0, 1.0]]}', out="a.json"),
        score({"front": [[1.0, 2.0]], "preferences": 5}, out="b.json"),
        score({"front": [{"a": 1}]}, out="c.json"),
        score({"front": [[i, -i] for i in range(5000)]}, out="d.json"),
        score({"front": [[1.0, 2.0]]}, out="o.json"),  # exists: only with --force
        score({"front": [[1.0, 2.0]]}, out="."),
    ]
    zero = [python, str(MORL_SCRIPT), "score", "--front", "/dev/zero", "--out", str(tmp_path / "z.json")]
    refused.append(subprocess.run(zero, capture_output=True, text=True, timeout=60))
    for done in refused:
        assert done.returncode == 2, done.stderr
        assert done.stderr.count("\n") == 1 and done.stderr.startswith("error:"), done.stderr
    assert json.loads((tmp_path / "o.json").read_text()) == record
    assert sorted(p.name for p in tmp_path.iterdir()) == ["front.json", "o.json"]
    assert score({"front": [[1.0, 2.0]]}, "--force").returncode == 0


def test_morl_runner_bounds_its_training_options_before_anything_runs(tmp_path):
    out = str(tmp_path / "o.json")
    for option in (["--preferences", "100000000"], ["--episodes", "0"], ["--timesteps", "10000000000"]):
        done = subprocess.run(
            [sys.executable, str(MORL_SCRIPT), "train", "--timesteps", "300", *option, "--out", out],
            capture_output=True,
            text=True,
        )
        assert done.returncode == 2 and "must be in" in done.stderr and "Traceback" not in done.stderr


def test_a_stopped_benchmark_takes_the_morl_runner_with_it(tmp_path):
    """SIGTERM to the process waiting on the runner (a benchmark being stopped) ends the runner as well."""
    fake = tmp_path / "python"  # stands for MORL-baselines' python: records its pid, then trains a while
    fake.write_text(f"#!/bin/sh\necho $$ > {tmp_path / 'runner.pid'}\nexec sleep 300\n")
    fake.chmod(0o755)
    code = (
        "from pathlib import Path; from hddpg_zoo.benchmark.morl import _run; "
        f"_run({str(fake)!r}, [], Path({str(tmp_path / 'out.json')!r}), [])"
    )
    waiting = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, stderr=subprocess.DEVNULL)
    pid_file = tmp_path / "runner.pid"
    deadline = time.monotonic() + 120
    while not (pid_file.exists() and pid_file.read_text().strip()) and time.monotonic() < deadline:
        time.sleep(0.1)
    runner = int(pid_file.read_text())
    waiting.send_signal(signal.SIGTERM)
    assert waiting.wait(60) != 0
    with pytest.raises(ProcessLookupError):  # killed and reaped by the process that started it
        os.kill(runner, 0)


def test_a_morl_runners_record_is_read_through_one_reader(tmp_path):
    from hddpg_zoo.benchmark.morl import read_morl_record

    keys = ("preferences", "mean_lengths", "wall_time_train_s", "hypervolume", "expected_utility")
    good = {
        "kind": "sb3-hddpg-morl-front",
        "record_version": 1,
        "front": [[1.0, 2.0], [2.0, 1.0]],
        "preferences": [[1.0, 0.0], [0.0, 1.0]],
        "mean_lengths": [30.0, 30.0],
        "wall_time_train_s": 10.0,
        "hypervolume": 3.0,
        "expected_utility": 1.5,
    }
    path = tmp_path / "capql.json"
    path.write_text(json.dumps(good))
    assert read_morl_record(path, keys) == good
    # A record left by an earlier invocation is read back on --resume: NaN and booleans passed as scores,
    # and a front of text or one point short went on into the front's points.
    for change in (
        {"hypervolume": float("nan")},
        {"expected_utility": True},
        {"front": [["a", "b"], [2.0, 1.0]]},
        {"front": [[1.0, 2.0], [2.0]]},
        {"mean_lengths": [30.0]},
        {"mean_lengths": [30.0, float("nan")]},
        {"preferences": [[1.0, 0.0], "x"]},
        {"wall_time_train_s": -1.0},
        {"kind": "other"},
        {"record_version": 99},
    ):
        path.write_text(json.dumps({**good, **change}))
        with pytest.raises(ValueError, match=r"capql\.json"):
            read_morl_record(path, keys)


@pytest.mark.slow
def test_capql_trains_and_scores_its_front(tmp_path):
    python = _morl_python()
    if python is None:
        pytest.skip("set MORL_PYTHON to the python of a virtual environment with morl-baselines and mujoco")
    out = tmp_path / "capql.json"
    done = subprocess.run(
        [
            python,
            str(MORL_SCRIPT),
            "train",
            "--env",
            "mo-halfcheetah-v5",
            "--timesteps",
            "300",
            "--learning-starts",
            "200",
            "--episode-steps",
            "50",
            "--preferences",
            "3",
            "--episodes",
            "1",
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    record = json.loads(out.read_text())
    assert record["algorithm"] == "capql" and record["total_timesteps"] == 300
    assert len(record["front"]) == 3 and record["preferences"][0] == [0.0, 1.0]
    assert record["hypervolume"] > 0 and record["wall_time_train_s"] > 0
    assert record["versions"]["torch"] and record["ref_point"] == [-100.0, -100.0]


def test_morl_python_is_checked_before_anything_runs(tmp_path):
    pytest.importorskip("mo_gymnasium")
    front = ["--scenario", "front", "--seeds", "1", "--timesteps", "8", "--out", str(tmp_path / "b")]
    # Three refusals, one interpreter (tests/cli_batch.py): each still gets its own exit code and output.
    python = sys.executable
    missing, snake, standard = run_batch(
        [
            ["benchmark", *MOUNTAIN_CAR, *front, "--morl-python", str(tmp_path / "none")],
            ["benchmark", *front, "--morl-python", python],
            [
                "benchmark",
                *MOUNTAIN_CAR,
                "--methods",
                "hddpg",
                "--morl-python",
                python,
                "--out",
                str(tmp_path),
            ],
        ]
    )
    assert missing.returncode == 2 and "executable python" in missing.stderr
    # Nor did the two refusals after it write the folder.
    assert "Traceback" not in missing.stderr and not (tmp_path / "b").exists()
    assert snake.returncode == 2 and "MO-Gymnasium env" in snake.stderr
    assert standard.returncode == 2 and "member of the front" in standard.stderr


def test_a_morl_runners_front_joins_the_hierarchys_planes():
    from hddpg_zoo.benchmark.front_pages import front_table
    from hddpg_zoo.benchmark.front_points import env_front
    from hddpg_zoo.benchmark.morl import morl_points, morl_results

    bounds = {"time": (-1.0, 0.0), "fuel": (-0.5, 0.0)}
    spec = env_front(("time", "fuel"), bounds, 30)
    record = {"preferences": [[1.0, 0.0], [0.0, 1.0]], "front": [[-30.0, -3.0], [-15.0, -15.0]]}
    points = morl_points({**record, "mean_lengths": [30.0, 15.0]}, spec, bounds)
    assert [p.label for p in points] == ["time=1,fuel=0", "time=0,fuel=1"]
    # 30 steps at the least time term; fuel -3 of its least -15: (0 + 0.8) * 30 / 30 per step.
    assert points[0].values["time_term"] == pytest.approx(0.0)
    assert points[0].values["fuel_term"] == pytest.approx(0.8)
    assert points[0].values["mean_reach_reward"] == pytest.approx(0 + 24.0)
    assert points[1].values["time_return"] == -15.0 and points[1].values["fuel_term"] == pytest.approx(-1.0)
    with pytest.raises(ValueError, match="2 returns per point"):
        morl_points({**record, "front": [[1.0], [2.0]], "mean_lengths": [1.0, 1.0]}, spec, bounds)

    def run(seed: int) -> dict:
        score = {"hypervolume": 10.0 + seed, "expected_utility": -5.0}
        return {
            "morl": {
                "algorithm": "capql",
                "env_steps": 1000,
                "ref_point": [-30.0, -15.0],
                "wall_time_train_s": 100.0 + seed,
                "wall_time_eval_s": 1.0,
                "conditioned_train_s": 20.0,
                "scores": {"capql": score, "conditioned": {**score, "hypervolume": 8.0}},
                "versions": {"torch": "2"},
            }
        }

    workers = {seed: {"wall_time_s_total": 40.0} for seed in (0, 1)}
    summary = morl_results({0: run(0), 1: run(1)}, workers)
    assert summary is not None and summary["env_steps"] == [1000, 1000]
    assert summary["scores"]["capql"]["hypervolume"]["mean"] == pytest.approx(10.5)
    assert summary["train_seconds"]["conditioned"]["mean"] == pytest.approx(60.0)
    assert morl_results({0: {}}, workers) is None
    front = {"members": [], "hypervolume": {}, "morl": summary}
    table = "\n".join(front_table(front))  # type: ignore[arg-type]
    assert "| capql | 10.5 [" in table and "1,000 per seed" in table


@pytest.mark.slow
def test_benchmark_runs_capql_beside_the_conditioned_manager(tmp_path):
    python = _morl_python()
    if python is None:
        pytest.skip("set MORL_PYTHON to the python of a virtual environment with morl-baselines")
    tiny = ["--seeds", "2", "--front-timesteps", "200", "--worker-timesteps", "200", "--eval-freq", "200"]
    tiny += ["--eval-episodes", "1", "--test-episodes", "2", "--n-jobs", "1"]
    out = tmp_path / "front"
    args = [*MOUNTAIN_CAR, "--scenario", "front", *tiny, "--morl-python", python, "--out", str(out)]
    done = run_cli("benchmark", *args)
    assert done.returncode == 0, done.stdout + done.stderr
    record = json.loads((out / "records" / "hddpg-front" / "seed-1.json").read_text())
    # CAPQL at the hierarchy's env steps for one policy: two workers and the conditioned manager.
    assert record["morl"]["env_steps"] == 200 + 200 + 200
    assert len(record["front"]["capql"]["points"]) == len(record["front"]["conditioned"]["points"])
    assert set(record["morl"]["scores"]) == {"capql", "conditioned"}
    results = json.loads((out / "results.json").read_text())["front"]
    assert "capql" in results["members"] and "conditioned vs capql" in results["comparisons"]
    assert results["morl"]["train_seconds"]["capql"]["mean"] > 0
    assert "(MORL-baselines) beside the conditioned manager" in (out / "results.md").read_text()
    # Resumed, the runner's records are read, not trained again.
    again = run_cli("benchmark", *args, "--resume")
    assert again.returncode == 0, again.stderr
