"""
Your own manager over trained workers, with any SB3 algorithm: load the workers (each knows which state
components it sees, and the set knows the shared env), wrap the env so that the manager's action chooses
a worker, train, bundle, evaluate.

    python examples/own_manager.py runs/quickstart/workers --timesteps 2000 --out my-hierarchy.zip

The lines between the markers are the README's Python section, as they run.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from stable_baselines3 import SAC

from sb3_hddpg import Hierarchy, WorkerSelectionWrapper, evaluate, load_workers


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("workers", type=Path, help="a train-workers run folder or its workers folder")
    parser.add_argument("--timesteps", type=int, default=2_000, help="the manager's budget, in decisions")
    parser.add_argument("--episodes", type=int, default=5, help="evaluation episodes")
    parser.add_argument("--out", type=Path, default=Path("my-hierarchy.zip"), help="where to save the bundle")
    args = parser.parse_args()

    # --- the README's snippet
    workers = load_workers(args.workers)  # SB3 models that know which state components they see
    env = WorkerSelectionWrapper(workers.make_env(), workers)  # the shared env, as the workers were trained
    manager = SAC("MlpPolicy", env, seed=0).learn(args.timesteps)
    hierarchy = Hierarchy(manager, workers)
    hierarchy.save(args.out)
    print(evaluate(Hierarchy.load(args.out), n_episodes=args.episodes).summary())
    # --- end of the snippet


if __name__ == "__main__":
    main()
