"""Post-hoc: each seed's managers evaluated with sampled worker selection (the paper's probabilistic selection)."""
import json
from sb3_hddpg.benchmark import TEST_SEED_BASE, normalised_term_sums
from sb3_hddpg.evaluation import evaluate
from sb3_hddpg.hierarchy import Hierarchy
import gymnasium as gym
out = {}
for method in ("hddpg", "hddpg-goal", "hddpg-avoid"):
    for seed in range(5):
        h = Hierarchy.load(f"runs/bench5/seed-{seed}/{method}/hierarchy.zip")
        h.seed(seed)
        env = gym.make(h.env_id, **h.env_kwargs)
        s = evaluate(h, env, n_episodes=10, seed=TEST_SEED_BASE, deterministic=False).summary()
        g, a = normalised_term_sums(s)
        out.setdefault(method, {})[seed] = {**s, "goal_reach_reward": g, "avoid_reach_reward": a}
json.dump(out, open("docs/results/sampled_selection.json", "w"), indent=1)
from sb3_hddpg.stats import summarise
for method, runs in out.items():
    for key in ("mean_reach_reward", "goal_reach_reward", "avoid_reach_reward", "collisions_per_episode", "goal_touch_rate"):
        st = summarise([r[key] for r in runs.values()])
        print(method, key, f"{st['mean']:.3f} [{st['ci_low']:.3f}, {st['ci_high']:.3f}]")
    print(method, "choices", [r.get("selection_rate") for r in runs.values()])
