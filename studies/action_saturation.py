"""Post-hoc: the benchmark run's saved policies scored for action_saturation on its 20 test episodes.

python studies/action_saturation.py RUN_FOLDER
"""

import json
import sys
from pathlib import Path

import gymnasium as gym

from hddpg_zoo.stats import summarise
from sb3_hddpg.episode_sets import DEVELOPMENT
from sb3_hddpg.evaluation import evaluate
from sb3_hddpg.hierarchy.loading import load_policy

run = sys.argv[1]
out = {}
for method in ("hddpg", "ham", "ddpg", "hddpg-goal", "hddpg-avoid"):
    vals = []
    for seed in range(5):
        path = f"{run}/seed-{seed}/" + {"ddpg": "ddpg/flat/ddpg.zip", "ham": "ham/ham.json"}.get(
            method, f"{method}/hierarchy.zip"
        )
        lp = load_policy(path)
        env = gym.make("hddpg/SnakeReach-v0")
        s = evaluate(lp.policy, env, n_episodes=20, seed=DEVELOPMENT.first_seed).summary()
        vals.append(s["action_saturation"])
    st = summarise(vals)
    out[method] = {"per_seed": vals, "mean": st["mean"], "ci": [st["ci_low"], st["ci_high"]]}
    print(
        method,
        [round(v, 2) for v in vals],
        round(st["mean"], 2),
        [round(st["ci_low"], 2), round(st["ci_high"], 2)],
    )
Path("docs/results/action_saturation.json").write_text(json.dumps(out, indent=1))
