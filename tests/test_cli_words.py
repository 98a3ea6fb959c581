"""Words that fit the env: one name for the normalised return, snake metrics only where reported, 80 columns."""

from __future__ import annotations

from types import SimpleNamespace

from rich.console import Console

from hddpg_zoo.cli.quickstart import comparison_table
from sb3_hddpg.cli.train import metrics_table
from sb3_hddpg.envs.terms_env import adapted_env_id
from sb3_hddpg.evaluation import EvaluationSummary
from sb3_hddpg.metric_labels import MANAGER_REWARD_LABEL, summary_rows
from tests.cli_runner import run_cli

SNAKE = {
    "episodes": 2,
    "mean_reward": -105.93,
    "std_reward": 12.31,
    "mean_reach_reward": 294.4,
    "std_reach_reward": 3.2,
    "goal_touch_rate": 0.031,
    "collisions_per_episode": 3.5,
    "success_rate": 0.2,
    "min_clearance": 0.258,
    "action_saturation": 0.4,
    "selection_rate": {"avoid": 0.31, "goal": 0.69},
}
TERMS = {
    "episodes": 2,
    "mean_reward": 1886.8,
    "std_reward": 0.1,
    "mean_reach_reward": 1886.8,
    "mean_time_reward": -30.0,
    "mean_fuel_reward": -0.6,
    "mean_speed_reward": 5.6,
    "action_saturation": 0.0,
}


def _render(table) -> list[str]:
    console = Console(width=80, record=True, file=open("/dev/null", "w"))  # noqa: SIM115
    console.print(table)
    return console.export_text().splitlines()


def _fits(lines: list[str]) -> None:
    assert all(len(line) <= 80 for line in lines), "\n".join(lines)
    assert not any("…" in line for line in lines), "\n".join(lines)


def test_training_tables_fit_80_columns_and_show_snake_metrics_only_where_reported():
    workers = _render(metrics_table("Workers", {"goal": SNAKE, "avoid": SNAKE}))
    _fits(workers)
    assert any("goal touch" in line for line in workers)
    manager = _render(metrics_table("Manager", {"manager": TERMS}, reward=MANAGER_REWARD_LABEL))
    _fits(manager)
    text = "\n".join(manager)
    assert "goal touch" not in text and "contact" not in text
    # The manager's own reward is named as such; here it is the normalised return, shown once.
    assert "manager reward = norm. return" in " ".join(text.split()), text


def test_the_quickstart_table_fits_80_columns_with_its_budget_in_env_steps():
    methods = {name: {"train_timesteps": 30_016} for name in ("HDDPG", "HAM", "flat DDPG")}
    result = SimpleNamespace(summaries=dict.fromkeys(methods, SNAKE), methods=methods)
    lines = _render(comparison_table(result))  # type: ignore[arg-type]
    _fits(lines)
    assert "env steps: trained" in " ".join(" ".join(lines).split())


def test_a_summary_shows_the_reward_and_the_normalised_return_once_when_they_are_one_number():
    rows = [quantity for quantity, _, _ in summary_rows(TERMS)]
    assert rows.count("reward (the env's own) = return (normalised terms)") == 1
    assert not any(q == "return (normalised terms)" for q in rows)
    shown = str(EvaluationSummary(TERMS))
    assert "mean_reward" not in shown and shown.count("1886.8") == 1


def test_headers_name_the_adapted_env():
    assert adapted_env_id("hddpg/MultiObjective-v0", {"env_id": "mo-hopper-v5"}) == "mo-hopper-v5"
    assert adapted_env_id("hddpg/SnakeReach-v0", {}) == "hddpg/SnakeReach-v0"


def test_help_texts_say_what_is_snake_only_and_give_one_default():
    helps = {
        command: run_cli(command, "--help", check=True).stdout
        for command in ("evaluate", "train-manager", "benchmark")
    }
    for command, text in helps.items():
        assert "only where the env reports them" in " ".join(text.split()), command
    evaluate = helps["evaluate"]
    assert "Usage: hddpg-cli evaluate [OPTIONS] PATH" in evaluate and "{path}" not in evaluate
    env_help = " ".join(evaluate.split("--env", 1)[1].split("--terms", 1)[0].split())
    assert env_help.lower().count("default") == 1, env_help
    assert "sb3-hddpg[" not in evaluate
    assert "budget in decisions" in " ".join(helps["train-manager"].split())
