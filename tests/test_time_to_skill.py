"""The time-to-skill benchmark script, on a tiny budget: it trains, times, reports ratios; no real measurement."""

from __future__ import annotations

import importlib
import json
import sys
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parent.parent / "benchmarks" / "time_to_skill.py"


def _module():
    # On the path, not only loaded: the script's spawned processes import run_one by the module's name, and
    # they inherit this process's sys.path.
    if str(SCRIPT.parent) not in sys.path:
        sys.path.insert(0, str(SCRIPT.parent))
    return importlib.import_module("time_to_skill")


def test_time_to_skill_is_the_first_evaluation_that_holds():
    tts = _module()
    history = [
        {"timesteps": 100, "goal_touch_rate": 0.6},
        {"timesteps": 200, "goal_touch_rate": 0.4},
        {"timesteps": 300, "goal_touch_rate": 0.5},
        {"timesteps": 400, "goal_touch_rate": 0.7},
    ]
    clock = {100: 1.0, 200: 2.0, 300: 3.0, 400: 4.0}
    assert tts.time_to_skill(history, clock, 0.5, 1) == (100, 1.0)
    assert tts.time_to_skill(history, clock, 0.5, 2) == (300, 3.0)
    assert tts.time_to_skill(history, clock, 0.8, 1) == (None, None)
    assert tts.parse_learners("ddpg:sb3, CrossQ:sb3") == [
        tts.Learner("ddpg", "sb3"),
        tts.Learner("crossq", "sb3"),
    ]
    # A learner of its own config file: its label and folder name the file (or a config.yml's folder).
    config = "docs/results/workers/goal-prior/config.yml"
    (variant,) = tts.parse_learners(f"ddpg:sbx@{config}")
    assert (variant.config, variant.label, variant.folder) == (
        config,
        "ddpg:sbx@goal-prior",
        "ddpg-sbx-goal-prior",
    )
    assert tts.result_label({"algo": "ddpg", "backend": "sbx", "config": config}) == variant.label
    with pytest.raises(ValueError, match="No config file"):
        tts.parse_learners("ddpg:sbx@missing.yml")
    with pytest.raises(ValueError, match="a2c"):
        tts.parse_learners("a2c:sb3")


def test_the_avoid_workers_skill_is_few_contacts_without_saturated_joints():
    tts = _module()
    history = [
        {"timesteps": 1000, "collisions_per_episode": 2.0, "action_saturation": 0.0},
        {"timesteps": 2000, "collisions_per_episode": 0.1, "action_saturation": 0.8},  # clear by saturating
        {"timesteps": 3000, "collisions_per_episode": 0.2, "action_saturation": 0.1},
    ]
    assert tts.time_to_skill(history, {3000: 9.0}, 0.3, 1, "avoid", 0.2) == (3000, 9.0)
    assert tts.time_to_skill(history, {}, 0.3, 1, "avoid", 0.9) == (2000, None)
    assert tts.time_to_skill(history, {}, 0.05, 1, "avoid", 0.9) == (None, None)


def test_a_discrete_workers_evaluation_has_no_saturation_to_fail_or_print():
    tts = _module()
    # Evaluation leaves action_saturation out for a discrete action: no limit can be pinned there.
    entry = {"timesteps": 1000, "collisions_per_episode": 0.1, "goal_touch_rate": 0.0}
    assert tts.has_skill(entry, "avoid", 0.3, 0.2)
    assert not tts.has_skill({**entry, "action_saturation": 0.5}, "avoid", 0.3, 0.2)
    development = {"goal_touch_rate": 0.0, "collisions_per_episode": 0.1}
    results = [
        {
            "algo": "ddpg",
            "backend": "sb3",
            "seed": 0,
            "reached": True,
            "steps": 1000,
            "seconds": 100.0,
            "development": development,
        },
    ]
    table = tts.report(results, [tts.Learner("ddpg", "sb3")], "ddpg:sb3")
    row = next(line for line in table.splitlines() if line.startswith("| ddpg:sb3"))
    assert row.rstrip().endswith("| 0.0% | 0.1 | - |")


def test_report_gives_per_seed_figures_and_ratios_to_the_baseline():
    tts = _module()
    results = [
        {"algo": "ddpg", "backend": "sb3", "seed": s, "reached": True, "steps": 1000, "seconds": 100.0}
        for s in (0, 1)
    ] + [
        {"algo": "crossq", "backend": "sb3", "seed": 0, "reached": True, "steps": 500, "seconds": 80.0},
        {"algo": "crossq", "backend": "sb3", "seed": 1, "reached": False, "steps": 500, "seconds": 80.0},
    ]
    table = tts.report(results, [tts.Learner("ddpg", "sb3"), tts.Learner("crossq", "sb3")], "ddpg:sb3")
    row = next(line for line in table.splitlines() if line.startswith("| crossq:sb3"))
    assert "| 1/2 |" in row and ">500" in row and "| 0.50 | 0.80 |" in row


@pytest.mark.slow  # two tiny training runs in fresh processes: tens of seconds on a shared machine
def test_script_runs_on_a_tiny_budget(tmp_path):
    tts = _module()
    out = tmp_path / "tts"
    argv = ["--learners", "ddpg:sb3,crossq:sb3", "--seeds", "1", "--timesteps", "120", "--eval-freq", "60"]
    argv += ["--eval-episodes", "1", "--development-episodes", "2", "--threshold", "0", "--out", str(out)]
    assert tts.main(argv) == 0
    report = (out / "report.md").read_text()
    assert "| ddpg:sb3 | 1/1 |" in report and "| crossq:sb3 | 1/1 |" in report
    result = json.loads((out / "crossq-sb3" / "seed-0" / "result.json").read_text())
    assert result["development"]["episode_set"] == {"name": "development", "first_seed": 15000, "episodes": 2}
    assert 0.0 <= result["development"]["goal_touch_rate"] <= 1.0
    assert (out / "curves.png").stat().st_size > 0
    # Reporting again trains nothing and gives the same table.
    assert tts.main([*argv, "--report-only"]) == 0
    assert (out / "report.md").read_text() == report


@pytest.mark.slow  # one tiny training run in a fresh process
def test_a_run_stops_once_the_skill_holds(tmp_path):
    tts = _module()
    out = tmp_path / "tts"
    argv = ["--learners", "ddpg:sb3", "--seeds", "1", "--timesteps", "600", "--eval-freq", "60"]
    argv += ["--hold", "2", "--eval-episodes", "1", "--development-episodes", "1", "--threshold", "0"]
    argv += ["--out", str(out)]
    assert tts.main([*argv, "--stop-at-skill"]) == 0
    result = json.loads((out / "ddpg-sb3" / "seed-0" / "result.json").read_text())
    # Every evaluation holds a threshold of 0: the skill holds from the first, and the second ends the run.
    assert result["stopped_at_skill"] and result["reached"] and result["steps"] == 60
    assert [e["timesteps"] for e in result["curve"]][:2] == [60, 120]
    assert len(result["curve"]) <= 3  # the closing evaluation at most, not ten


@pytest.mark.parametrize(
    "study",
    sorted(p.parent.name for p in (SCRIPT.parent.parent / "docs/results/workers").glob("*/report.md")),
)
def test_every_shipped_study_report_regenerates_from_its_records(study):
    tts = _module()
    folder = SCRIPT.parent.parent / "docs" / "results" / "workers" / study
    shipped = (folder / "report.md").read_text()
    lines = shipped.splitlines()
    results = [json.loads(path.read_text()) for path in sorted(folder.glob("*/seed-*/result.json"))]
    labels = {tts.result_label(result): result for result in results}
    # The learners in the report's order; the baseline is named in the header ("steps / BASELINE").
    order = [line.split(" | ")[0].removeprefix("| ") for line in lines[2:]]
    learners = [tts.Learner(labels[o]["algo"], labels[o]["backend"], labels[o].get("config")) for o in order]
    baseline = lines[0].split("steps / ")[1].split(" |")[0]
    assert tts.report(results, learners, baseline) + "\n" == shipped


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--baseline", "ddpg:sbx,sac:sbx", "--baseline takes one learner, got 2"),
        ("--baseline", "ddpg:nope", "--baseline: Expected a backend"),
        ("--learners", "ddpg:sbx@missing.yml", "--learners: No config file"),
    ],
)
def test_bad_learner_options_are_one_line_usage_errors(option, value, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        _module().main([option, value])
    assert exit_info.value.code == 2
    assert message in capsys.readouterr().err
