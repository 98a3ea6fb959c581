"""MORL-baselines' protocol: its settings, its runner's arguments, its records, its indicators and its page."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from hddpg_zoo.benchmark.morl_coverage import convex_coverage_set, recovered_points
from hddpg_zoo.benchmark.morl_page import morl_page, write_morl_page
from hddpg_zoo.benchmark.morl_protocol import PROTOCOL_ENVS, ProtocolSettings
from hddpg_zoo.benchmark.morl_protocol_run import (
    PROTOCOL_RUNNER,
    protocol_weights,
    read_protocol_record,
    read_protocol_run,
)

#: A development run made by a real (tiny) run of `benchmark --protocol morl-baselines` (see its protocol.json).
SHIPPED = Path(__file__).parent / "data" / "morl_protocol" / "deep-sea-treasure-concave-v0"
MORL_PYTHON = os.environ.get("MORL_PYTHON")
COMMAND = [sys.executable, "-m", "sb3_hddpg", "benchmark", "--protocol", "morl-baselines"]
COMMAND += ["--env", "deep-sea-treasure-concave-v0", "--seeds", "1"]
TRAIN_TINY = [
    "train",
    "--algo",
    "envelope",
    "--timesteps",
    "10",
    "--env",
    "minecart-v0",
    "--ref-point=0,0,-200",
]
needs_morl = pytest.mark.skipif(not MORL_PYTHON, reason="MORL_PYTHON (MORL-baselines' python) is not set")


@pytest.mark.parametrize(
    ("changes", "option"),
    [
        ({"env_id": "mo-halfcheetah-v5"}, "--env"),
        ({"seeds": (0, 0)}, "--seeds"),
        ({"peers": ("capql",)}, "--methods"),
        ({"methods": ("hddpg-unknown",)}, "--methods"),
        ({"methods": ("hddpg-gpi-sac",)}, "--methods"),  # SAC acts on continuous actions only
        ({"methods": ("hddpg-gpi-terms-sac",)}, "--methods"),
        ({"timesteps": 200_001}, "--timesteps"),
        ({"timesteps": 9_999, "peers": ("gpi-ls",)}, "--timesteps"),
        ({"eval_weights": 0}, "--eval-weights"),
        ({"morl_python": None}, "--morl-python"),
    ],
)
def test_settings_refuse_what_the_protocol_does_not_allow(changes, option):
    given = {"env_id": "deep-sea-treasure-concave-v0", "seeds": (0, 1), "morl_python": "python", **changes}
    with pytest.raises(ValueError, match=option):
        ProtocolSettings(**given)


def test_the_settings_take_both_hierarchy_methods():
    settings = ProtocolSettings("minecart-v0", (0,), ("hddpg-conditioned", "hddpg-gpi"), morl_python="python")
    assert settings.methods == ("hddpg-conditioned", "hddpg-gpi")


def test_a_run_of_record_takes_the_protocols_budget_ten_seeds_and_the_final_test():
    record = ProtocolSettings("minecart-v0", tuple(range(10)), final_test=True, morl_python="python")
    assert record.of_record and record.budget == 150_000 and record.peers == ("gpi-pd", "envelope")
    assert record.full_budget
    reduced = ProtocolSettings(
        "minecart-v0", tuple(range(10)), timesteps=15_000, final_test=True, morl_python="p"
    )
    assert reduced.of_record and not reduced.full_budget
    for pilot in (
        ProtocolSettings("minecart-v0", tuple(range(10)), timesteps=15_000, morl_python="p"),
        ProtocolSettings("minecart-v0", tuple(range(10)), timesteps=14_999, final_test=True, morl_python="p"),
        ProtocolSettings("minecart-v0", tuple(range(9)), final_test=True, morl_python="p"),
        ProtocolSettings("minecart-v0", tuple(range(10)), eval_episodes=1, final_test=True, morl_python="p"),
    ):
        assert not pilot.of_record
    written = json.dumps(record.to_json())
    assert "python" not in written.replace('"protocol"', "")  # no interpreter path of this machine


def test_the_protocols_time_limits_are_the_registered_ones():
    gym = pytest.importorskip("gymnasium")
    pytest.importorskip("mo_gymnasium")
    for env in PROTOCOL_ENVS.values():
        assert gym.spec(env.env_id).max_episode_steps == env.episode_steps, env.env_id


@pytest.mark.parametrize(
    "arguments",
    [
        ["train", "--algo", "pgmorl", "--timesteps", "10", "--env", "minecart-v0", "--ref-point=0,0,-200"],
        ["train", "--algo", "envelope", "--timesteps", "0", "--env", "minecart-v0", "--ref-point=0,0,-200"],
        ["score", "--returns", "r.json", "--env", "minecart-v0", "--ref-point=0,0,-200", "--gamma", "1.5"],
        [
            "score",
            "--returns",
            "r.json",
            "--env",
            "minecart-v0",
            "--ref-point=0,0,-200",
            "--eval-weights",
            "0",
        ],
        [*TRAIN_TINY, "--stop-after-chunks", "1"],
        [*TRAIN_TINY, "--checkpoint-dir", "c", "--chunk-steps", "0"],
        [*TRAIN_TINY, "--checkpoint-dir", __file__],
    ],
)
def test_the_runner_refuses_bad_options_before_anything_is_imported(arguments, tmp_path):
    # Our python has no MORL-baselines: the options are checked before it is needed.
    done = subprocess.run(
        [sys.executable, str(PROTOCOL_RUNNER), *arguments, "--out", str(tmp_path / "o.json")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 2
    assert "Traceback" not in done.stderr and "--" in done.stderr.splitlines()[-1]
    assert not (tmp_path / "o.json").exists()


def test_the_weights_are_the_protocols():
    weights = np.asarray(protocol_weights(2, 100))
    assert weights.shape == (100, 2)
    np.testing.assert_allclose(weights.sum(axis=1), 1.0)
    assert {tuple(weights.min(axis=0)), tuple(weights.max(axis=0))} == {(0.0, 0.0), (1.0, 1.0)}


def test_a_shipped_record_reads_and_a_broken_one_is_named(tmp_path):
    settings, records = read_protocol_run(SHIPPED)
    assert settings["env_id"] == "deep-sea-treasure-concave-v0" and not settings["of_record"]
    assert {r.side for by in records.values() for r in by.values()} == {"hierarchy", "peer"}
    for by in records.values():
        for record in by.values():
            assert len(record.discounted_returns) == len(record.weights) == settings["eval_weights"]
            assert all(len(episodes) == settings["eval_episodes"] for episodes in record.returns)
            assert record.total_env_steps >= settings["budget"] - 1 and "igd" in record.indicators
    path = next((SHIPPED / "records").glob("*/seed-0.json"))
    broken = json.loads(path.read_text())
    broken["discounted_returns"] = broken["discounted_returns"][:-1]
    (tmp_path / "r.json").write_text(json.dumps(broken))
    with pytest.raises(ValueError, match="discounted_returns"):
        read_protocol_record(tmp_path / "r.json")


def test_the_page_replays_the_shipped_records(tmp_path):
    page = tmp_path / "MORL.md"
    assert write_morl_page([SHIPPED], page)
    text = page.read_text()
    assert "## deep-sea-treasure-concave-v0" in text and "**Not a result**" in text
    assert "No run of record exists yet" in text and "ahead" not in text and "behind" not in text
    _, records = read_protocol_run(SHIPPED)
    for method, by in records.items():
        row = next(line for line in text.splitlines() if line.startswith(f"| {method} |"))
        assert f"{by[0].indicators['hypervolume']:.4g}" in row
    assert (tmp_path / "results" / "morl-deep-sea-treasure-concave-v0.png").stat().st_size > 1000
    assert not write_morl_page([SHIPPED], page, check=True)  # regenerated: the same text


def _as_record_at_a_reduced_budget(tmp_path: Path) -> Path:
    """The shipped run, made a run of record at a tenth of the protocol's budget: a second seed, the final test."""
    run = tmp_path / "run"
    shutil.copytree(SHIPPED, run)
    settings = json.loads((run / "protocol.json").read_text())
    settings.update(final_test=True, of_record=True, seeds=[0, 1], budget=20_000)
    (run / "protocol.json").write_text(json.dumps(settings))
    for path in (run / "records").glob("*/seed-0.json"):
        record = json.loads(path.read_text())
        record["seed"] = 1
        record["indicators"]["hypervolume"] += 1.0 if record["side"] == "hierarchy" else 0.0
        record["wall_time_train_s"] *= 1.5
        path.with_name("seed-1.json").write_text(json.dumps(record))
    return run


def test_a_run_of_record_at_a_reduced_budget_says_so_with_the_peers_speed(tmp_path):
    run = _as_record_at_a_reduced_budget(tmp_path)
    _, records = read_protocol_run(run)
    text = morl_page([run], tmp_path / "MORL.md", draw=False)
    assert "**Not a result**" not in text and "No run of record exists yet" not in text
    assert (
        "A run of record at a **reduced budget**: 20,000 env steps per side, 10% of the protocol's 200,000"
        in text
    )
    # The peer's speed, measured on its seeds, extrapolated to the protocol's budget.
    envelope = list(records["envelope"].values())
    hours = np.mean([r.wall_time_train_s / r.total_env_steps * 200_000 for r in envelope]) / 3600
    assert f"a seed of envelope would train for about {hours:.2g} h" in text
    row = next(line for line in text.splitlines() if line.startswith("| envelope |"))
    assert row.rstrip(" |").endswith(f"{hours:.2g}")
    # Worded as a result: the paired test's word beside each indicator.
    comparison = next(
        line for line in text.splitlines() if line.startswith("| hddpg-conditioned - envelope |")
    )
    assert "ahead" in comparison or "behind" in comparison or "not distinguishable" in comparison
    ratios = [
        records["hddpg-conditioned"][s].wall_time_train_s / records["envelope"][s].wall_time_train_s
        for s in (0, 1)
    ]
    assert comparison.endswith(f"| {np.median(ratios):.3g} [{min(ratios):.3g}, {max(ratios):.3g}] |")


#: deep-sea-treasure-concave's true front at gamma 0.99 (MO-Gymnasium 1.3): only its two ends are convex.
DST_FRONT = [
    [1.0, -1.0],
    [1.9602, -2.9701],
    [2.88178803, -4.90099501],
    [4.707400747005, -6.793465209301],
    [7.456522783255919, -7.72553055720799],
    [14.763915110846721, -8.64827525163591],
    [21.273236921187102, -12.247897700103202],
    [43.876051149948395, -13.12541872310217],
    [63.00787506102079, -15.70568066160731],
    [103.47970641981085, -17.383137616441324],
]


def test_the_convex_coverage_set_leaves_out_concave_and_dominated_points():
    # Two ends, a point on the segment between them, one below it (concave) and one dominated.
    values = np.array([[1.0, 0.0], [0.0, 1.0], [0.5, 0.5], [0.4, 0.4], [0.9, -0.1], [0.8, 0.45]])
    ccs = convex_coverage_set(values)
    assert set(ccs) == {0, 1, 5}
    for index, weights in ccs.items():
        scores = values @ weights
        # Each point is the one best at its own weighting.
        assert scores[index] == pytest.approx(scores.max())
        assert np.all(np.delete(scores, index) < scores[index] - 1e-9)
    # A point on the segment between two others ties with them wherever it is optimal: not in the minimal set.
    assert set(convex_coverage_set(values[:3])) == {0, 1}
    # The same in three terms (on an edge of the front), a duplicate, a weakly dominated point.
    assert set(convex_coverage_set(np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0]]))) == {0, 1, 2}
    assert set(convex_coverage_set(np.array([[0.0, 1.0], [1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]))) == {0, 1}
    assert set(convex_coverage_set(np.array([[1.0, 0.0], [1.0, -0.5], [0.0, 1.0]]))) == {0, 2}


def test_a_side_recovers_the_points_of_the_convex_coverage_set_it_reaches():
    assert recovered_points(DST_FRONT, DST_FRONT) == {0, 9}
    assert recovered_points(DST_FRONT, [[1.0, -1.0], [63.0, -15.7]]) == {0}
    # The far treasure two steps late is not the far treasure.
    assert recovered_points(DST_FRONT, [[101.42, -19.03]]) == set()
    assert recovered_points(DST_FRONT, [[103.4, -17.39], [0.0, -50.0]]) == {9}


def test_the_page_counts_the_recovered_points_per_side(tmp_path):
    run = _as_record_at_a_reduced_budget(tmp_path)
    _, records = read_protocol_run(run)
    assert records["envelope"][0].known_front == DST_FRONT
    text = morl_page([run], tmp_path / "MORL.md", draw=False)
    assert "Points of the true front's convex coverage set (2) recovered" in text
    # The shipped run: envelope reaches the first treasure, the conditioned manager no treasure's utility.
    assert [recovered_points(DST_FRONT, records[m][0].front) for m in ("envelope", "hddpg-conditioned")] == [
        {0},
        set(),
    ]
    assert "| envelope | 1 of 2 | 0 of 2 |" in text and "| hddpg-conditioned | 0 of 2 | 0 of 2 |" in text
    assert (
        "- hddpg-conditioned recovers every point envelope recovers in 0 of the 2 seeds where envelope recovers "
        "one (envelope recovers none in 0)." in text
    )


def test_the_page_counts_a_peers_points_beyond_every_mixture_of_the_hierarchys(tmp_path):
    run = _as_record_at_a_reduced_budget(tmp_path)
    fronts = {
        # A switch between two policies reaches the segment between their points.
        "hddpg-conditioned": [[0.0, 0.0]] * 50 + [[10.0, -10.0]] * 50,
        # On the segment; beyond it by 0.5 on both objectives at once; dominated (not counted).
        "envelope": [[5.0, -5.0]] * 50 + [[2.0, -1.0]] * 49 + [[1.0, -20.0]],
    }
    # MORL-baselines' non-dominated filter of those fronts, as the runner writes it.
    kept = {"hddpg-conditioned": [[0.0, 0.0], [10.0, -10.0]], "envelope": [[5.0, -5.0], [2.0, -1.0]]}
    for method, front in fronts.items():
        for path in (run / "records" / method).glob("seed-*.json"):
            record = json.loads(path.read_text())
            record.update(front=front, non_dominated=kept[method])
            path.write_text(json.dumps(record))
    text = morl_page([run], tmp_path / "MORL.md", draw=False)
    line = next(
        line for line in text.splitlines() if line.startswith("- envelope's non-dominated points beyond")
    )
    assert line.endswith("per seed: 1 of 2, 1 of 2; the farthest by 0.5 on every objective at once.")


def test_a_known_front_too_large_to_cover_is_refused(tmp_path):
    path = next((SHIPPED / "records").glob("*/seed-0.json"))
    record = json.loads(path.read_text())
    record["known_front"] = [[float(i), -float(i)] for i in range(500)]
    (tmp_path / "r.json").write_text(json.dumps(record))
    with pytest.raises(ValueError, match="known_front"):
        read_protocol_record(tmp_path / "r.json")


def test_a_run_of_one_side_has_no_comparison_table(tmp_path):
    run = tmp_path / "run"
    shutil.copytree(SHIPPED, run)
    shutil.rmtree(run / "records" / "envelope")
    text = morl_page([run], tmp_path / "MORL.md", draw=False)
    assert "| hddpg-conditioned | 1 |" in text and "| hierarchy - peer |" not in text


def test_the_page_without_runs_says_no_result_exists(tmp_path):
    text = morl_page([], tmp_path / "MORL.md")
    assert "No run of record exists yet" in text and "## Results" in text


@needs_morl
def test_morl_baselines_indicators_of_a_fixed_front(tmp_path):
    from hddpg_zoo.benchmark.front_points import hypervolume

    returns = {"discounted_returns": [[[1.0, -1.0], [1.0, -1.0]], [[8.2, -3.0]], [[0.5, -0.5]]]}
    (tmp_path / "r.json").write_text(json.dumps(returns))
    out = tmp_path / "s.json"
    arguments = ["score", "--returns", str(tmp_path / "r.json"), "--env", "deep-sea-treasure-concave-v0"]
    subprocess.run(
        [MORL_PYTHON, str(PROTOCOL_RUNNER), *arguments, "--ref-point=0,-50", "--out", str(out)],
        check=True,
        capture_output=True,
        env={**os.environ, "WANDB_MODE": "disabled"},
    )
    scored = json.loads(out.read_text())["indicators"]
    # By hand: the three points' boxes above (0, -50) and pymoo's hypervolume agree with MORL-baselines'.
    assert scored["hypervolume"] == pytest.approx(1 * 49 + 7.2 * 47 + 0.5 * 0.5)
    points = [{"a": 1.0, "b": -1.0}, {"a": 8.2, "b": -3.0}, {"a": 0.5, "b": -0.5}]
    mine = hypervolume(points, [("a", True), ("b", True)], (0.0, -50.0))
    assert scored["hypervolume"] == pytest.approx(mine)
    assert scored["cardinality"] == 3 and scored["maximum_utility_loss"] > 0 and scored["igd"] > 0


@needs_morl
def test_the_runner_reads_relative_paths_from_where_it_was_started(tmp_path):
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "r.json").write_text(
        json.dumps({"discounted_returns": [[[1.0, -1.0]], [[8.2, -3.0]]]})
    )
    arguments = [
        "score",
        "--returns",
        "in/r.json",
        "--env",
        "deep-sea-treasure-concave-v0",
        "--ref-point=0,-50",
    ]
    done = subprocess.run(
        [MORL_PYTHON, str(PROTOCOL_RUNNER), *arguments, "--out", "out/s.json"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ, "WANDB_MODE": "disabled"},
        check=False,
    )
    assert done.returncode == 0, done.stderr[-1000:]
    assert json.loads((tmp_path / "out" / "s.json").read_text())["indicators"]["cardinality"] == 2


@needs_morl
def test_a_tiny_protocol_run_end_to_end(tmp_path):
    out = tmp_path / "run"
    arguments = ["--timesteps", "1200", "--methods", "envelope", "--test-episodes", "1"]
    done = subprocess.run(
        [*COMMAND, *arguments, "--morl-python", str(MORL_PYTHON), "--out", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    settings, records = read_protocol_run(out)
    assert set(records) == {"hddpg-conditioned", "envelope"} and settings["budget"] == 1200
    # The peer trained in one chunk, never resumed; its checkpoint went once its record was written.
    assert (records["envelope"][0].resumes, records["envelope"][0].chunk_steps) == (0, 10_000)
    assert not list((out / "runs" / "envelope").rglob("*.pt"))
    assert str(Path.home()) not in (out / "protocol.json").read_text()
    shutil.rmtree(out / "runs")


@needs_morl
def test_tasks_in_parallel_write_the_records_one_task_at_a_time_writes(tmp_path):
    arguments = ["--timesteps", "400", "--methods", "hddpg-conditioned,envelope", "--test-episodes", "1"]
    runs = {}
    for jobs in ("1", "2"):
        out = tmp_path / f"jobs-{jobs}"
        done = subprocess.run(
            [*COMMAND, *arguments, "--n-jobs", jobs, "--morl-python", str(MORL_PYTHON), "--out", str(out)],
            capture_output=True,
            text=True,
            check=False,
        )
        assert done.returncode == 0, done.stderr[-2000:]
        runs[jobs] = read_protocol_run(out)
    assert runs["1"][0] == runs["2"][0]
    for side, by_seed in runs["1"][1].items():
        # Seeded sides: the same front whether the tasks ran one after another or side by side.
        assert by_seed[0].discounted_returns == runs["2"][1][side][0].discounted_returns


def test_a_resumed_protocol_run_may_add_seeds_and_sides_but_change_nothing_else(tmp_path):
    pytest.importorskip("mo_gymnasium")
    from hddpg_zoo.benchmark.morl_protocol_run import _continues_run, run_protocol

    def settings(**changed: object) -> ProtocolSettings:
        given = {"seeds": (0,), "methods": ("hddpg-gpi",), "peers": (), "timesteps": 400, **changed}
        return ProtocolSettings("deep-sea-treasure-concave-v0", morl_python=sys.executable, **given)

    kept = settings().to_json()
    (tmp_path / "protocol.json").write_text(json.dumps(kept))
    widened = settings(seeds=(0, 1), methods=("hddpg-gpi", "hddpg-gpi-terms"), peers=("envelope",))
    assert _continues_run(kept, widened) and _continues_run(kept, settings())
    others = [
        settings(timesteps=800),
        settings(eval_episodes=2),
        settings(final_test=True),
        settings(methods=("hddpg-gpi-terms",)),  # drops a side the folder holds records of
        settings(seeds=(1,)),
    ]
    for other in others:
        assert not _continues_run(kept, other)
        with pytest.raises(ValueError, match="may only add seeds and sides"):
            run_protocol(other, tmp_path)
    assert json.loads((tmp_path / "protocol.json").read_text()) == kept


@needs_morl
def test_a_resumed_protocol_run_runs_only_its_new_tasks(tmp_path):
    arguments = ["--timesteps", "400", "--test-episodes", "1", "--morl-python", str(MORL_PYTHON)]
    out = ["--out", str(tmp_path / "run")]
    first = [*COMMAND, *arguments, "--methods", "hddpg-gpi-terms", *out]
    assert subprocess.run(first, capture_output=True, text=True, check=False).returncode == 0
    kept = tmp_path / "run" / "records" / "hddpg-gpi-terms" / "seed-0.json"
    before = (kept.read_bytes(), kept.stat().st_mtime_ns)
    widened = [*COMMAND, *arguments, "--methods", "hddpg-gpi-terms,hddpg-conditioned", "--seeds", "2", *out]
    done = subprocess.run([*widened, "--resume"], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    settings, records = read_protocol_run(tmp_path / "run")
    assert {side: sorted(by) for side, by in records.items()} == {
        "hddpg-gpi-terms": [0, 1],
        "hddpg-conditioned": [0, 1],
    }
    assert settings["seeds"] == [0, 1] and (kept.read_bytes(), kept.stat().st_mtime_ns) == before


def _meeting_task(settings: ProtocolSettings, side: str, seed: int, out: Path) -> Path:
    """A task that says it started, then waits (at most 60 s) to see every other task started too."""
    (out / f"started-{side}").touch()
    deadline = time.monotonic() + 60
    while len(list(out.glob("started-*"))) < len(settings.methods) and time.monotonic() < deadline:
        time.sleep(0.05)
    met = len(list(out.glob("started-*"))) == len(settings.methods)
    (out / f"{'met' if met else 'alone'}-{side}").touch()
    return out


def test_tasks_in_parallel_overlap_in_time(tmp_path):
    pytest.importorskip("mo_gymnasium")
    from hddpg_zoo.benchmark.morl_protocol_run import _run_in_parallel

    methods = ("hddpg-conditioned", "hddpg-gpi")
    settings = ProtocolSettings(
        "deep-sea-treasure-concave-v0", (0,), methods, (), 400, morl_python=sys.executable
    )
    _run_in_parallel(settings, [(method, 0) for method in methods], tmp_path, n_jobs=2, task=_meeting_task)
    # Each task, in its own process, saw the other one started while it was still running.
    assert sorted(p.name for p in tmp_path.glob("met-*")) == [f"met-{m}" for m in sorted(methods)]


def test_a_failed_task_in_parallel_is_raised_and_writes_no_record(tmp_path):
    pytest.importorskip("mo_gymnasium")
    from hddpg_zoo.benchmark.morl_protocol_run import run_protocol

    # Two env steps train no model: every task fails in its own spawned process, before any scoring.
    settings = ProtocolSettings(
        "deep-sea-treasure-concave-v0", (0, 1, 2), ("hddpg-conditioned",), (), 2, morl_python=sys.executable
    )
    with pytest.raises(ValueError, match="trains no model"):
        run_protocol(settings, tmp_path / "run", n_jobs=2)
    assert not list((tmp_path / "run").glob("records/*/*.json"))
    assert json.loads((tmp_path / "run" / "protocol.json").read_text()) == settings.to_json()


def test_morl_report_check_says_the_shipped_page_is_up_to_date():
    root = Path(__file__).parents[1]
    runs = sorted(str(run) for run in (root / "docs" / "results" / "morl-dev").iterdir())
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "sb3_hddpg",
            "morl-report",
            *runs,
            "--page",
            str(root / "docs" / "MORL.md"),
            "--check",
        ],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0 and "up to date" in done.stdout and "would change" not in done.stdout


def test_the_shipped_page_is_current():
    docs = Path(__file__).parents[1] / "docs"
    runs = sorted((docs / "results" / "morl-dev").iterdir())
    assert runs and all((run / "protocol.json").is_file() for run in runs)
    assert not write_morl_page(runs, docs / "MORL.md", check=True)


@pytest.mark.parametrize(
    ("arguments", "named"),
    [
        (["--protocol", "morl-baseline", "--env", "minecart-v0"], "--protocol"),
        (
            ["--protocol", "morl-baselines", "--env", "mo-halfcheetah-v5", "--morl-python", sys.executable],
            "--env",
        ),
        (["--protocol", "morl-baselines", "--env", "minecart-v0", "--methods", "capql"], "--methods"),
        (["--protocol", "morl-baselines", "--env", "minecart-v0"], "--morl-python"),
        (["--protocol", "morl-baselines", "--env", "minecart-v0", "--n-jobs", "999"], "--n-jobs"),
        (["--protocol", "morl-baselines", "--env", "minecart-v0", "--executor", "ray"], "--executor"),
    ],
)
def test_the_command_names_a_bad_option_in_one_line(arguments, named, tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "sb3_hddpg", "benchmark", *arguments, "--out", str(tmp_path / "o")],
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 2, done.stderr
    assert named in done.stderr and "Traceback" not in done.stderr
    assert not (tmp_path / "o").exists()


def test_deep_sea_treasures_constant_time_gets_bounds_and_costs_no_steps(tmp_path):
    pytest.importorskip("mo_gymnasium")
    from hddpg_zoo.benchmark.morl_sides import SideRun, pinned_env, train_conditioned

    shared, steps = pinned_env("deep-sea-treasure-concave-v0")
    # With its sign: -1 a step normalises to -1, so that shorter episodes are better, as the raw time says.
    assert steps == 0 and shared.env_kwargs["term_bounds"]["obj1"] == [0.0, 1.0]
    with pytest.raises(ValueError, match="trains no model"):
        train_conditioned(SideRun("deep-sea-treasure-concave-v0", True, 0.99, 2, 0, tmp_path))


def test_gpi_coefficients_carry_the_constant_objectives_offset():
    from hddpg_zoo.benchmark.morl_gpi import gpi_coefficients

    # DST-like, time pinned to 1 a step (bounds (-2, -1)): w.V = 0.5 (-L + 10 N0) + 0.5 (-L) = 5 N0 - L, and
    # the time critic is L: coefficients (5, -1), negative on time.
    bounds = {"treasure": (-1.0, 9.0), "time": (-2.0, -1.0)}
    terms = ["treasure", "time"]
    assert gpi_coefficients([0.5, 0.5], terms, bounds, {"time": -1.0}) == pytest.approx(
        {"treasure": 5.0, "time": -1.0}
    )
    # With treasure's low 0 the time coefficient is -w_time.
    dst = {"treasure": (0.0, 124.0), "time": (-2.0, -1.0)}
    assert gpi_coefficients([0.3, 0.7], terms, dst, {"time": -1.0}) == pytest.approx(
        {"treasure": 37.2, "time": -0.7}
    )
    # Time pinned with its sign (bounds (0, 1): -1 a step, critic -L): w.V = 0.3 * 124 N0 - 0.7 L, coefficient
    # +0.7 on the critic -L.
    signed = {"treasure": (0.0, 124.0), "time": (0.0, 1.0)}
    assert gpi_coefficients([0.3, 0.7], terms, signed, {"time": -1.0}) == pytest.approx(
        {"treasure": 37.2, "time": 0.7}
    )
    # Cheetah-like, no constant objective: w_i range_i alone (the length's offset is not known).
    cheetah = {"speed": (-1.0, 3.0), "energy": (-2.0, 0.0)}
    assert gpi_coefficients([0.25, 0.75], ["speed", "energy"], cheetah) == pytest.approx(
        {"speed": 1.0, "energy": 1.5}
    )


def test_the_gpi_policy_plays_negative_coefficients_without_the_preference_check():
    from hddpg_zoo.benchmark.morl_gpi import GpiPolicy
    from sb3_hddpg.hierarchy.frozen import FrozenWorker
    from sb3_hddpg.hierarchy.gpi import GpiSelector
    from tests.test_gpi import Fixed, constant_critic

    workers = [FrozenWorker(Fixed(np.float32([0.5, 0.5]))), FrozenWorker(Fixed(np.float32([-0.5, 0.0])))]
    # "avoid" is a constant objective pinned to 1 a step: its critic is the remaining length.
    selector = GpiSelector(workers, [constant_critic([1.0, 2.0]), constant_critic([0.5, 20.0])])
    bounds = {"goal": (0.0, 10.0), "avoid": (-2.0, -1.0)}
    policy = GpiPolicy(selector, ["goal", "avoid"], bounds, {"avoid": -1.0})
    policy.set_weights([0.1, 0.9])
    assert policy.coefficients == pytest.approx({"goal": 1.0, "avoid": -0.9})
    # 1 - 0.9 * 2 > 0.5 - 0.9 * 20: the short episode's worker; without the offset, 1 + 1.8 < 0.5 + 18.
    assert np.allclose(policy.act(np.zeros(3)), [0.5, 0.5])


def test_hddpg_gpi_trains_a_support_within_one_budget_and_plays_its_weights(tmp_path):
    pytest.importorskip("mo_gymnasium")
    from hddpg_zoo.benchmark.morl_gpi import GPI_EXTRA_WORKERS, train_gpi
    from hddpg_zoo.benchmark.morl_protocol import GAMMA
    from hddpg_zoo.benchmark.morl_sides import PROTOCOL_METHODS, SideRun, pinned_env, play_front
    from sb3_hddpg.artifacts.manifests import load_workers
    from sb3_hddpg.artifacts.records.support import read_support_record

    assert PROTOCOL_METHODS["hddpg-gpi"].train is train_gpi
    shared, _ = pinned_env("deep-sea-treasure-concave-v0")
    assert shared.env_kwargs["term_bounds"]["obj1"] == [0.0, 1.0]  # time: -1 a step, as raw
    with pytest.raises(ValueError, match="trains no model"):
        train_gpi(SideRun("deep-sea-treasure-concave-v0", True, GAMMA, 19, 0, tmp_path / "none"))
    budget = 6000  # 1200 env steps per worker: past DQN's 1000 learning starts, so that the support grows
    trained = train_gpi(SideRun("deep-sea-treasure-concave-v0", True, GAMMA, budget, 0, tmp_path))
    record = read_support_record(tmp_path / "workers" / "support.json")
    names = list(load_workers(tmp_path))
    assert sorted([*record.start, *(s.name for s in record.added)]) == sorted(names)
    assert record.start == ["obj0", "obj1"] and 1 <= len(record.added) <= GPI_EXTRA_WORKERS
    assert set(trained.env_steps) == {"bounds", *(f"workers/{n}" for n in names)}
    assert all(trained.env_steps[f"workers/{s.name}"] == s.steps for s in record.added)
    assert sum(trained.env_steps.values()) <= budget
    env = trained.env.make()
    try:
        discounted, returns = play_front(
            trained.policy, env, [[1.0, 0.0], [0.5, 0.5], [0.0, 1.0]], 1, 0, GAMMA
        )
    finally:
        env.close()
    assert len(discounted) == 3 and all(len(episodes) == 1 for episodes in returns)
    assert all(r[0][1] <= -1.0 and r[0][0] >= 0.0 for r in returns)  # a step costs 1 time, treasure >= 0
    # Time alone: the coefficient on the time critic (-L) is its weight, with nothing on treasure.
    assert trained.policy.coefficients == pytest.approx({"obj0": 0.0, "obj1": 1.0})


def test_gpi_over_the_per_term_workers_gives_them_the_whole_budget(tmp_path):
    pytest.importorskip("mo_gymnasium")
    from hddpg_zoo.benchmark.morl_gpi import STEP_QUANTUM
    from hddpg_zoo.benchmark.morl_protocol import GAMMA
    from hddpg_zoo.benchmark.morl_sides import PROTOCOL_METHODS, SideRun

    budget = 2402
    trained = PROTOCOL_METHODS["hddpg-gpi-terms"].train(
        SideRun("deep-sea-treasure-concave-v0", True, GAMMA, budget, 0, tmp_path)
    )
    share = budget // 2 // STEP_QUANTUM * STEP_QUANTUM
    assert trained.env_steps == {"workers/obj0": share, "workers/obj1": share, "bounds": 0}
    assert not (tmp_path / "workers" / "support.json").exists()


def test_hddpg_gpi_sac_trains_sac_workers_with_the_continuous_peers_settings(tmp_path):
    pytest.importorskip("mo_gymnasium")
    from stable_baselines3 import SAC

    from hddpg_zoo.benchmark.morl_protocol import GAMMA
    from hddpg_zoo.benchmark.morl_sides import PROTOCOL_METHODS, SideRun, pinned_env
    from sb3_hddpg.artifacts.manifests import load_workers
    from sb3_hddpg.training.config import default_config, load_hyperparams
    from sb3_hddpg.training.workers import train_workers

    for env_id in ("mo-halfcheetah-v4", "mo-hopper-2d-v4"):
        block = load_hyperparams((f"{env_id}/mix", env_id), SAC, default_config("sac"))
        kwargs = block.algo_kwargs
        assert (kwargs["gamma"], kwargs["learning_rate"], kwargs["batch_size"]) == (0.99, 3e-4, 128)
        assert kwargs["policy_kwargs"]["net_arch"] == [256, 256] and kwargs["buffer_size"] == 1_000_000
    trained = PROTOCOL_METHODS["hddpg-gpi-sac"].train(
        SideRun("mo-mountaincarcontinuous-v0", False, GAMMA, 4000, 0, tmp_path)
    )
    assert sum(trained.env_steps.values()) <= 4000
    # A weighted worker added as grow adds one (no algorithm named), whether or not this tiny support grew any.
    shared, _ = pinned_env("mo-mountaincarcontinuous-v0")
    # Not the equal weighting, which grow may take.
    shares = np.arange(1.0, len(shared.terms) + 1)
    weights = dict(zip(shared.terms, (shares / shares.sum()).tolist()))
    train_workers(
        tmp_path,
        [],
        env=shared,
        weights=[weights],
        timesteps=200,
        term_critic=None,
        eval_freq=0,
        eval_episodes=1,
        seed=0,
    )
    workers = load_workers(tmp_path)
    weighted = [name for name in workers if workers.manifest.entries[name].get("reward_weights")]
    assert weighted and len(workers) > len(weighted)
    assert {type(model) for model in workers.models.values()} == {SAC}


def _train(arguments: list[str], checkpoint: Path, out: Path) -> subprocess.CompletedProcess[str]:
    """The protocol runner's ``train`` with MORL-baselines' python, a tiny evaluation, checkpointed."""
    evaluation = ["--eval-weights", "3", "--eval-episodes", "1", "--checkpoint-dir", str(checkpoint)]
    return subprocess.run(
        [
            str(MORL_PYTHON),
            str(PROTOCOL_RUNNER),
            "train",
            *arguments,
            *evaluation,
            "--out",
            str(out),
            "--force",
        ],
        capture_output=True,
        text=True,
        check=False,
        env={**os.environ, "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"},
    )


@needs_morl
@pytest.mark.parametrize(
    ("learner", "chunking"),
    [
        (
            ["--algo", "capql", "--env", "mo-mountaincarcontinuous-v0", "--ref-point=-100,-100"],
            "--chunk-steps",
        ),
        (
            ["--algo", "envelope", "--env", "deep-sea-treasure-concave-v0", "--ref-point=0,-50"],
            "--chunk-steps",
        ),
        (
            ["--algo", "gpi_ls_discrete", "--env", "deep-sea-treasure-concave-v0", "--ref-point=0,-50"],
            "--iteration-steps",
        ),
    ],
)
def test_a_peer_stopped_after_a_chunk_goes_on_from_its_checkpoint(learner, chunking, tmp_path):
    checkpoint, out = tmp_path / "checkpoint", tmp_path / "record.json"
    budget = 200 if chunking == "--iteration-steps" else 300
    arguments = [*learner, "--timesteps", str(budget), chunking, "100", "--seed", "3"]
    stopped = _train([*arguments, "--stop-after-chunks", "1"], checkpoint, out)
    assert stopped.returncode == 3, stopped.stderr[-2000:]
    state = json.loads((checkpoint / "state.json").read_text())
    assert (state["env_steps"], state["chunks"], state["resumes"]) == (100, 1, 0) and not out.exists()
    assert [p.name for p in checkpoint.glob("*.pt")] == ["learner-1.pt"]
    done = _train(arguments, checkpoint, out)
    assert done.returncode == 0, done.stderr[-2000:]
    record = json.loads(out.read_text())
    # The learner's own global_step carried on: the whole budget, in chunks of 100, one resume.
    assert record["env_steps"]["learner"] == budget
    assert (record["chunks"], record["resumes"], record["chunk_steps"]) == (budget // 100, 1, 100)
    # The replay buffer went on too: every step of both processes is in the last checkpoint's.
    read = "import sys, torch; print(len(torch.load(sys.argv[1], weights_only=False)['learner']['replay_buffer']))"
    last = checkpoint / f"learner-{budget // 100}.pt"
    kept = subprocess.run(
        [str(MORL_PYTHON), "-c", read, str(last)], capture_output=True, text=True, check=True
    )
    assert int(kept.stdout.strip().splitlines()[-1]) == budget
    if learner[1] == "gpi_ls_discrete":  # its weight search played the eval env in both processes
        assert record["env_steps"]["evaluations_in_training"] > state["evaluations_in_training"] > 0
    # The checkpoint is of seed 3: a run of seed 4 is refused in one line, and the checkpoint kept.
    other = _train([*learner, "--timesteps", str(budget), chunking, "100", "--seed", "4"], checkpoint, out)
    assert other.returncode == 2 and "Traceback" not in other.stderr
    assert "--checkpoint-dir" in other.stderr.splitlines()[-1] and "seed 3" in other.stderr.splitlines()[-1]
    assert json.loads((checkpoint / "state.json").read_text())["chunks"] == budget // 100


@needs_morl
def test_a_peer_seed_repeats(tmp_path):
    arguments = ["--algo", "capql", "--env", "mo-mountaincarcontinuous-v0", "--ref-point=-100,-100"]
    arguments += ["--timesteps", "300", "--chunk-steps", "100", "--seed", "5"]
    records = []
    for run in ("a", "b"):
        done = _train(arguments, tmp_path / run / "checkpoint", tmp_path / run / "record.json")
        assert done.returncode == 0, done.stderr[-2000:]
        records.append(json.loads((tmp_path / run / "record.json").read_text()))
    assert records[0]["discounted_returns"] == records[1]["discounted_returns"]


@needs_morl
def test_a_protocol_peer_goes_on_from_its_checkpoint_and_deletes_it(tmp_path):
    from hddpg_zoo.benchmark.morl_protocol_run import record_path, run_peer

    settings = ProtocolSettings(
        "deep-sea-treasure-concave-v0",
        (0,),
        peers=("envelope",),
        timesteps=300,
        eval_weights=3,
        eval_episodes=1,
        morl_python=MORL_PYTHON,
    )
    folder, out = tmp_path / "runs" / "envelope" / "seed-0", record_path(tmp_path, "envelope", 0)
    # A run stopped after its (only) chunk, with the arguments run_peer passes.
    learner = [
        "--algo",
        "envelope",
        "--env",
        "deep-sea-treasure-concave-v0",
        "--ref-point=0,-50",
        "--seed",
        "0",
    ]
    stopped = _train([*learner, "--timesteps", "300", "--stop-after-chunks", "1"], folder / "checkpoint", out)
    assert stopped.returncode == 3, stopped.stderr[-2000:]
    run_peer(settings, "envelope", 0, out, folder)
    record = read_protocol_record(out)
    assert record.method == "envelope" and record.total_env_steps == 300
    assert (record.resumes, record.chunk_steps) == (1, 10_000)
    assert not (folder / "checkpoint").exists() and not list(folder.iterdir())


#: Run with MORL-baselines' python: Envelope trained by one ``train`` call and in chunks of 100 steps, from the
#: same seeds; prints the largest difference of their networks' weights and both episode counts.
_CHUNKED_IS_ONE_CALL = """
import importlib.util, json, random, sys, tempfile, types
from pathlib import Path
import mo_gymnasium, numpy as np, torch
from morl_baselines.multi_policy.envelope.envelope import Envelope
spec = importlib.util.spec_from_file_location("resume", sys.argv[1])
resume = importlib.util.module_from_spec(spec); sys.modules["resume"] = resume; spec.loader.exec_module(resume)
def built(wrap):
    random.seed(0); np.random.seed(0); torch.manual_seed(0)
    env = mo_gymnasium.make("deep-sea-treasure-concave-v0"); env.action_space.seed(0); env.reset(seed=0)
    env = resume.Continuing(env) if wrap else env
    agent = Envelope(env, gamma=0.99, seed=0, log=False, device="cpu", learning_starts=50, batch_size=16)
    return agent, env
one, _ = built(False)
evaluation = {"eval_env": types.SimpleNamespace(steps=0), "ref_point": np.array([0.0, -50.0])}
one.train(total_timesteps=300, reset_num_timesteps=False, **evaluation)
chunked, env = built(True)
run = {"algo": "envelope", "env": "dst", "seed": 0, "timesteps": 300, "gamma": 0.99, "chunk_steps": 100}
eval_env, kwargs = evaluation.pop("eval_env"), evaluation
resume.train_in_chunks(chunked, env, eval_env, {**run, "stop_after": None}, Path(tempfile.mkdtemp()), kwargs)
weights = [torch.cat([p.flatten() for p in a.q_net.parameters()]) for a in (one, chunked)]
print(json.dumps({"difference": float((weights[0] - weights[1]).abs().max()),
                  "episodes": [one.num_episodes, chunked.num_episodes], "steps": chunked.global_step}))
"""


@needs_morl
def test_envelope_in_chunks_trains_as_one_train_call():
    resume = PROTOCOL_RUNNER.with_name("morl_protocol_resume.py")
    done = subprocess.run(
        [str(MORL_PYTHON), "-c", _CHUNKED_IS_ONE_CALL, str(resume)],
        capture_output=True,
        text=True,
        check=False,
        env={**os.environ, "WANDB_MODE": "disabled", "OMP_NUM_THREADS": "1"},
    )
    assert done.returncode == 0, done.stderr[-2000:]
    shown = json.loads(done.stdout.strip().splitlines()[-1])
    # Chunk ends fell inside episodes and just after them (DST's episodes are short): the held env and
    # Envelope's kept weight make the chunks one stream of episodes, the same updates to the last bit.
    assert shown["steps"] == 300 and shown["episodes"][0] == shown["episodes"][1] > 10
    assert shown["difference"] == 0.0


def test_an_iterated_learner_whose_train_changed_is_refused():
    from hddpg_zoo.benchmark.morl_protocol_resume import LoopChanged, check_loop_source

    class GPIPD:  # the name MORL-baselines' class has, with a train that is not 1.3.0's
        def train(self, total_timesteps: int) -> None:
            """Another loop."""

    with pytest.raises(LoopChanged, match=r"GPIPD\.train .* re-read it"):
        check_loop_source(GPIPD)


_INSTALLED_LOOPS = """
import importlib.util, sys
spec = importlib.util.spec_from_file_location("resume", sys.argv[1])
resume = importlib.util.module_from_spec(spec); sys.modules["resume"] = resume; spec.loader.exec_module(resume)
from morl_baselines.multi_policy.gpi_pd.gpi_pd import GPILS, GPIPD
from morl_baselines.multi_policy.gpi_pd.gpi_pd_continuous_action import GPIPDContinuousAction
for learner in (GPIPD, GPILS, GPIPDContinuousAction):
    resume.check_loop_source(learner)
print("same loops")
"""


@needs_morl
def test_the_installed_gpi_learners_train_by_the_loop_the_chunks_re_run():
    resume = PROTOCOL_RUNNER.with_name("morl_protocol_resume.py")
    done = subprocess.run(
        [str(MORL_PYTHON), "-c", _INSTALLED_LOOPS, str(resume)], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0 and done.stdout.strip().endswith("same loops"), done.stderr[-2000:]
