"""
Confirm a tuning study's pick for a flat agent at the full budget before it replaces the bundled block
(docs/TUNING.md): the bundled block and the study's written config trained side by side, the benchmark's way
(its flat budget, run options and kept model), over several seeds, each kept model scored on the
development episodes. A pick replaces the bundled block only if it scores higher there.

    python studies/confirm_pick.py --method sac --pick runs/record-studies/sac.yml --seeds 5 --backend sbx \\
        --n-jobs 2 --out runs/confirm-sac

Writes ``OUT/<base|pick>/seed-<s>/record.json`` per run (kept: an interrupted confirmation continues where it
stopped) and ``OUT/report.md``: per seed the two scores and their difference, the means, and in how many seed
pairs the pick is higher. ``--report-only`` writes the report from the records alone.
"""

from __future__ import annotations

import argparse
import json
import statistics
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from sb3_hddpg.experiments.benchmark.methods import FLAT_HER_METHODS

#: The flat methods a pick can be confirmed for: the studies of record's (their algorithm: the method's name,
#: or for a ``-her`` method the algorithm whose ``flat-her`` block it trains).
FLAT_PICKS = ("ddpg", "sac", *FLAT_HER_METHODS)
#: The score compared: the mean reach reward per development episode.
SCORE = "mean_reach_reward"
ARMS = ("base", "pick")


def run_one(method: str, arm: str, config: str | None, seed: int, options: dict[str, Any]) -> dict[str, Any]:
    """Train one arm's flat agent for one seed as the benchmark does; its development score (kept)."""
    from sb3_hddpg.artifacts.io import atomic_write_json
    from sb3_hddpg.experiments.benchmark.methods import final_test
    from sb3_hddpg.experiments.benchmark.settings import BenchmarkSettings
    from sb3_hddpg.training.flat import FLAT_ENV_ID, FLAT_HER_KEY, train_flat

    folder = Path(options["out"]) / arm / f"seed-{seed}"
    path = folder / "record.json"
    if path.exists():
        return json.loads(path.read_text())
    algo = FLAT_HER_METHODS.get(method, method)
    block = FLAT_HER_KEY if method in FLAT_HER_METHODS else None
    settings = BenchmarkSettings(methods=[method], seeds=[seed], backend=options["backend"])
    budget = options["timesteps"] or settings.flat_budget
    train_flat(
        folder,
        algo=algo,
        config=config,
        env_id=FLAT_ENV_ID,
        run=settings.run_options(seed, budget, budget),
        block=block,
    )
    test = final_test(folder / "flat" / f"{algo}.zip", settings)
    record = {
        "method": method,
        "arm": arm,
        "config": config,
        "seed": seed,
        "env_steps": budget,
        "backend": settings.backend,
        "test_episode_set": test["test_episode_set"],
        "development": test["test"],
    }
    atomic_write_json(path, record)
    return record


def report(out: Path, method: str, seeds: int) -> str:
    """Per seed the base and pick scores and their difference; the means; the seed pairs the pick wins."""
    records = {
        (arm, seed): json.loads(p.read_text())
        for arm in ARMS
        for seed in range(seeds)
        if (p := out / arm / f"seed-{seed}" / "record.json").exists()
    }
    pairs = [s for s in range(seeds) if ("base", s) in records and ("pick", s) in records]
    lines = [
        f"# Confirming the study's pick for `{method}` at the full budget",
        "",
        f"Mean reach reward per development episode of each run's kept model; {len(pairs)} seed pairs.",
        "",
        "| seed | bundled block | study's pick | pick - bundled |",
        "|---|---|---|---|",
    ]
    differences = []
    for seed in pairs:
        base = records[("base", seed)]["development"][SCORE]
        pick = records[("pick", seed)]["development"][SCORE]
        differences.append(pick - base)
        lines.append(f"| {seed} | {base:.1f} | {pick:.1f} | {pick - base:+.1f} |")
    if pairs:
        base_mean = statistics.mean(records[("base", s)]["development"][SCORE] for s in pairs)
        pick_mean = statistics.mean(records[("pick", s)]["development"][SCORE] for s in pairs)
        wins = sum(d > 0 for d in differences)
        lines.append(f"| mean | {base_mean:.1f} | {pick_mean:.1f} | {pick_mean - base_mean:+.1f} |")
        verdict = (
            "replaces the bundled block" if pick_mean > base_mean else "does not replace the bundled block"
        )
        lines += ["", f"The pick is higher in {wins} of {len(pairs)} seed pairs and {verdict}."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--method", required=True, choices=sorted(FLAT_PICKS), help="The flat method.")
    parser.add_argument("--pick", help="The study's written config file (its method's block is the pick).")
    parser.add_argument("--seeds", type=int, default=5, help="Seed pairs (0 .. N-1).")
    parser.add_argument(
        "--timesteps", type=int, default=None, help="Env steps a run (default: the flat budget)."
    )
    parser.add_argument("--backend", default="sbx", help="sb3 or sbx.")
    parser.add_argument("--n-jobs", type=int, default=1, help="Runs at a time.")
    parser.add_argument("--out", type=Path, required=True, help="Results folder (finished runs are kept).")
    parser.add_argument("--report-only", action="store_true", help="Write the report from the records alone.")
    args = parser.parse_args(argv)
    if args.seeds < 1 or args.n_jobs < 1 or (args.timesteps is not None and args.timesteps < 1):
        parser.error("--seeds, --n-jobs and --timesteps must be >= 1")
    if not args.report_only:
        if args.pick is None:
            parser.error("--pick is required unless --report-only")
        if not Path(args.pick).is_file():
            parser.error(f"--pick: no config file {args.pick!r}")
        options = {"out": str(args.out), "backend": args.backend, "timesteps": args.timesteps}
        jobs = [
            (arm, config, seed)
            for seed in range(args.seeds)
            for arm, config in (("base", None), ("pick", args.pick))
        ]
        # One fresh process per run, started with spawn (JAX warns about fork).
        with ProcessPoolExecutor(args.n_jobs, mp_context=get_context("spawn"), max_tasks_per_child=1) as pool:
            list(
                pool.map(
                    run_one, *zip(*[(args.method, arm, config, seed, options) for arm, config, seed in jobs])
                )
            )
    args.out.mkdir(parents=True, exist_ok=True)
    text = report(args.out, args.method, args.seeds)
    (args.out / "report.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
