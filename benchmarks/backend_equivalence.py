"""
Do the two backends learn alike? N seeds of the goal worker on each, same hyperparameters and steps.

Each (backend, seed) run is ``train_workers(workers=["goal"], backend=...)`` with the bundled config (or
``--config``), exactly what ``hddpg-cli train-workers --backend`` does; the saved (SB3) worker is then
tested on ``--test-episodes`` fixed episodes, disjoint from the ones that picked the best model, and the
score is its mean reward. With the same seed both backends start from the same networks and draw the same
exploration noise and replay batches (see docs/PERFORMANCE.md), so runs are paired by seed and the
reported statistic is the bootstrap CI of the mean paired difference SBX - SB3 (hddpg_zoo.stats). A CI
that includes 0 means no difference was detected at this number of seeds.

    python benchmarks/backend_equivalence.py [--seeds 5] [--timesteps 30000] [--n-jobs 2] [--out DIR]

Runs are independent processes (``--n-jobs`` at a time); a finished run's result is kept in ``--out`` and
reused, so an interrupted comparison continues where it stopped.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

BACKENDS = ("sb3", "sbx")


def run_one(backend: str, seed: int, args: dict[str, Any]) -> dict[str, Any]:
    """Train the goal worker on ``backend`` with ``seed`` and test it; returns the result (also saved)."""
    out = Path(args["out"]) / f"{backend}-seed-{seed}"
    result_path = out / "result.json"
    if result_path.exists():
        return json.loads(result_path.read_text())
    from hddpg_zoo.benchmark import TEST_SEED_BASE
    from sb3_hddpg.artifacts.io import atomic_write_json
    from sb3_hddpg.evaluation import evaluate
    from sb3_hddpg.hierarchy.loading import load_policy
    from sb3_hddpg.training.workers import train_workers

    started, cpu = time.perf_counter(), time.process_time()
    trained = train_workers(
        out,
        workers=["goal"],
        config=args["config"],
        timesteps=args["timesteps"],
        seed=seed,
        resume=True,
        eval_freq=args["eval_freq"],
        eval_episodes=args["eval_episodes"],
        checkpoint_freq=0,
        backend=backend,
    )
    loaded = load_policy(out / "workers" / "goal.zip")
    env = loaded.make_env()
    try:
        test = evaluate(loaded.policy, env, n_episodes=args["test_episodes"], seed=TEST_SEED_BASE).summary()
    finally:
        env.close()
    result = {
        "backend": backend,
        "seed": seed,
        "timesteps": trained.manifest["workers"]["goal"]["timesteps_trained"],
        "test_mean_reward": test["mean_reward"],
        "test_goal_touch_rate": test["goal_touch_rate"],
        "wall_seconds": time.perf_counter() - started,
        "cpu_seconds": time.process_time() - cpu,
    }
    atomic_write_json(result_path, result)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seeds", type=int, default=5, help="seeds 0..N-1 per backend")
    parser.add_argument("--timesteps", type=int, default=None, help="steps per run (default: the config's)")
    parser.add_argument("--config", default=None, help="zoo_configs file (default: the bundled ddpg.yml)")
    parser.add_argument("--eval-freq", type=int, default=5000, help="steps between evaluations (best model)")
    parser.add_argument("--eval-episodes", type=int, default=5, help="episodes per evaluation")
    parser.add_argument("--test-episodes", type=int, default=20, help="episodes of the final test")
    parser.add_argument("--n-jobs", type=int, default=1, help="runs at a time, one process each")
    parser.add_argument("--out", default="runs/backend-equivalence", help="folder for runs and results")
    args = parser.parse_args()
    if args.seeds < 1 or args.n_jobs < 1:
        parser.error("--seeds and --n-jobs must be >= 1")
    from sb3_hddpg.training.backends import check_backend

    check_backend("sbx")  # a clear error, naming the extra, before anything runs
    settings = {key: getattr(args, key) for key in ("config", "timesteps", "eval_freq", "eval_episodes")}
    settings.update(test_episodes=args.test_episodes, out=args.out)
    jobs = [(backend, seed) for seed in range(args.seeds) for backend in BACKENDS]
    started = time.perf_counter()
    # Fresh interpreters ("spawn"): each SBX run sets JAX's threads before its first import of jax.
    with ProcessPoolExecutor(args.n_jobs, mp_context=get_context("spawn")) as pool:
        results = list(pool.map(run_one, *zip(*jobs), [settings] * len(jobs)))

    from hddpg_zoo.stats import paired_difference_ci

    by = {(r["backend"], r["seed"]): r for r in results}
    seeds = range(args.seeds)
    print(
        f"{'seed':>4s} {'SB3 test reward':>16s} {'SBX test reward':>16s} {'SB3 CPU s':>10s} {'SBX CPU s':>10s}"
    )
    for seed in seeds:
        a, b = by[("sb3", seed)], by[("sbx", seed)]
        print(
            f"{seed:4d} {a['test_mean_reward']:16.1f} {b['test_mean_reward']:16.1f} "
            f"{a['cpu_seconds']:10.0f} {b['cpu_seconds']:10.0f}"
        )
    sbx = [by[("sbx", s)]["test_mean_reward"] for s in seeds]
    sb3 = [by[("sb3", s)]["test_mean_reward"] for s in seeds]
    point, low, high = paired_difference_ci(sbx, sb3)
    verdict = "includes 0: no difference detected" if low <= 0 <= high else "excludes 0: the backends differ"
    print(
        f"mean paired difference SBX - SB3: {point:.1f}, 95 % bootstrap CI [{low:.1f}, {high:.1f}] ({verdict})"
    )
    print(
        f"{len(jobs)} runs in {time.perf_counter() - started:.0f} s wall; load average {os.getloadavg()[0]:.2f}"
    )
    summary = {
        "settings": settings,
        "seeds": args.seeds,
        "results": results,
        "difference": [point, low, high],
    }
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "summary.json").write_text(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()
