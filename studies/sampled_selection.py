"""
Post-hoc evaluation for docs/RESULTS.md: each seed's managers with *sampled* worker selection (the paper's
probabilistic selection) on the benchmark's test episodes. Run from a checkout after the benchmark:
``python studies/sampled_selection.py [RUN_FOLDER]`` (default ``runs/bench``).
"""

import json
import sys
from pathlib import Path

import gymnasium as gym

from hddpg_zoo.benchmark import normalised_term_sums
from hddpg_zoo.stats import summarise
from sb3_hddpg.episode_sets import DEVELOPMENT
from sb3_hddpg.evaluation import evaluate
from sb3_hddpg.hierarchy.hierarchy import Hierarchy

RUN = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/bench")
METRICS = ("mean_reach_reward", "goal_reach_reward", "avoid_reach_reward", "collisions_per_episode")

out: dict[str, dict[int, dict]] = {}
for method in ("hddpg", "hddpg-goal", "hddpg-avoid"):
    for seed in range(5):
        hierarchy = Hierarchy.load(RUN / f"seed-{seed}" / method / "hierarchy.zip")
        hierarchy.seed(seed)
        env = gym.make(hierarchy.env_id, **hierarchy.env_kwargs)
        s = evaluate(
            hierarchy, env, n_episodes=20, seed=DEVELOPMENT.first_seed, deterministic=False
        ).summary()
        goal, avoid = normalised_term_sums(s)
        out.setdefault(method, {})[seed] = {**s, "goal_reach_reward": goal, "avoid_reach_reward": avoid}
Path("docs/results/sampled_selection.json").write_text(json.dumps(out, indent=1))
for method, runs in out.items():
    for key in METRICS:
        st = summarise([r[key] for r in runs.values()])
        print(method, key, f"{st['mean']:.3f} [{st['ci_low']:.3f}, {st['ci_high']:.3f}]")
