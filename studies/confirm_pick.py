"""
Confirm a tuning study's pick at the full budget before it replaces the bundled block (docs/TUNING.md): the
bundled block and the study's written config trained side by side, the benchmark's way (its budget, run
options and kept model), over several seeds, each kept model scored on the development episodes. A pick
replaces the bundled block only if it scores higher there.

    python studies/confirm_pick.py --method sac --pick runs/record-studies/sac.yml --seeds 5 --backend sbx \\
        --n-jobs 2 --out runs/confirm-sac

The flat methods train as the benchmark's flat agents. The managers (``hddpg``: the DDPG manager;
``hddpg-front``: the front's managers' algorithm, ``--front-manager``, at ``--front-timesteps`` and seeing
``--front-motion`` as the front's do) train at the unweighted preference, as their studies did, over one
set of workers (``--workers``, a ``train-workers`` folder): each seed trains another manager over the same
workers, so the pairs differ by the manager's block and seed alone.

Writes ``OUT/<base|pick>/seed-<s>/record.json`` per run (kept: an interrupted confirmation continues where it
stopped) and ``OUT/report.md``: per seed the two scores and their difference, the means, and in how many seed
pairs the pick is higher. ``--report-only`` writes the report from the records alone.
"""

from __future__ import annotations

import argparse
import statistics
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hddpg_zoo.benchmark.methods import FLAT_HER_METHODS

if TYPE_CHECKING:
    from hddpg_zoo.benchmark.settings import BenchmarkSettings

#: The flat methods a pick can be confirmed for: the studies of record's (their algorithm: the method's name,
#: or for a ``-her`` method the algorithm whose ``flat-her`` block it trains).
FLAT_PICKS = ("ddpg", "sac", *FLAT_HER_METHODS)
#: The managers a pick can be confirmed for (the benchmark's methods that train one).
MANAGER_PICKS = ("hddpg", "hddpg-front")
#: The score compared: the mean reach reward per development episode.
SCORE = "mean_reach_reward"
ARMS = ("base", "pick")


@dataclass(frozen=True)
class ArmRun:
    """One arm's run: the method, its config file (``None``: the bundled block), seed, folder and settings."""

    method: str
    config: str | None
    seed: int
    folder: Path
    settings: BenchmarkSettings
    options: dict[str, Any]


def run_one(method: str, arm: str, config: str | None, seed: int, options: dict[str, Any]) -> dict[str, Any]:
    """Train one arm's agent for one seed as the benchmark does; its development score (kept)."""
    from hddpg_zoo.benchmark.methods import final_test
    from hddpg_zoo.benchmark.settings import BenchmarkSettings
    from sb3_hddpg.artifacts.io import atomic_write_json

    folder = Path(options["out"]) / arm / f"seed-{seed}"
    path = folder / "record.json"
    if path.exists():
        return read_arm_record(path)
    settings = BenchmarkSettings(
        methods=[method],
        seeds=[seed],
        backend=options["backend"],
        front_manager=options["front_manager"],
        front_timesteps=options["front_timesteps"],
        front_motion=options["front_motion"],
    )
    train = train_manager_arm if method in MANAGER_PICKS else train_flat_arm
    budget, policy = train(ArmRun(method, config, seed, folder, settings, options))
    test = final_test(policy, settings)
    record = {
        "method": method,
        "arm": arm,
        # The file's name, not its path: the records are shipped, and a path names this machine's folders.
        "config": None if config is None else Path(config).name,
        "seed": seed,
        "env_steps": budget,
        "backend": settings.backend,
        "test_episode_set": test["test_episode_set"],
        "development": test["test"],
    }
    atomic_write_json(path, record)
    return record


def train_flat_arm(arm: ArmRun) -> tuple[int, Path]:
    """A flat agent as the benchmark trains ``arm.method``: its env steps and its kept model."""
    from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
    from sb3_hddpg.training.flat import FLAT_HER_KEY, train_flat

    algo = FLAT_HER_METHODS.get(arm.method, arm.method)
    block = FLAT_HER_KEY if arm.method in FLAT_HER_METHODS else None
    budget = arm.options["timesteps"] or arm.settings.flat_budget
    train_flat(
        arm.folder,
        algo=algo,
        config=arm.config,
        env_id=SNAKE_REACH_ENV_ID,
        run=arm.settings.run_options(arm.seed, budget, budget),
        block=block,
    )
    return budget, arm.folder / "flat" / f"{algo}.zip"


def train_manager_arm(arm: ArmRun) -> tuple[int, Path]:
    """A manager as the benchmark trains ``arm.method``'s, at the unweighted preference: its env steps and bundle."""
    from hddpg_zoo.agent_settings import manager_option_steps
    from sb3_hddpg.training.manager import train_manager

    front = arm.method == "hddpg-front"
    algo = arm.settings.front_manager if front else "ddpg"
    budget = arm.options["timesteps"] or (
        arm.settings.front_env_steps if front else arm.settings.manager_env_steps
    )
    # The same env steps for both arms, as in the study's trials: each block decides every its own option_steps.
    run = arm.settings.manager_run_options(
        arm.seed, algo, budget, option_steps=manager_option_steps(arm.config, algo)
    )
    train_manager(
        arm.options["workers"],
        arm.folder / "manager",
        algo=algo,
        config=arm.config,
        manager_motion=arm.settings.front_motion if front else None,
        run=run,
    )
    return budget, arm.folder / "manager" / "hierarchy.zip"


def read_arm_record(path: Path) -> dict[str, Any]:
    """
    An arm's record (kept, or shipped with a confirmation and regenerated from): through the JSON size and
    depth limits, its development score a finite number.

    :raises ValueError: one line naming the file.
    """
    from sb3_hddpg.artifacts.limits import read_json_record
    from sb3_hddpg.artifacts.values import is_finite_number

    record = read_json_record(path, f"{path}: not a readable record of confirm_pick")
    development = record.get("development") if isinstance(record, dict) else None
    if not isinstance(development, dict) or not is_finite_number(development.get(SCORE)):
        raise ValueError(f"{path}: expected a record with development.{SCORE} a finite number")
    return record


def check_inputs(args: argparse.Namespace) -> None:
    """
    Everything an arm reads, checked before any arm runs: the settings it is made with, the pick's block as
    the arm reads it and the workers. A pick that cannot train was refused by its arm's process,
    a traceback after the bundled block's arm had trained for the whole budget.

    :raises ValueError: one line naming the option.
    """
    from hddpg_zoo.agent_settings import manager_option_steps
    from hddpg_zoo.benchmark.settings import BenchmarkSettings
    from sb3_hddpg.artifacts.manifests import load_workers
    from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
    from sb3_hddpg.training.flat import FLAT_HER_KEY, flat_hyperparams
    from sb3_hddpg.training.manager_setup import manager_hyperparams

    settings = BenchmarkSettings(
        methods=[args.method],
        seeds=list(range(args.seeds)),
        backend=args.backend,
        front_manager=args.front_manager,
        front_timesteps=args.front_timesteps,
        front_motion=args.front_motion,
    )
    if args.method in MANAGER_PICKS:
        algo = settings.front_manager if args.method == "hddpg-front" else "ddpg"
        manager_hyperparams(algo, args.pick)
        manager_option_steps(args.pick, algo)
        load_workers(args.workers)  # as the arm loads them: the manifest, every hash
    else:
        block = FLAT_HER_KEY if args.method in FLAT_HER_METHODS else None
        flat_hyperparams(
            FLAT_HER_METHODS.get(args.method, args.method), SNAKE_REACH_ENV_ID, None, args.pick, block
        )


def report(out: Path, method: str, seeds: int) -> str:
    """Per seed the base and pick scores and their difference; the means; the seed pairs the pick wins."""
    records = {
        (arm, seed): read_arm_record(p)
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
    parser.add_argument(
        "--method", required=True, choices=sorted((*FLAT_PICKS, *MANAGER_PICKS)), help="The benchmark method."
    )
    parser.add_argument("--pick", help="The study's written config file (its method's block is the pick).")
    parser.add_argument("--seeds", type=int, default=5, help="Seed pairs (0 .. N-1).")
    parser.add_argument(
        "--timesteps",
        type=int,
        default=None,
        help="Env steps a run (default: the method's benchmark budget).",
    )
    parser.add_argument("--workers", help="A manager's workers: a train-workers folder.")
    parser.add_argument("--front-manager", default="dqn", help="The front's managers' algorithm.")
    parser.add_argument("--front-timesteps", type=int, default=None, help="The front's managers' env steps.")
    parser.add_argument("--front-motion", type=float, default=0.0, help="The front's managers' motion scale.")
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
        if args.method in MANAGER_PICKS and (args.workers is None or not Path(args.workers).is_dir()):
            parser.error(f"--workers: {args.method} trains a manager over a train-workers folder")
        try:
            check_inputs(args)
        except (ValueError, OSError) as error:  # a missing workers manifest too
            parser.error(str(error))
        options = {
            "out": str(args.out),
            "backend": args.backend,
            "timesteps": args.timesteps,
            "workers": args.workers,
            "front_manager": args.front_manager,
            "front_timesteps": args.front_timesteps,
            "front_motion": args.front_motion,
        }
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
    from sb3_hddpg.artifacts.io import atomic_write_bytes

    try:
        text = report(args.out, args.method, args.seeds)
    except ValueError as error:
        parser.error(str(error))
    atomic_write_bytes(args.out / "report.md", text.encode())  # never half a report
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
