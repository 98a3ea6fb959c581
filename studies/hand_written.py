"""
What hand-written skills score on the snake arm (docs/WORKERS.md, "The hand-written skills"): the
damped-least-squares IK reacher, the potential-field avoider, and HAM's switch over the two at every
threshold of ``ham-tuned``'s grid, on the combined task. Nothing trains: these are the bars a learned worker
and a learned hierarchy are held to, and a user's alternative to both where the kinematics are known.

    python studies/hand_written.py [--episodes 20] [--out docs/results/hand_written]

Each policy runs on the development episodes (never the final test set); the switch's threshold is picked on
the learning-curve episodes as ``ham-tuned`` picks it. Writes ``hand_written.json`` (every policy's summary)
and ``report.md`` (the table) into ``--out``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import gymnasium as gym

import sb3_hddpg  # noqa: F401  (registers the env ids)
from sb3_hddpg.artifacts.io import atomic_write_json
from sb3_hddpg.baselines import HAMSwitch
from sb3_hddpg.envs.snake.controllers import make_controller
from sb3_hddpg.episode_sets import CURVE, DEVELOPMENT
from sb3_hddpg.evaluation import evaluate

REACH_ENV_ID = "hddpg/SnakeReach-v0"
#: The columns of the report, each a key of an evaluation summary.
COLUMNS = ("mean_reach_reward", "goal_touch_rate", "collisions_per_episode", "action_saturation")


def measure(episodes: int) -> dict[str, object]:
    """Every policy's development summary, and the switch's threshold picked on the curve episodes."""
    env = gym.make(REACH_ENV_ID)
    try:
        layout = env.unwrapped.state_layout  # type: ignore[attr-defined]
        speed = float(env.unwrapped.max_joint_speed)  # type: ignore[attr-defined]
        ik, field = make_controller("ik", layout, speed), make_controller("field", layout, speed)
        switch = HAMSwitch(ik, field, layout)
        grid = switch.threshold_grid()
        curve, development = {}, {}
        for threshold in grid:
            switch.threshold = threshold
            curve[threshold] = evaluate(switch, env, n_episodes=episodes, seed=CURVE.first_seed).summary()
            development[threshold] = evaluate(
                switch, env, n_episodes=episodes, seed=DEVELOPMENT.first_seed
            ).summary()
        picked = max(grid, key=lambda t: curve[t]["mean_reward"])
        return {
            "episodes": {"curve": CURVE.describe(episodes), "development": DEVELOPMENT.describe(episodes)},
            "ik": evaluate(ik, env, n_episodes=episodes, seed=DEVELOPMENT.first_seed).summary(),
            "field": evaluate(field, env, n_episodes=episodes, seed=DEVELOPMENT.first_seed).summary(),
            "switch_threshold": picked,
            "switch": [{"threshold": t, **development[t]} for t in grid],
        }
    finally:
        env.close()


def report(record: dict[str, object]) -> str:
    """The Markdown table: each controller alone, the picked switch, then the switch's whole sweep."""
    header = "| policy | reach reward | goal touch | contacts / episode | saturated outputs |"
    rows = [header, "|---|---|---|---|---|"]

    def row(name: str, summary: dict[str, float]) -> str:
        reach, touch, contacts, saturated = (summary[c] for c in COLUMNS)
        return f"| {name} | {reach:.1f} | {touch:.1%} | {contacts:.2f} | {saturated:.1%} |"

    sweep: list[dict[str, float]] = record["switch"]  # type: ignore[assignment]
    picked = record["switch_threshold"]
    rows.append(row("IK reacher alone", record["ik"]))  # type: ignore[arg-type]
    rows.append(row("field avoider alone", record["field"]))  # type: ignore[arg-type]
    for point in sweep:
        mark = " (picked on the curve episodes)" if point["threshold"] == picked else ""
        rows.append(row(f"switch at {point['threshold']:g}{mark}", point))
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--episodes", type=int, default=20, help="Episodes per policy and episode set.")
    parser.add_argument("--out", default="runs/hand_written", help="Folder for the record and the report.")
    args = parser.parse_args(argv)
    if not 1 <= args.episodes <= 1000:
        parser.error(f"--episodes must be in [1, 1000], got {args.episodes}")
    record = measure(args.episodes)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out / "hand_written.json", record)
    table = report(record)
    (out / "report.md").write_text(table + "\n")
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
