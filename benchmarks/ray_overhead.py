"""
What does the Ray executor cost? The same ``hddpg-cli benchmark`` (its default methods, 2 seeds, small
budgets) run with the local process pool and with ``--executor ray`` on a local Ray head of as many CPUs,
wall clock compared (run it on an otherwise idle machine). The head is started before the Ray run is
timed, as a cluster exists before a user points the benchmark at it; connecting to it is timed.

Target: the Ray run takes at most 1.1x the local run's wall time.

    python benchmarks/ray_overhead.py [--scale 1.0] [--n-jobs 2]

Needs Ray (``pip install "sb3-hddpg[cluster]"``). The head runs on loopback without Ray's token
authentication and is stopped afterwards (only the processes this script started).
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

from hddpg_zoo.ray_executor import ClusterError

# The loopback head is test scaffolding (tests/ray_head.py), not part of the library: import it from the
# repository root.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.ray_head import LOOPBACK_ENV, local_ray_head

CLI = [sys.executable, "-m", "sb3_hddpg"]
#: A loopback cluster of our own: no token to hand around (keep authentication on a real network).
ENV = {**os.environ, "COLUMNS": "120", **LOOPBACK_ENV}


def wall_seconds(args: list[str]) -> float:
    start = time.perf_counter()
    done = subprocess.run([*CLI, *args], capture_output=True, text=True, env=ENV)
    if done.returncode != 0:
        raise SystemExit(f"hddpg-cli {' '.join(args)} failed:\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}")
    return time.perf_counter() - start


def benchmark_args(out: Path, n_jobs: int, steps: int) -> list[str]:
    return [
        "benchmark",
        "--seeds", "2",
        "--timesteps", str(steps),
        "--worker-timesteps", str(steps),
        "--eval-freq", str(max(1, steps // 2)),
        "--eval-episodes", "2",
        "--test-episodes", "4",
        "--n-jobs", str(n_jobs),
        "--out", str(out),
    ]  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--scale", type=float, default=1.0, help="multiply the training budgets (1: 2000 steps per run)"
    )
    parser.add_argument("--n-jobs", type=int, default=2, help="runs at a time, and the Ray head's CPUs")
    args = parser.parse_args()
    steps = max(100, int(2000 * args.scale))
    root = Path(tempfile.mkdtemp(prefix="hddpg-ray-overhead-"))
    try:
        local = wall_seconds(benchmark_args(root / "local", args.n_jobs, steps))
        print(f"local executor, --n-jobs {args.n_jobs}: {local:6.1f} s wall")
        started = time.perf_counter()
        with local_ray_head(args.n_jobs, root / "ray-head.log", env=ENV) as head:
            print(f"(ray start --head: {time.perf_counter() - started:.1f} s, not counted)")
            ray_args = [*benchmark_args(root / "ray", args.n_jobs, steps), "--executor", "ray"]
            on_ray = wall_seconds([*ray_args, "--ray-address", head.address])
        print(f"Ray executor,   --n-jobs {args.n_jobs}: {on_ray:6.1f} s wall")
    except ClusterError as error:  # Ray missing, or the head did not come up
        raise SystemExit(str(error)) from None
    finally:
        shutil.rmtree(root, ignore_errors=True)
    print(f"ratio Ray / local wall time: {on_ray / local:.2f}x (target <= 1.1x)")


if __name__ == "__main__":
    main()
