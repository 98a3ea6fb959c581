"""
Post-hoc, for docs/RESULTS.md ("Is a better switch within reach?"): what can switching between a seed's two workers buy? HAM's
switch over each seed's workers of a benchmark, at every threshold of ``ham-tuned``'s grid (0.25 to the
number of links), on episodes neither the curves nor the test use (seeds 20000..), with the reach reward,
goal touch and contact steps per episode. The best reach reward among thresholds that keep the contacts at
or under a limit says whether "reach >= 350 with <= 2 collisions" is within a state-dependent switch of
these workers.

python studies/switch_frontier.py runs/bench-e20 [--seeds 0 1 2 3 4] [--episodes 20] [--out FILE.json]
"""

import argparse
import json
from pathlib import Path

import gymnasium as gym

from sb3_hddpg.baselines.ham import load_ham
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.evaluation import evaluate

#: Episodes neither the learning curves (10000..) nor the test (15000..) use.
FRONTIER_SEED = 20000
KEYS = ("mean_reach_reward", "goal_touch_rate", "collisions_per_episode")


def frontier(ham_file: Path, episodes: int, seed: int) -> list[dict[str, float]]:
    """Per threshold of the grid: the switch's reach reward, goal touch and contact steps per episode."""
    switch, _ = load_ham(ham_file)
    env = gym.make(SNAKE_REACH_ENV_ID)
    try:
        points = []
        for threshold in switch.threshold_grid():
            switch.threshold = threshold
            summary = evaluate(switch, env, n_episodes=episodes, seed=seed).summary()
            points.append({"threshold": switch.threshold, **{k: float(summary[k]) for k in KEYS}})
    finally:
        env.close()
    return points


def best_within(points: list[dict[str, float]], limit: float) -> dict[str, float] | None:
    """The highest reach reward among the thresholds with at most ``limit`` contact steps per episode."""
    within = [p for p in points if p["collisions_per_episode"] <= limit]
    return max(within, key=lambda p: p["mean_reach_reward"]) if within else None


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("benchmark", type=Path, help="a benchmark folder with each seed's ham/ham.json")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="benchmark seeds")
    parser.add_argument("--episodes", type=int, default=20, help="episodes per threshold")
    parser.add_argument("--limit", type=float, default=2.0, help="contact steps per episode allowed")
    parser.add_argument("--out", type=Path, default=None, help="write every point as JSON here")
    args = parser.parse_args()

    out = {"episodes": args.episodes, "first_episode_seed": FRONTIER_SEED, "limit": args.limit, "seeds": {}}
    for seed in args.seeds:
        points = frontier(args.benchmark / f"seed-{seed}" / "ham" / "ham.json", args.episodes, FRONTIER_SEED)
        best = max(points, key=lambda p: p["mean_reach_reward"])
        within = best_within(points, args.limit)
        out["seeds"][seed] = {"points": points, "best": best, "best_within_limit": within}
        print(
            f"seed {seed}: best {best['mean_reach_reward']:.1f} at threshold {best['threshold']:.2f} "
            f"({best['collisions_per_episode']:.2f} contacts, {100 * best['goal_touch_rate']:.1f} % touch); "
            + (
                f"best with <= {args.limit:g} contacts {within['mean_reach_reward']:.1f} at {within['threshold']:.2f} "
                f"({within['collisions_per_episode']:.2f}, {100 * within['goal_touch_rate']:.1f} % touch)"
                if within
                else f"no threshold keeps <= {args.limit:g} contacts"
            ),
            flush=True,
        )
    if args.out is not None:
        args.out.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
