"""
``hddpg-cli --help`` start-up of two checkouts, measured back to back (interleaved rounds, medians).

On a machine shared with other work absolute times drift, so the two checkouts alternate and the ratio is
the figure to read. Per round and checkout: the wall time of ``python -m sb3_hddpg --help`` and the cumulative
``python -X importtime`` time of ``import sb3_hddpg.cli``.

    git archive REV | tar -x -C /tmp/before
    python benchmarks/cli_startup.py /tmp/before . [--rounds 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path


def wall_time(tree: Path) -> float:
    """Seconds of ``python -m sb3_hddpg --help`` in ``tree`` (its package first on the path)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    started = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "sb3_hddpg", "--help"], cwd=tree, env=env, check=True, capture_output=True
    )
    return time.perf_counter() - started


def import_time(tree: Path) -> float:
    """Seconds ``-X importtime`` reports for ``import sb3_hddpg.cli`` (cumulative, everything it imports)."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    command = [sys.executable, "-X", "importtime", "-c", "import sb3_hddpg.cli"]
    report = subprocess.run(command, cwd=tree, env=env, check=True, capture_output=True, text=True).stderr
    line = [row for row in report.splitlines() if row.rstrip().endswith("| sb3_hddpg.cli")][-1]
    return int(line.split("|")[1]) / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("before", type=Path, help="The checkout to compare against.")
    parser.add_argument("after", type=Path, help="The checkout measured.")
    parser.add_argument("--rounds", type=int, default=5, help="Interleaved rounds (default 5).")
    args = parser.parse_args()
    trees = {"before": args.before.resolve(), "after": args.after.resolve()}
    walls: dict[str, list[float]] = {name: [] for name in trees}
    imports: dict[str, list[float]] = {name: [] for name in trees}
    for _ in range(args.rounds):
        for name, tree in trees.items():
            walls[name].append(wall_time(tree))
            imports[name].append(import_time(tree))
    for name in trees:
        print(
            f"{name}: --help {statistics.median(walls[name]):.2f} s, import sb3_hddpg.cli "
            f"{statistics.median(imports[name]):.2f} s (medians of {args.rounds})"
        )
    wall_ratio = statistics.median(walls["after"]) / statistics.median(walls["before"])
    import_ratio = statistics.median(imports["after"]) / statistics.median(imports["before"])
    print(f"after / before: --help {wall_ratio:.3f}, import {import_ratio:.3f}")


if __name__ == "__main__":
    main()
