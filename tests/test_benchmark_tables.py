"""The benchmark's console tables are built by the library from results.json; the CLI only draws them."""

from __future__ import annotations

from hddpg_zoo.benchmark.tables import TextTable, console_tables, wall_time_text
from hddpg_zoo.records import BenchmarkResults


def _stats(mean: float) -> dict[str, float]:
    return {"mean": mean, "ci_low": mean - 1, "ci_high": mean + 1, "iqm": mean}


def _results(with_snake_metrics: bool, **run: object) -> BenchmarkResults:
    """Results as read from a results.json holding only what the tables print."""
    extra = {"goal_touch_rate": _stats(0.4)} if with_snake_metrics else {}
    stats = {"mean_reach_reward": _stats(300.0), "curve_mean": _stats(250.0), "slope": _stats(0.5), **extra}
    value = {
        "test_episode_set": {"name": "development"},
        "test_seeds": [15000],
        "curve_window": 3,
        "slope_unit_steps": 1000,
        "methods": {"hddpg": {"seeds": [0, 1], "stats": stats}},
        "comparisons": {},
        "wall_time_s_this_invocation": 120.0,
        **run,
    }
    return BenchmarkResults.from_json(value, "results.json")


def test_tables_hold_text_cells_and_only_the_metrics_reported():
    tables = console_tables(_results(with_snake_metrics=True))
    assert len(tables) == 1  # no comparisons, no state dependence, no transfer
    (table,) = tables
    assert isinstance(table, TextTable) and table.left == ("method",)
    assert "goal touch" in table.columns
    assert table.rows[0][:3] == ("hddpg", "2", "300.0 [299.0, 301.0]")
    assert all(isinstance(cell, str) for row in table.rows for cell in row)
    assert all(len(row) == len(table.columns) for row in table.rows)
    (plain,) = console_tables(_results(with_snake_metrics=False))
    assert "goal touch" not in plain.columns


def test_wall_time_counts_every_invocation_of_a_resumed_run():
    assert wall_time_text(_results(with_snake_metrics=False)) == "2.0 min"
    resumed = _results(with_snake_metrics=False, invocations=2, wall_time_s_all_invocations=600.0)
    assert wall_time_text(resumed) == "2.0 min (10.0 min over its 2 invocations)"
