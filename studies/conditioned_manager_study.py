"""
The conditioned-manager study of docs/MANAGER.md: which way of training one manager for every preference
gives the best front, measured against HAM's threshold front over the same workers.

Per variant and manager seed: ``train_manager(manager_preferences="ratio-sweep", ...)`` over one pair of
workers, then the manager's front (goal touch against contacts, and the two normalised terms) at the 7
preferences of the sweep, on the frontier episodes (seeds 20000..): episodes that neither the learning
curves (10000..), the development scores (15000..) nor the final test (900000..) use. HAM's thresholds are
picked on the curve episodes (the non-dominated ones of a grid) and scored on the same frontier episodes,
once per workers. Each front's hypervolume is pymoo's, against the benchmark's fixed reference points.

    python studies/conditioned_manager_study.py --workers runs/w --variants box,box-ham --seeds 2 --out runs/cms
    python studies/conditioned_manager_study.py --compose goal=RUN_A/workers avoid=RUN_B/workers ...

``--compose`` builds the workers folder from single-worker folders (e.g. two ``benchmarks/time_to_skill.py``
runs), the models and their manifest entries as they are. Finished runs are kept, so the same command
continues an interrupted study; ``--report-only`` writes the report from what is there.

Variants (each a ``train_manager`` setting; ``--timesteps`` env steps unless the variant says otherwise):

- ``box``: the paper's DDPG manager on the simplex action, the bundled manager block;
- ``box-ham``: ``box`` started from HAM's choices (``init_from_ham``, HAM at ``--ham-start`` threshold);
- ``box-end``: ``box`` whose options also end when the nearest obstacle crosses half the sensor range or the
  goal touch changes (``option_end="distance=0.5,touch"``);
- ``box-long``: ``box`` with three times the budget;
- ``dqn``: a DQN manager on ``Discrete(n_workers)`` (SMDP Q-learning over options);
- ``dqn-ham``: ``dqn`` started from HAM's choices;
- ``dqn-long``: ``dqn`` with three times the budget;
- ``dqn-step``: ``dqn`` deciding at every env step (``option_steps=1``), as HAM does;
- ``dqn-motion``: ``dqn`` that also sees how the state moved over the last env step (``manager_motion=20``):
  whether an obstacle comes or goes, which no threshold on a distance can tell;
- ``dqn-wide``: ``dqn`` trained over, and measured at, preferences that reach further towards each end
  (ratios 1, 2, 4, 8 and 16, 9 preferences), as HAM's threshold sweep runs from the goal worker alone to
  nearly the avoid worker alone;
- ``dqn-wide-motion``: both; ``dqn-wide-motion-50`` with motion scaled by 50, ``dqn-wide-motion-k2`` deciding
  every 2 env steps.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import gymnasium as gym

import sb3_hddpg  # noqa: F401  (registers the env ids)
from hddpg_zoo.agent_settings import manager_option_steps
from hddpg_zoo.benchmark.front import SWEEP, ham_thresholds
from hddpg_zoo.benchmark.front_points import (
    PLANES,
    SAFE_CONTACTS,
    SNAKE_FRONT,
    FrontPoint,
    member_fields,
    safe_touch,
    sweep_labels,
)
from sb3_hddpg.artifacts.manifests import save_manifest
from sb3_hddpg.artifacts.records.models import models_manifest, read_workers_manifest
from sb3_hddpg.baselines.ham import load_ham, save_ham
from sb3_hddpg.envs.contract import env_contract, state_layout_of
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.episode_sets import FRONTIER
from sb3_hddpg.evaluation import evaluate
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.loading import load_policy
from sb3_hddpg.policy import Policy
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.run_options import RunOptions


@dataclass(frozen=True)
class Variant:
    """One way of training the conditioned manager."""

    algo: str = "ddpg"
    ham_start: bool = False
    option_end: str | None = None
    budget_factor: int = 1
    option_steps: int | None = None
    manager_motion: float | None = None
    sweep: PreferenceSpace = SWEEP


#: Each worker in turn weighted 1, 2, 4, 8 and 16 times the other, the factors summing to 2.
WIDE = PreferenceSpace.parse("ratio-sweep:16", SWEEP.names)

VARIANTS = {
    "box": Variant(),
    "box-ham": Variant(ham_start=True),
    "box-end": Variant(option_end="distance=0.5,touch"),
    "box-long": Variant(budget_factor=3),
    "dqn": Variant(algo="dqn"),
    "dqn-ham": Variant(algo="dqn", ham_start=True),
    "dqn-long": Variant(algo="dqn", budget_factor=3),
    "dqn-step": Variant(algo="dqn", option_steps=1),
    "dqn-motion": Variant(algo="dqn", manager_motion=20.0),
    "dqn-wide": Variant(algo="dqn", sweep=WIDE),
    "dqn-wide-motion": Variant(algo="dqn", sweep=WIDE, manager_motion=20.0),
    "dqn-wide-motion-50": Variant(algo="dqn", sweep=WIDE, manager_motion=50.0),
    "dqn-wide-motion-k2": Variant(algo="dqn", sweep=WIDE, manager_motion=20.0, option_steps=2),
}


@dataclass(frozen=True)
class CurveSettings:
    """What :func:`ham_thresholds` reads: episodes per threshold on the curve episodes."""

    eval_episodes: int


def compose(parts: Sequence[str], folder: Path) -> Path:
    """A workers folder holding each ``NAME=DIR``'s worker NAME (model and manifest entry as they are)."""
    entries = {}
    for part in parts:
        name, _, source = part.partition("=")
        manifest = read_workers_manifest(Path(source) / "manifest.json")
        if name not in manifest.entries:
            raise SystemExit(f"No worker {name!r} in {source}")
        entries[name] = manifest.entries[name]
        folder.mkdir(parents=True, exist_ok=True)
        shutil.copy2(Path(source) / f"{name}.zip", folder / f"{name}.zip")
    save_manifest(folder / "manifest.json", models_manifest("workers", entries))
    return folder.parent


def score(policy: Policy, env: gym.Env, label: str, episodes: int) -> FrontPoint:
    """The policy's point on the frontier episodes."""
    summary = evaluate(policy, env, n_episodes=episodes, seed=FRONTIER.first_seed).summary()
    return FrontPoint.of(label, summary, env_contract(env).reward_bounds)


def front_record(points: list[FrontPoint]) -> dict[str, object]:
    """A front's points and its hypervolume in each plane."""
    return member_fields(points, SNAKE_FRONT)


def baselines(workers: Path, out: Path, episodes: int, curve_episodes: int) -> dict[str, object]:
    """HAM's threshold front (thresholds picked on the curve episodes) and each worker alone."""
    path = out / "baselines.json"
    if path.exists():
        return json.loads(path.read_text())
    env = gym.make(SNAKE_REACH_ENV_ID)
    try:
        n_links = state_layout_of(env)["joint_obstacle_distances"]
        ham_path = save_ham(
            out / "ham.json",
            workers / "workers" / "manifest.json",
            threshold=(n_links.stop - n_links.start) / 2,
            env_id=SNAKE_REACH_ENV_ID,
        )
        switch, _ = load_ham(ham_path)
        thresholds = ham_thresholds(switch, env, CurveSettings(curve_episodes))  # type: ignore[arg-type]
        ham_points = []
        for entry in thresholds:
            switch.threshold = entry["threshold"]
            ham_points.append(score(switch, env, f"threshold={entry['threshold']:g}", episodes))
        record: dict[str, object] = {"ham": front_record(ham_points), "ham_thresholds": thresholds}
        for worker in ("goal", "avoid"):
            loaded = load_policy(workers / "workers" / f"{worker}.zip")
            worker_env = loaded.make_env(SNAKE_REACH_ENV_ID)
            try:
                record[worker] = front_record([score(loaded.policy, worker_env, worker, episodes)])
            finally:
                worker_env.close()
    finally:
        env.close()
    path.write_text(json.dumps(record, indent=1))
    return record


def read_baselines(out: Path) -> dict[str, object]:
    """The baselines a study measured (``OUT/baselines.json``)."""
    path = out / "baselines.json"
    if not path.is_file():
        raise SystemExit(f"No baselines in {out}: run the study first")
    return json.loads(path.read_text())


def run_variant(
    workers: Path, out: Path, name: str, seed: int, args: argparse.Namespace
) -> dict[str, object]:
    """Train one variant's conditioned manager for one seed and measure its front (kept once done)."""
    folder = out / name / f"seed-{seed}"
    path = folder / "front.json"
    if path.exists():
        return json.loads(path.read_text())
    variant = VARIANTS[name]
    # SB3 counts a manager's budget and evaluation period in decisions, each ``option_steps`` env steps.
    option_steps = variant.option_steps or manager_option_steps(algo=variant.algo)
    run = RunOptions(
        timesteps=max(1, args.timesteps * variant.budget_factor // option_steps),
        seed=seed,
        eval_freq=max(1, args.eval_freq // option_steps),
        eval_episodes=args.curve_episodes,
        resume=(folder / "manager").exists(),
        backend=args.backend,
    )
    start = time.perf_counter()
    train_manager(
        workers,
        folder,
        algo=variant.algo,
        manager_preferences=variant.sweep,
        init_from_ham=args.ham_start if variant.ham_start else None,
        option_end=variant.option_end,
        option_steps=variant.option_steps,
        manager_motion=variant.manager_motion,
        run=run,
    )
    seconds = time.perf_counter() - start
    hierarchy = Hierarchy.load(folder / "hierarchy.zip")
    env = gym.make(SNAKE_REACH_ENV_ID)
    try:
        points = []
        sweep = variant.sweep
        for label, point in zip(sweep_labels(sweep), sweep.points):
            hierarchy.set_preference(dict(zip(sweep.names, (float(v) for v in point))))
            points.append(score(hierarchy, env, label, args.episodes))
    finally:
        env.close()
    record = {
        "variant": name,
        "seed": seed,
        "env_steps": args.timesteps * variant.budget_factor,
        "seconds": seconds,
        **front_record(points),
    }
    path.write_text(json.dumps(record, indent=1))
    return record


def _cell(values: Sequence[float | None], digits: int, scale: float = 1.0) -> str:
    """Mean and per seed; a seed without a value is ``-`` and left out of the mean."""
    known = [v * scale for v in values if v is not None]
    mean = f"{statistics.mean(known):.{digits}f}" if known else "-"
    each = ", ".join("-" if v is None else f"{v * scale:.{digits}f}" for v in values)
    return f"{mean} [{each}]"


def report(out: Path, names: Sequence[str], seeds: int, base: dict[str, object]) -> str:
    """
    A Markdown table: each variant's hypervolume per plane and its goal touch at the safe end (mean and per
    seed) beside HAM's and the workers'.
    """
    lines = [
        f"# Conditioned managers against HAM's threshold front ({out.name})",
        "",
        "Fronts on the frontier episodes; a manager's budget in env steps; HAM and the workers train nothing.",
        "",
        "| front | env steps | seeds | hypervolume (touch, contacts): mean [per seed] | hypervolume (goal, "
        f"avoid terms) | most goal touch (%) with <= {SAFE_CONTACTS:g} contacts |",
        "|---|---|---|---|---|---|",
    ]
    for member in ("ham", "goal", "avoid"):
        record = base[member]
        hv = record["hypervolume"]  # type: ignore[index]
        safe = _cell([safe_touch(record["points"])], 1, 100)  # type: ignore[index]
        lines.append(f"| {member} | - | - | {hv['outcomes']:.4f} | {hv['terms']:.4f} | {safe} |")
    for name in names:
        runs = [
            json.loads(p.read_text())
            for s in range(seeds)
            if (p := out / name / f"seed-{s}" / "front.json").exists()
        ]
        if not runs:
            continue
        cells = [_cell([r["hypervolume"][plane] for r in runs], 4) for plane in PLANES]
        cells.append(_cell([safe_touch(r["points"]) for r in runs], 1, 100))
        steps = ", ".join(f"{n:,}" for n in sorted({int(r["env_steps"]) for r in runs}))
        lines.append(f"| {name} | {steps} | {len(runs)} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    source = p.add_mutually_exclusive_group()
    source.add_argument("--workers", type=Path, help="a train-workers run folder (goal and avoid workers)")
    source.add_argument(
        "--compose", nargs="+", metavar="NAME=DIR", help="build it from single-worker folders"
    )
    p.add_argument("--variants", default="box,box-ham,box-end,dqn", help=f"among {list(VARIANTS)}")
    p.add_argument("--seeds", type=int, default=2, help="manager seeds 0..N-1 per variant")
    p.add_argument(
        "--timesteps", type=int, default=40_000, help="manager env steps (the bundled budget: 10k decisions)"
    )
    p.add_argument("--eval-freq", type=int, default=5000, help="env steps between curve evaluations")
    p.add_argument("--curve-episodes", type=int, default=5, help="episodes per curve evaluation")
    p.add_argument("--episodes", type=int, default=20, help="frontier episodes per front point")
    p.add_argument("--ham-start", type=float, default=3.0, help="HAM's threshold for the *-ham variants")
    p.add_argument("--backend", default=None, help="sb3 or sbx (default: the config block's)")
    p.add_argument("--out", type=Path, required=True, help="study folder")
    p.add_argument("--report-only", action="store_true", help="write the report from finished runs")
    args = p.parse_args()
    names = [n for n in args.variants.split(",") if n]
    unknown = sorted(set(names) - set(VARIANTS))
    if unknown:
        raise SystemExit(f"Unknown variants {unknown}; choose from {list(VARIANTS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    if args.report_only:  # from the records alone, e.g. the shipped ones under docs/results/
        (args.out / "report.md").write_text(report(args.out, names, args.seeds, read_baselines(args.out)))
        print((args.out / "report.md").read_text())
        return
    if not (args.compose or args.workers):
        p.error("one of the arguments --workers --compose is required")
    workers = compose(args.compose, args.out / "workers" / "workers") if args.compose else args.workers
    base = baselines(workers, args.out, args.episodes, args.curve_episodes)
    for seed in range(args.seeds):  # seed by seed: an early stop leaves every variant compared
        for name in names:
            record = run_variant(workers, args.out, name, seed, args)
            print(name, seed, record["hypervolume"], f"{record['seconds']:.0f} s", flush=True)
    text = report(args.out, names, args.seeds, base)
    (args.out / "report.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
