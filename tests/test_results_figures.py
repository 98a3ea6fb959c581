"""The transfer ratio to a common target, highway's crashes and its curve-to-test figures, from the shipped records."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hddpg_zoo.benchmark.episodes import seed_metrics
from hddpg_zoo.benchmark.front_statistics import CRASH_PLANE, crash_plane, with_crash_rate
from hddpg_zoo.benchmark.statistics import censored_ratio, steps_to_fraction

ROOT = Path(__file__).resolve().parents[1]


def curve(*scores: float, every: int = 1000) -> list[dict]:
    return [{"timesteps": every * (i + 1), "score": s} for i, s in enumerate(scores)]


def test_a_run_that_never_reaches_the_common_target_is_censored_and_cannot_win():
    # The manager ends lower (60) than the flat agent (100): 90 % of the way to 100 is 90, which it never
    # reaches. By its own final score it was "there" at once; to the common target it is censored.
    manager, flat = curve(60, 60, 60), curve(10, 50, 95, 100, every=2000)

    def score(point: dict) -> float:
        return point["score"]

    assert steps_to_fraction(manager, score) == 1000  # the old definition: a 8x "win"
    target = max(manager[-1]["score"], flat[-1]["score"])
    hit_m = steps_to_fraction(manager, score, final=target)
    hit_f = steps_to_fraction(flat, score, final=target)
    assert (hit_m, hit_f) == (None, 6000)
    result = censored_ratio(hit_m, hit_f, manager, flat)
    # At most 6000 / 3000: the manager did not get there within its 3000 steps.
    assert result == {
        "manager_steps_to_target": None,
        "flat_steps_to_target": 6000,
        "ratio_to_target": 2.0,
        "censored": "manager",
    }
    assert censored_ratio(1000, None, manager, flat)["censored"] == "flat"
    assert censored_ratio(None, None, manager, flat)["ratio_to_target"] is None


@pytest.fixture(scope="module")
def transfer():
    from hddpg_zoo.benchmark.pages import run_results

    return run_results(ROOT / "docs" / "results" / "transfer-record")


def test_the_shipped_transfer_replays_to_the_text(transfer):
    pairings = [c for entry in transfer.transfer["preferences"].values() for c in entry.values()]
    seeds = [v for c in pairings for v in c["per_seed"].values()]
    assert len(seeds) == 40
    sooner = sum(v["ratio_to_target"] > 1 and v["censored"] in ("none", "flat") for v in seeds)
    ties = sum(v["ratio_to_target"] == 1 and v["censored"] == "none" for v in seeds)
    assert (sooner, ties) == (39, 1)
    # Every seed's target is 90 % of the way to the better final score: no run wins by reaching a lower own one.
    for v in seeds:
        best = max(v["manager_final_score"], v["flat_final_score"])
        assert v["target_score"] == pytest.approx(v["random_score"] + 0.9 * (best - v["random_score"]))
    seed_6 = transfer.transfer["preferences"]["goal=2,avoid=1"]["ddpg"]["per_seed"]["6"]
    assert seed_6["manager_final_score"] < seed_6["flat_final_score"]
    assert (seed_6["manager_steps_to_target"], seed_6["flat_steps_to_target"]) == (4000, 200000)


# ------------------------------------------------------------------------------------------------ highway
def test_the_crash_rate_counts_episodes_that_end_in_a_crash():
    rows = [{"reach_reward": 1.0, "raw:collision": c} for c in (-1.0, 0.0, 0.0, -1.0)]
    assert seed_metrics(rows)["crash_rate"] == 0.5
    assert "crash_rate" not in seed_metrics([{"reach_reward": 1.0}])


@pytest.fixture(scope="module")
def highway():
    from hddpg_zoo.benchmark.pages import run_results

    return run_results(ROOT / "docs" / "results" / "highway")


def test_highway_crashes_and_the_outcome_plane(highway):
    crash = {m: e.stats["crash_rate"]["mean"] for m, e in highway.methods.items()}
    assert crash["hddpg-front"] == pytest.approx(0.79, abs=0.01)
    assert crash["term3-only"] < crash["term2-only"] < crash["dqn"] < crash["hddpg-front"]
    front = highway.front
    assert front["planes"][CRASH_PLANE] == [["speed_return", True], ["crash_rate", False]]
    assert front["references"][CRASH_PLANE] == [0.0, 1.0]
    points = front["points"]["0"]["conditioned"]
    assert all(p["crash_rate"] == -p["collision_return"] for p in points)
    assert all(0.0 <= p["crash_rate"] <= 1.0 for p in points)
    # The collision term's per-step value hides what the plane shows: near 1 for every member.
    assert all(p["collision_term"] > 0.9 for p in points)
    assert crash_plane({"front": {}}) is None
    assert with_crash_rate({"collision_return": -0.25})["crash_rate"] == 0.25


def test_highway_curve_figures_are_the_tests_metric(highway):
    manager = highway.methods["hddpg-front"].per_seed
    best = [manager[str(s)]["best_curve_reward"] for s in range(5)]
    drops = [manager[str(s)]["best_curve_reward"] - manager[str(s)]["mean_reach_reward"] for s in range(5)]
    # The normalised return, not the curve's mean_reward (60 to 67 for this manager).
    assert min(best) == pytest.approx(53.0, abs=0.05) and max(best) == pytest.approx(59.4, abs=0.05)
    assert np.round(drops, 1).tolist() == [24.7, 25.0, 17.9, 17.9, 6.5]
