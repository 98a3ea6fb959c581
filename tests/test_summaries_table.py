"""The tables the training and evaluation commands print are built in the library, as text the CLI draws."""

from __future__ import annotations

from sb3_hddpg.evaluation import dependence_rows, summaries_table
from sb3_hddpg.metric_labels import MANAGER_REWARD_LABEL


def test_summaries_table_one_row_per_agent_missing_values_as_dashes():
    summaries = {
        "goal": {
            "mean_reward": 1.5,
            "std_reward": 0.5,
            "mean_reach_reward": 1.5,
            "goal_touch_rate": 0.25,
            "action_saturation": 0.1,
        },
        "avoid": {"mean_reward": 2.0, "mean_reach_reward": 2.0},
    }
    table = summaries_table("Workers", summaries)
    assert table.title == "Workers"
    assert len(table.columns) == 3  # the reward (the same as the normalised return here), touches, saturation
    assert table.rows[0][:2] == ("goal", "1.5 ± 0.5")
    assert table.rows[1] == ("avoid", "2.0", "-", "-")
    assert "goal touch" in table.caption


def test_summaries_table_names_the_managers_reward_and_the_normalised_return_apart():
    summary = {
        "mean_reward": 3.0,
        "mean_reach_reward": 1.0,
        "mean_goal_reward": 0.5,
        "mean_avoid_reward": 0.5,
    }
    table = summaries_table("Manager", {"manager": summary}, reward=MANAGER_REWARD_LABEL)
    # The reward, the normalised return, the two terms (no touches reported) and the saturation.
    assert table.columns[:2] == ("manager reward", "norm. return")
    assert len(table.columns) == 5
    assert table.rows[0][1:3] == ("3.0", "1.0")


def test_dependence_rows_say_why_a_share_is_missing():
    figure = {
        "near_clearance": 0.5,
        "clear_clearance": 1.0,
        "near_share": 0.8,
        "near_choices": 10,
        "clear_share": None,
        "clear_choices": 0,
        "ratio": None,
    }
    rows = dependence_rows(figure, "avoid")
    assert [value for _, value, _ in rows] == ["80.0% of 10", "- (0 choices)", "n/a"]
