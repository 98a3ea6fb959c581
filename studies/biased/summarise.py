"""
Summarise the biased-manager runs of docs/MANAGER.md: per bias, the goal- and avoid-preferred managers'
test metrics per seed and their paired differences (bootstrap CI over seeds).

    python studies/biased/summarise.py RUN_FOLDER     # the folder run.sh wrote (default runs/biased)
"""

import json
import sys
from pathlib import Path

from hddpg_zoo.stats import paired_difference_ci

RUN = Path(sys.argv[1] if len(sys.argv) > 1 else "runs/biased")
METRICS = {
    "goal_touch_rate": ("goal touch %", 100.0),
    "collisions_per_episode": ("collisions / ep", 1.0),
    "mean_reach_reward": ("reach reward", 1.0),
    "success_rate": ("success %", 100.0),
}
summary = {}
for bias in sorted({p.name.split("-")[0][1:] for p in RUN.glob("b*-goal-s*.json")}, key=float):
    seeds = sorted(int(p.stem.rsplit("-s", 1)[1]) for p in RUN.glob(f"b{bias}-goal-s*.json"))
    runs = {
        prefer: [
            json.loads((RUN / f"b{bias}-{prefer}-s{seed}.json").read_text())["summary"] for seed in seeds
        ]
        for prefer in ("goal", "avoid")
    }
    print(f"\n## bias {bias} (factor {1 + float(bias):g} on the preferred worker), seeds {seeds}\n")
    print(
        "| seed | manager | " + " | ".join(label for label, _ in METRICS.values()) + " | goal worker chosen |"
    )
    print("|---|---|" + "---|" * (len(METRICS) + 1))
    for index, seed in enumerate(seeds):
        for prefer in ("goal", "avoid"):
            s = runs[prefer][index]
            cells = [f"{s[key] * scale:.2f}" for key, (_, scale) in METRICS.items()]
            chosen = s.get("selection_rate", {}).get("goal", float("nan"))
            print(f"| {seed} | {prefer}-preferred | " + " | ".join(cells) + f" | {100 * chosen:.0f} % |")
    print("\n| goal-preferred minus avoid-preferred | mean [95 % CI], paired by seed |\n|---|---|")
    for key, (label, scale) in METRICS.items():
        a = [s[key] * scale for s in runs["goal"]]
        b = [s[key] * scale for s in runs["avoid"]]
        mean, low, high = paired_difference_ci(a, b)
        summary.setdefault(bias, {})[key] = {"goal": a, "avoid": b, "difference": [mean, low, high]}
        print(f"| {label} | {mean:+.2f} [{low:+.2f}, {high:+.2f}] |")
(RUN / "summary.json").write_text(json.dumps(summary, indent=1))
