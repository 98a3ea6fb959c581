"""
Post-hoc, for docs/MANAGER.md: when does a hierarchy call its avoid worker? Its share of the choices by the
nearest obstacle's clearance and by the goal distance of the state it decided in, on the benchmark's 20
test episodes, with the collision and goal-touch rate of the step that followed. The state-dependence
figure (``evaluate``) splits the choices into two bands only; this shows where inside them the manager acts.

python studies/selection_by_state.py NAME=BUNDLE [NAME=BUNDLE ...] [--out FILE.json]
"""

import argparse
import itertools
import json
from pathlib import Path

import gymnasium as gym
import numpy as np

from sb3_hddpg.episode_sets import DEVELOPMENT
from sb3_hddpg.hierarchy.hierarchy import Hierarchy

#: Band edges: clearance (negative = in contact; the sensor range is 0.3) and tip-to-goal distance.
BANDS = {
    "clearance": [-np.inf, 0.0, 0.05, 0.1, 0.15, 0.2, 0.3, np.inf],
    "goal_distance": [0.0, 0.05, 0.1, 0.2, 0.4, np.inf],
}
EPISODES = 20


def steps_of(bundle: str) -> np.ndarray:
    """Per step: clearance and goal distance before the decision, avoid chosen, collision, goal touched."""
    hierarchy = Hierarchy.load(bundle)
    env = gym.make(hierarchy.env_id, **hierarchy.env_kwargs)
    rows = []
    for k in range(EPISODES):
        obs, info = env.reset(seed=DEVELOPMENT.first_seed + k)
        done = False
        while not done:
            before = (info["min_clearance"], info["distance_to_goal"])
            action, _ = hierarchy.predict(obs, deterministic=True)
            avoid = hierarchy.last_selection == "avoid"
            obs, _, terminated, truncated, info = env.step(action)
            rows.append((*before, avoid, info["collision"], info["goal_touched"]))
            done = terminated or truncated
    env.close()
    return np.asarray(rows, dtype=float)


def bands(rows: np.ndarray) -> dict[str, list[dict[str, float]]]:
    """The avoid share, collision and touch rate of the steps in each band of each quantity."""
    out: dict[str, list[dict[str, float]]] = {}
    for column, (quantity, edges) in enumerate(BANDS.items()):
        out[quantity] = []
        for low, high in itertools.pairwise(edges):
            inside = (rows[:, column] >= low) & (rows[:, column] < high)
            if inside.any():
                share, collision, touch = rows[inside, 2:].mean(axis=0)
                out[quantity].append(
                    {
                        # None for an open end: strict JSON has no infinity.
                        "low": float(low) if np.isfinite(low) else None,
                        "high": float(high) if np.isfinite(high) else None,
                        "steps": int(inside.sum()),
                        "avoid_share": share,
                        "collision_rate": collision,
                        "touch_rate": touch,
                    }
                )
    return out


def _edge(value: float | None, open_end: str) -> str:
    return f"{value:6.2f}" if value is not None else f"{open_end:>6}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "bundles", nargs="+", help="NAME=PATH of a hierarchy.zip whose workers are goal and avoid"
    )
    parser.add_argument("--out", type=Path, help="Also write the figures to this JSON file.")
    args = parser.parse_args()
    result = {}
    for spec in args.bundles:
        name, _, path = spec.partition("=")
        rows = steps_of(path)
        by_band = bands(rows)
        result[name] = {"avoid_share": float(rows[:, 2].mean()), **by_band}
        print(f"{name}: avoid worker on {rows[:, 2].mean():.1%} of {len(rows)} steps")
        for quantity, entries in by_band.items():
            print(f"  by {quantity}")
            for e in entries:
                print(
                    f"    [{_edge(e['low'], '-inf')}, {_edge(e['high'], 'inf')})  {e['steps']:5d} steps  avoid "
                    f"{e['avoid_share']:6.1%}  collision {e['collision_rate']:6.1%}  touch {e['touch_rate']:6.1%}"
                )
    if args.out:
        args.out.write_text(json.dumps(result, indent=1, default=float))


if __name__ == "__main__":
    main()
