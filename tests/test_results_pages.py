"""The docs' result tables regenerate from the shipped records; per-episode records make the per-seed figures."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hddpg_zoo.benchmark import BenchmarkSettings, compute_results
from hddpg_zoo.benchmark.episodes import (
    read_episodes_csv,
    records_episode_rows,
    seed_metrics,
    write_episodes_csv,
)
from hddpg_zoo.benchmark.pages import (
    BLOCK,
    README_END,
    README_START,
    load_run,
    render_page,
    render_readme,
    update_pages,
)
from sb3_hddpg.artifacts.io import atomic_write_json
from sb3_hddpg.episode_sets import FINAL_TEST, FINAL_TEST_EPISODES

ROOT = Path(__file__).resolve().parents[1]
RESULTS_PAGE = ROOT / "docs" / "RESULTS.md"
#: The pages with tables generated from shipped records: the snake arm's, the other envs', the support's.
GENERATED_PAGES = (RESULTS_PAGE, ROOT / "docs" / "ENVIRONMENTS.md", ROOT / "docs" / "guide" / "support.md")


def shipped_runs(page: Path = RESULTS_PAGE) -> list[str]:
    """The benchmark folders whose tables ``page`` holds."""
    keys = {m.group("key").split("/")[0] for m in BLOCK.finditer(page.read_text())}
    return sorted(keys)


def test_results_page_has_generated_tables_of_the_shipped_runs():
    assert "record" in shipped_runs()
    assert "highway-dev-horizon" in shipped_runs(GENERATED_PAGES[1])


@pytest.mark.parametrize(
    ("page", "run"), [(page, run) for page in GENERATED_PAGES for run in shipped_runs(page)]
)
def test_shipped_tables_regenerate_exactly_from_the_shipped_records(page, run):
    readme = ROOT / "README.md" if run == "record" else None
    # A run on an env whose optional package `make` leaves out (highway-env) is read without making it.
    outcome = update_pages(ROOT / "docs" / "results" / run, page, readme, check=True)
    assert outcome["written"], f"no generated table of {run} in {page.name}"
    assert outcome["changed"] == [], f"run `hddpg-cli report docs/results/{run} --page docs/{page.name}`"


# ------------------------------------------------------------------------------------------ constructed run
def episode_record(method: str, seed: int, rewards: list[float], collisions: list[int]) -> dict:
    """A finished run's record with its test episodes on the final test set."""
    episodes = [
        {
            "episode_seed": FINAL_TEST.first_seed + k,
            "reward": r,
            "reach_reward": r,
            "length": 200.0,
            "collisions": float(c),
            "raw:goal": -40.0,
            "norm:goal": r / 2,
            "action_saturation": 0.25 if method == "ddpg" else 1.0,
        }
        for k, (r, c) in enumerate(zip(rewards, collisions, strict=True))
    ]
    history = [
        {"timesteps": 1000 * i, "total_timesteps": 1000 * i, "mean_reach_reward": 200.0 + i} for i in (1, 2)
    ]
    return {
        "method": method,
        "seed": seed,
        "status": "done",
        "worker_timesteps": 0,
        "history": history,
        "test": {"episodes": len(rewards), "mean_reach_reward": float(np.mean(rewards))},
        "episodes": episodes,
        "test_episode_set": FINAL_TEST.describe(len(rewards)),
    }


@pytest.fixture
def final_run(tmp_path):
    settings = BenchmarkSettings(methods=["hddpg", "ddpg"], seeds=[0, 1, 2], timesteps=2000, final_test=True)
    assert settings.test_episodes == FINAL_TEST_EPISODES and settings.test_set is FINAL_TEST
    rng = np.random.default_rng(0)
    records = []
    for seed in settings.seeds:
        for method, level in (("hddpg", 300.0), ("ddpg", 280.0)):
            rewards = (level + rng.normal(0, 5, FINAL_TEST_EPISODES)).round(3).tolist()
            records.append(
                episode_record(method, seed, rewards, rng.integers(0, 4, FINAL_TEST_EPISODES).tolist())
            )
    run = tmp_path / "final-run"
    atomic_write_json(run / "benchmark.json", {"settings": {**settings.__dict__}})
    for record in records:
        atomic_write_json(run / "records" / record["method"] / f"seed-{record['seed']}.json", record)
    return run, settings, records


def test_results_are_derived_from_the_episodes(final_run):
    run, settings, records = final_run
    results = compute_results(settings, records)
    first = next(r for r in records if r["method"] == "hddpg" and r["seed"] == 0)
    per_seed = results["methods"]["hddpg"]["per_seed"]["0"]
    assert per_seed["mean_reach_reward"] == pytest.approx(
        np.mean([e["reach_reward"] for e in first["episodes"]])
    )
    assert per_seed["collisions_per_episode"] == pytest.approx(
        np.mean([e["collisions"] for e in first["episodes"]])
    )
    assert per_seed["goal_reach_reward"] == pytest.approx(
        np.mean([e["norm:goal"] for e in first["episodes"]])
    )
    assert results["test_episode_set"] == {"name": "final-test", "first_seed": 900_000, "episodes": 100}
    assert results["test_seeds"] == [900_000, 900_099]
    aggregate = results["aggregates"]
    # The seed is the unit: one task (the env), each cell a seed's mean over its episodes; the episodes'
    # spread is a separate figure.
    assert aggregate["unit"] == "seed" and aggregate["tasks"] == 1
    seed_means = [
        results["methods"]["hddpg"]["per_seed"][str(s)]["mean_reach_reward"] for s in settings.seeds
    ]
    assert aggregate["intervals"]["hddpg"]["mean"]["value"] == pytest.approx(np.mean(seed_means))
    assert aggregate["episode_spread"]["hddpg"] == pytest.approx(
        np.sqrt(np.mean([np.var([e["reach_reward"] for e in r["episodes"]], ddof=1) for r in records[::2]]))
    )
    assert aggregate["probability_of_improvement"]["hddpg vs ddpg"]["value"] > 0.9

    # episodes.csv holds every row, and reading it back gives the same per-seed figures.
    path = write_episodes_csv(run / "episodes.csv", records_episode_rows(records))
    rows = read_episodes_csv(path)
    assert len(rows) == 6 * FINAL_TEST_EPISODES and rows[0]["episode_set"] == "final-test"
    shipped = [r for r in rows if r["method"] == "hddpg" and r["seed"] == 0]
    assert seed_metrics(shipped) == pytest.approx(seed_metrics(first["episodes"]))
    _, loaded = load_run(run)
    assert compute_results(settings, loaded)["methods"] == results["methods"]


def test_a_run_never_mixes_episode_sets(final_run):
    _, settings, records = final_run
    development = BenchmarkSettings(methods=["hddpg", "ddpg"], seeds=[0, 1, 2], timesteps=2000)
    with pytest.raises(ValueError, match="one benchmark folder holds one test episode set"):
        compute_results(development, records)
    # A record from before episode sets were recorded counts as 20 development episodes.
    old = {**records[0], "test": {"episodes": 20, "mean_reach_reward": 1.0}}
    del old["test_episode_set"], old["episodes"]
    with pytest.raises(ValueError, match="'development'"):
        compute_results(settings, [old, *records[1:]])


def test_bad_episodes_csv_is_refused_with_the_line(tmp_path):
    path = tmp_path / "episodes.csv"
    path.write_text("method,seed,episode_set,episode_seed,reach_reward\nhddpg,0,final-test,900000,nan\n")
    with pytest.raises(
        ValueError, match=r"episodes.csv:2: expected a finite number in column 'reach_reward'"
    ):
        read_episodes_csv(path)
    path.write_text("method,seed\nhddpg,0\n")
    with pytest.raises(ValueError, match="missing"):
        read_episodes_csv(path)


def test_pages_rewrite_only_their_own_blocks(final_run):
    run, settings, records = final_run
    results = compute_results(settings, records)
    page = (
        "intro\n<!-- generated:final-run/per-seed-reach -->\nold\n<!-- /generated:final-run/per-seed-reach -->\n"
        "<!-- generated:other/methods -->\nkept\n<!-- /generated:other/methods -->\n"
    )
    text, written = render_page(page, "final-run", results)
    assert written == ["per-seed-reach"] and "old" not in text and "kept" in text
    assert re.search(r"\| `hddpg` \| 30\d\.\d \|", text)
    assert render_page(text, "final-run", results)[0] == text  # regenerating changes nothing
    saturation = (
        "<!-- generated:final-run/per-seed-saturation -->\n<!-- /generated:final-run/per-seed-saturation -->"
    )
    assert "| `ddpg` | 25.0 | 25.0 | 25.0 |" in render_page(saturation, "final-run", results)[0]
    with pytest.raises(ValueError, match="Unknown generated table 'nope'"):
        render_page(
            "<!-- generated:final-run/nope -->\n<!-- /generated:final-run/nope -->", "final-run", results
        )
    readme = f"a\n{README_START}\nold sentence\n{README_END}\nb"
    new = render_readme(readme, "new sentence")
    assert (
        "new sentence" in new and "old sentence" not in new and new.startswith("a\n") and new.endswith("\nb")
    )
    assert render_readme("no markers", "x") == "no markers"


def test_the_readme_sentence_gives_every_challenger_its_verdicts(final_run):
    from hddpg_zoo.benchmark.page_blocks import results_sentence

    _, settings, records = final_run
    sentence = results_sentence(compute_results(settings, records), "final-run")
    assert sentence.startswith(
        "On the 3-seed benchmark `final-run` (100 final-test episodes per model; reach reward"
    )
    assert re.search(
        r"`hddpg` scores 30\d\.\d: ahead of `ddpg` \(2[78]\d\.\d; \+\d+\.\d \[\+\d+\.\d, \+\d+\.\d\]\)\.$",
        sentence,
    )
    # A run whose hierarchy is another challenger than `hddpg` (another env's, say) has its sentence too.
    renamed = [{**r, "method": "hddpg-sac"} if r["method"] == "hddpg" else r for r in records]
    other = BenchmarkSettings(methods=["hddpg-sac", "ddpg"], seeds=[0, 1, 2], timesteps=2000, final_test=True)
    sentence = results_sentence(compute_results(other, renamed), "final-run")
    assert "`hddpg-sac` scores" in sentence and "`hddpg` scores" not in sentence
    flat = BenchmarkSettings(methods=["ddpg"], seeds=[0, 1, 2], timesteps=2000, final_test=True)
    with pytest.raises(ValueError, match="no method of this benchmark is compared"):
        results_sentence(compute_results(flat, [r for r in records if r["method"] == "ddpg"]), "final-run")


def test_resuming_a_development_folder_as_a_final_run_is_refused(tmp_path):
    from dataclasses import asdict

    from hddpg_zoo.benchmark import run_benchmark

    development = BenchmarkSettings(methods=["ham"], seeds=[0], timesteps=1000, worker_timesteps=100)
    out = tmp_path / "bench"
    atomic_write_json(out / "benchmark.json", {"settings": asdict(development)})
    final = BenchmarkSettings(
        methods=["ham"], seeds=[0], timesteps=1000, worker_timesteps=100, final_test=True
    )
    with pytest.raises(ValueError, match="final_test"):
        run_benchmark(final, out, resume=True)
    assert not (out / "records").exists()  # refused before anything ran


def test_the_headline_figures_are_drawn_from_the_records(final_run):
    from hddpg_zoo.benchmark.pages import draw_headline_figures

    run, _, _ = final_run
    paths = draw_headline_figures(run)
    assert [p.name for p in paths] == ["aggregates.png", "performance_profile.png"]
    assert all(p.stat().st_size > 0 for p in paths)


def test_report_rewrites_a_shipped_runs_own_results_from_its_records(tmp_path):
    import shutil

    from hddpg_zoo.benchmark.pages import run_results
    from hddpg_zoo.benchmark.report import markdown_report
    from tests.cli_runner import run_cli

    run = tmp_path / "bench-e20"
    shutil.copytree(ROOT / "docs" / "results" / "bench-e20", run)
    records = {p: p.read_bytes() for p in (run / "records").rglob("*.json")}
    (tmp_path / "page.md").write_text("no generated block\n")
    result = run_cli("report", run, "--page", tmp_path / "page.md", "--results", check=True)
    assert "results.json" in result.stdout
    written = json.loads((run / "results.json").read_text())
    assert written == json.loads(json.dumps(run_results(run).to_json()))
    assert (run / "results.md").read_text() == markdown_report(run_results(run))
    # The records the results come from are left as they were.
    assert {p: p.read_bytes() for p in (run / "records").rglob("*.json")} == records


def test_gpi_at_the_equal_weighting_is_compared_with_each_worker_alone():
    from hddpg_zoo.benchmark.front_pages import _equal_weight_lines, _term_weights

    # A weighted worker's share splits over its terms: 0.6 + 1.8 * 0.5 on each term is the equal weighting.
    assert _term_weights("goal=0.6,avoid=0.6,mix-goal50-avoid50=1.8", ["goal", "avoid"]) == {
        "goal": 1.5,
        "avoid": 1.5,
    }
    assert _term_weights("goal=1,other=1", ["goal", "avoid"]) is None
    assert _term_weights("goal=1,mix-goal0-avoid0=1", ["goal", "avoid"]) is None
    # A weighting's percentages are its share of the worker's reward, as the manager's reward takes them.
    assert _term_weights("mix-goal70-avoid30=2", ["goal", "avoid"]) == pytest.approx(
        {"goal": 1.4, "avoid": 0.6}
    )

    def point(label, goal, avoid):
        return {"label": label, "goal_term": goal, "avoid_term": avoid, "mean_reach_reward": 300 + goal}

    points = {
        str(seed): {
            "gpi": [
                point("goal=2.4,avoid=0.57,mix-goal50-avoid50=0.03", 9.0, 9.0),  # not equal: left out
                point("goal=0.6,avoid=0.6,mix-goal50-avoid50=1.8", 0.8 - 0.01 * seed, 0.9),
            ],
            "goal": [point("goal", 0.9, 0.92)],
            "avoid": [point("avoid", 0.3, 0.99)],
        }
        for seed in range(4)
    }
    front = {"planes": {"terms": [["goal_term", True], ["avoid_term", True]]}, "points": points}
    lines = _equal_weight_lines(front)
    by_comparison = {line.split(":")[0]: line for line in lines if line.startswith("- gpi vs")}
    terms_vs_goal = by_comparison["- gpi vs goal (normalised terms a step, summed)"]
    assert terms_vs_goal.split("; ")[0].endswith("behind") and "difference -0.135 " in terms_vs_goal
    assert "difference -0.115 " in by_comparison["- gpi vs goal (reach reward)"]
    assert by_comparison["- gpi vs avoid (normalised terms a step, summed)"].split("; ")[0].endswith("ahead")
    # A seed without a worker alone is left out of the pairs.
    del points["0"]["goal"]
    by_comparison = {
        line.split(":")[0]: line for line in _equal_weight_lines(front) if line.startswith("- gpi")
    }
    assert "difference -0.14 " in by_comparison["- gpi vs goal (normalised terms a step, summed)"]


def test_a_front_sets_its_workers_benchmarks_flat_runs_beside_its_equal_weighting(tmp_path):
    import shutil

    from hddpg_zoo.benchmark.front_pages import _equal_weight_lines
    from hddpg_zoo.benchmark.workers_source import copy_flat_runs

    shipped = Path(__file__).parent.parent / "docs" / "results" / "highway" / "records"
    source = tmp_path / "source"
    for method, seed in (("dqn", 0), ("dqn", 1), ("term2-only", 0)):
        (source / "records" / method).mkdir(parents=True, exist_ok=True)
        shutil.copy(shipped / method / f"seed-{seed}.json", source / "records" / method / f"seed-{seed}.json")

    def front(**kwargs):
        kwargs = {"seeds": [0, 1, 2], "final_test": True, "test_episodes": 100, **kwargs}
        return BenchmarkSettings(
            methods=["hddpg-support"], scenario="front", workers_from=str(source), **kwargs
        )

    out = tmp_path / "front"
    # Only flat agents (a worker alone is a member of the front already), only on the same test episodes.
    assert copy_flat_runs(front(final_test=False, test_episodes=20), out) == []
    assert copy_flat_runs(replace(front(), scenario="standard"), out) == []
    copied = copy_flat_runs(front(), out)
    assert [(r["method"], r["seed"]) for r in copied] == [("dqn", 0), ("dqn", 1)]
    assert not (out / "records" / "term2-only").exists()
    record = json.loads((out / "records" / "dqn" / "seed-1.json").read_text())
    assert record["copied_from"] == "../source/records/dqn/seed-1.json"
    assert record["episodes"] == json.loads((shipped / "dqn" / "seed-1.json").read_text())["episodes"]

    def point(label, reach):
        return {"label": label, "speed_term": 0.5, "lane_term": 0.5, "mean_reach_reward": reach}

    reach = {"0": 60.0, "1": 50.0, "2": 70.0}
    points = {
        seed: {
            "gpi": [point("speed=1,lane=1", value)],
            "speed": [point("speed", value - 1)],
            "lane": [point("lane", value - 2)],
        }
        for seed, value in reach.items()
    }
    flat = {
        seed: {"mean_reach_reward": value, "env_steps": 130_000.0}
        for seed, value in (("0", 55.0), ("1", 56.0))
    }
    results = {
        "planes": {"terms": [["speed_term", True], ["lane_term", True]]},
        "points": points,
        "flat": {"dqn": flat},
    }
    line = next(line for line in _equal_weight_lines(results) if line.startswith("- gpi vs dqn"))
    # Paired over the two seeds both have: (60 - 55 + 50 - 56) / 2.
    assert line.startswith(
        "- gpi vs dqn (reach reward; dqn of the workers' benchmark, 130,000 env steps a seed)"
    )
    assert "difference -0.5 " in line
    # Its models stay in the benchmark it came from: an export of the front does not look for them.
    from hddpg_zoo.model_export import run_models

    assert run_models(out, out / "records" / "dqn" / "seed-1.json") == []


def test_a_front_with_copied_flat_runs_writes_every_output(tmp_path):
    import shutil

    from hddpg_zoo.benchmark.pages import load_run
    from hddpg_zoo.benchmark.report import write_outputs

    run = tmp_path / "highway-support-record"
    shutil.copytree(ROOT / "docs" / "results" / "highway-support-record", run)
    settings, records = load_run(run)
    assert {r["method"] for r in records} == {"workers", "hddpg-support", "dqn"}
    results = write_outputs(run, compute_results(settings, records), records)
    # The copies stand beside the front's point only: no method row, aggregate or figure of their own.
    assert set(results.methods) == {"hddpg-support"} and "dqn" in results.front["flat"]
    assert (run / "aggregates.png").is_file() and (run / "performance_profile.png").is_file()
