"""
Do experiments use every core? The same ``hddpg-cli benchmark`` and ``hddpg-cli tune`` work run with
``--n-jobs 1`` and with ``--n-jobs 2``, wall clock compared (run on an otherwise idle machine: other load
takes cores away from exactly the parallel runs).

Both runs of a pair do identical work: the benchmark trains the same (method, seed) runs; the tuning runs
fix the parameters that set a trial's cost (network size, batch size, update schedule) and prune nothing,
so every trial trains the same number of steps on the same network. Each process uses one torch thread
(``--threads 1`` for tune; the benchmark always does), the fastest setting for these small networks
(``benchmarks/torch_threads.py``), so the ratio measures parallelism, not a thread-count change.

Target (issue: speed): ``--n-jobs 2`` finishes at least 1.7x faster than ``--n-jobs 1`` on 2 cores.

    python benchmarks/parallel_scaling.py [--scale 1.0]
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CLI = [sys.executable, "-m", "sb3_hddpg"]


def wall_seconds(args: list[str]) -> float:
    start = time.perf_counter()
    subprocess.run(
        [*CLI, *args],
        check=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "COLUMNS": "120"},
    )
    return time.perf_counter() - start


def benchmark_args(out: Path, n_jobs: int, steps: int) -> list[str]:
    return [
        "benchmark",
        "--methods", "hddpg,ddpg,ham",
        "--seeds", "2",
        "--timesteps", str(steps),
        "--worker-timesteps", str(steps),
        "--eval-freq", str(steps // 2),
        "--eval-episodes", "2",
        "--test-episodes", "4",
        "--n-jobs", str(n_jobs),
        "--out", str(out),
    ]  # fmt: skip


def tune_args(out: Path, n_jobs: int, steps: int) -> list[str]:
    # Trials of ~30 s each (4x the benchmark's per-run budget): real trials are minutes long, and with
    # seconds-long ones the fixed cost of starting the trial processes would be all the ratio measured.
    steps *= 4
    fixed = ["net_arch=small", "batch_size=64", "train_freq=1", "buffer_size=10000", "noise_type=normal"]
    return [
        "tune",
        "--level", "flat",
        "--n-trials", "4",
        "--timesteps", str(steps),
        "--n-evaluations", "2",
        "--eval-episodes", "2",
        "--pruner", "none",
        "--sampler", "random",
        "--seed", "0",
        *[arg for item in fixed for arg in ("--fix", item)],
        "--n-jobs", str(n_jobs),
        "--threads", "1",
        "--out", str(out),
    ]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--scale", type=float, default=1.0, help="multiply the training budgets (1: ~8 min total)"
    )
    parser.add_argument("--only", choices=["benchmark", "tune"], help="measure one command only")
    args = parser.parse_args()
    steps = max(200, int(2000 * args.scale))
    root = Path(tempfile.mkdtemp(prefix="hddpg-scaling-"))
    results = {}
    try:
        for name, make in (("benchmark", benchmark_args), ("tune", tune_args)):
            if args.only not in (None, name):
                continue
            times = {}
            for n_jobs in (1, 2):
                times[n_jobs] = wall_seconds(make(root / f"{name}-{n_jobs}", n_jobs, steps))
                print(f"{name:9s} --n-jobs {n_jobs}: {times[n_jobs]:6.1f} s wall")
            results[name] = times[1] / times[2]
    finally:
        shutil.rmtree(root, ignore_errors=True)
    for name, ratio in results.items():
        print(f"speed-up {name} --n-jobs 2 vs 1: {ratio:.2f}x (target >= 1.7x)")
    print(f"ratio (worst) --n-jobs 2 vs 1: {min(results.values()):.2f}x (target >= 1.7x)")


if __name__ == "__main__":
    main()
