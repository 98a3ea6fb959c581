"""
Equal tuning effort for every method of the benchmark (docs/TUNING.md): one Optuna study per method, each with
the same number of trials, each trial the same share of what that method finally trains with in the
benchmark (``--budget-fraction``), or the same env steps for every method (``--timesteps``); every study starts
from its method's bundled block (its first trial, ``enqueue_base``) and is evaluated on the tuning episodes.

    python studies/equal_effort_tuning.py --n-trials 10 --budget-fraction 0.1 --backend sbx --n-jobs 2 \\
        --front-manager dqn --front-timesteps 160000 --out runs/record-studies

Each study is named for the benchmark method it serves:

- ``goal``, ``avoid``: the workers, each with its snake-arm algorithm (``SNAKE_WORKER_ALGOS``), final
  budget its block's ``n_timesteps``;
- ``ddpg``, ``sac``, ``ddpg-her``, ``sac-her`` (``--flat``): the flat agents, final budget the benchmark's
  flat budget (the hierarchy's env steps); the ``-her`` ones tune the ``flat-her`` block, the goal worker's
  tricks on the reach task;
- ``hddpg``: the DDPG manager over workers trained from the tuned worker blocks, final budget the manager's;
- ``hddpg-front``: the front's managers' algorithm (``--front-manager``, when it is not DDPG), final budget
  ``--front-timesteps``; tuned at the unweighted preference, as a manager of its own;
- ``ham``: HAM's threshold over the same workers (its trial is one evaluation, no training).

Order: the workers, then the flat agents while two workers train with the tuned worker blocks at their full
budget (one more process); then the managers and HAM over those workers. Everything resumes: re-run the same
command after an interruption. ``--seeds-per-trial K`` trains every trial K times and ranks it by the mean.

Writes the tuned blocks (``OUT/ddpg.yml``, ``OUT/sac.yml``...: each the bundled file with its method's block
replaced), every study's trials (``OUT/studies/<method>.json``, :func:`~hddpg_zoo.study_export.
export_study`, which ``hddpg-cli report`` turns into docs/TUNING.md's table), ``OUT/summary.json`` (per study:
trials by state, steps per trial, the base config's value, the best value and parameters; HAM's best
threshold), and prints the summary as a Markdown table.

The best trial of each study is the one with the best evaluation (``--rank-by peak``, the default): the
benchmark keeps each run's best-evaluated checkpoint, and ranking by the last evaluation let a policy stuck on
one constant action win a flat DDPG study by 1.4 points (docs/TUNING.md). The summary also names the best
trial by the last evaluation.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from hddpg_zoo.agent_settings import backend_for
from hddpg_zoo.benchmark.settings import FLAT_HER_METHODS, BenchmarkSettings
from hddpg_zoo.study_export import export_study
from hddpg_zoo.study_storage import default_storage_url
from hddpg_zoo.tuning import (
    RANKINGS,
    StudySettings,
    TuningTarget,
    best_trials,
    save_best_config,
    trial_counts,
    trial_score,
    tune,
)
from sb3_hddpg.envs.ids import WORKER_ENV_IDS
from sb3_hddpg.training.config import load_config_file
from sb3_hddpg.training.flat import FLAT_HER_KEY
from sb3_hddpg.training.run_options import RunOptions
from sb3_hddpg.training.workers import SNAKE_WORKER_ALGOS, train_workers

#: The flat agents tuned by default: the run of record's.
DEFAULT_FLAT = ("ddpg", "sac", "ddpg-her", "sac-her")


@dataclass(frozen=True)
class Study:
    """
    One method's study.

    :param name: the benchmark method it serves (the study's name, its folder and its export).
    :param level: the tuning level (``worker``, ``flat``, ``manager`` or ``ham``).
    :param algo: the algorithm tuned.
    :param worker: the worker (level ``worker``).
    :param block: another block of the config than the level's (the ``-her`` flat agents).
    """

    name: str
    level: str
    algo: str
    worker: str | None = None
    block: str | None = None

    @property
    def file(self) -> str | None:
        """The tuned file this study's best block is written to (``None``: HAM, which has no block)."""
        return None if self.level == "ham" else f"{self.algo}.yml"


def worker_studies() -> list[Study]:
    """The workers' studies, each with the algorithm the snake arm trains it with."""
    return [Study(w, "worker", algo, worker=w) for w, algo in SNAKE_WORKER_ALGOS.items()]


def flat_studies(methods: list[str]) -> list[Study]:
    """The flat agents' studies: a ``-her`` method tunes its algorithm's ``flat-her`` block."""
    return [
        Study(m, "flat", FLAT_HER_METHODS[m], block=FLAT_HER_KEY)
        if m in FLAT_HER_METHODS
        else Study(m, "flat", m)
        for m in methods
    ]


def over_workers_studies(front_manager: str) -> list[Study]:
    """The studies over the tuned workers: the DDPG manager, the front's manager (if another), HAM."""
    studies = [Study("hddpg", "manager", "ddpg")]
    if front_manager != "ddpg":
        studies.append(Study("hddpg-front", "manager", front_manager))
    return [*studies, Study("ham", "ham", "ddpg")]


def final_budget(study: Study, settings: BenchmarkSettings) -> int | None:
    """What the method trains with in the benchmark, in env steps (``None``: HAM, which trains nothing)."""
    if study.level == "worker":
        block = TuningTarget(level="worker", worker=study.worker, algo=study.algo).base_block()
        return settings.worker_timesteps or int(block["n_timesteps"])
    if study.level == "flat":
        return settings.flat_budget
    if study.name == "hddpg-front":
        return settings.front_env_steps
    if study.level == "manager":
        return settings.manager_env_steps
    return None


def run_study(
    args: argparse.Namespace, study: Study, settings: BenchmarkSettings, workers: Path | None
) -> tuple[TuningTarget, Any]:
    """One method's study (resumed if it exists), with its share of its final budget; its trials exported."""
    budget = final_budget(study, settings)
    share = args.budget_fraction is not None and budget is not None
    target = TuningTarget(
        level=study.level,
        worker=study.worker,
        workers_dir=str(workers) if workers is not None else None,
        timesteps=None if share or study.level == "ham" else args.timesteps,
        budget_fraction=args.budget_fraction if share else None,
        final_budget=budget if share else None,
        block=study.block,
        n_evaluations=args.n_evaluations,
        eval_episodes=args.eval_episodes,
        seed=args.seed,
        algo=study.algo,
        backend=backend_for(study.algo, args.backend) if study.level != "ham" else None,
        n_seeds=args.seeds_per_trial if study.level != "ham" else 1,
    )
    folder = args.out / "tuning" / study.name
    folder.mkdir(parents=True, exist_ok=True)
    storage = default_storage_url(folder)
    settings_ = StudySettings(
        storage=storage, study_name=study.name, n_trials=args.n_trials, pruner=args.pruner, seed=args.seed
    )
    tuned = tune(target, settings_, folder, n_jobs=args.n_jobs)
    exports = args.out / "studies"
    exports.mkdir(exist_ok=True)
    (exports / f"{study.name}.json").write_text(
        json.dumps(export_study(storage, study.name), indent=1) + "\n"
    )
    print(f"{study.name}: {trial_counts(tuned)}", flush=True)
    return target, tuned


def summarise(study: Study, target: TuningTarget, tuned: Any, args: argparse.Namespace) -> dict[str, Any]:
    """What the docs report of a study: its budget, trials by state, the base config's value and the best."""
    base = [t for t in tuned.trials if t.user_attrs.get("base_config") and t.value is not None]
    best = best_trials(tuned, 1, args.rank_by)
    by_last = best_trials(tuned, 1)
    return {
        "study": study.name,
        "level": target.level,
        "algo": target.algo,
        "trials": trial_counts(tuned),
        "env_steps_per_trial": None if target.level == "ham" else target.budget(),
        "budget_fraction": target.budget_fraction,
        "final_budget": target.final_budget,
        "rank_by": args.rank_by,
        "base_value": trial_score(base[0], args.rank_by) if base else None,
        "base_last_value": base[0].value if base else None,
        "base_sampled_outside_space": base[0].user_attrs.get("sampled_outside_space") if base else None,
        "best_value": trial_score(best[0], args.rank_by) if best else None,
        "best_trial": best[0].number if best else None,
        "best_params": best[0].params if best else None,
        # Which trial the last evaluation alone would have picked, and its value.
        "best_trial_by_last": by_last[0].number if by_last else None,
        "best_last_value": by_last[0].value if by_last else None,
        # What the study cost: its finished trials' own durations, summed (process minutes, not wall time).
        "trial_minutes": sum(
            (t.datetime_complete - t.datetime_start).total_seconds() / 60
            for t in tuned.trials
            if t.datetime_complete is not None and t.datetime_start is not None
        ),
    }


def workers_config(out: Path, studies: list[Study]) -> Path:
    """
    One file with every tuned worker block (each worker's from its algorithm's tuned file), from which the
    workers the managers are tuned over train: a block names its algorithm's parameters only.
    """
    config: dict[str, Any] = {}
    for study in studies:
        key = WORKER_ENV_IDS[str(study.worker)]
        config[key] = load_config_file(out / str(study.file))[key]
    path = out / "workers.yml"
    path.write_text(yaml.safe_dump(config, sort_keys=False))
    return path


def parse_args() -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--n-trials", type=int, default=10, help="finished trials per method")
    effort = p.add_mutually_exclusive_group()
    effort.add_argument("--timesteps", type=int, default=40_000, help="env steps per trial, every method")
    effort.add_argument(
        "--budget-fraction", type=float, default=None, help="each trial's share of its method's final budget"
    )
    p.add_argument("--flat", default=",".join(DEFAULT_FLAT), help="the flat agents tuned (benchmark methods)")
    p.add_argument("--front-manager", default="ddpg", help="the front's managers' algorithm (as benchmark's)")
    p.add_argument(
        "--front-timesteps", type=int, default=None, help="their budget in env steps (as benchmark's)"
    )
    p.add_argument("--n-evaluations", type=int, default=5, help="evaluations per trial (for the pruner)")
    p.add_argument("--eval-episodes", type=int, default=5, help="episodes per evaluation")
    p.add_argument("--pruner", default="median", choices=["median", "halving", "none"], help="Optuna pruner")
    p.add_argument("--backend", default="sb3", choices=["sb3", "sbx"], help="training backend of every trial")
    p.add_argument("--n-jobs", type=int, default=1, help="trial processes per study")
    p.add_argument(
        "--worker-timesteps",
        type=int,
        default=None,
        help="steps per worker under the manager (default: its block's)",
    )
    p.add_argument("--seed", type=int, default=0, help="training seed of every trial, and the samplers' seed")
    p.add_argument(
        "--seeds-per-trial",
        type=int,
        default=1,
        help="training seeds per trial (--seed, --seed + 1, ...), every method but HAM; a trial's value is their mean",
    )
    p.add_argument(
        "--rank-by",
        default="peak",
        choices=RANKINGS,
        help="which trial is best: by its best evaluation (peak) or its last (last)",
    )
    p.add_argument(
        "--only",
        default=None,
        help="run only these studies (comma-separated names, e.g. avoid,ddpg,sac), e.g. while another "
        "method's block is still being decided; a study over the workers also runs the worker studies it "
        "needs. summary.json is written by a run of every study",
    )
    p.add_argument("--out", type=Path, default=Path("runs/equal-tuning"), help="output folder")
    args = p.parse_args()
    args.flat = [m.strip() for m in args.flat.split(",") if m.strip()]
    if args.only is not None:
        known = [s.name for s in all_studies(args.flat, args.front_manager)]
        args.only = [name.strip() for name in args.only.split(",") if name.strip()]
        unknown = sorted(set(args.only) - set(known))
        if unknown or not args.only:
            p.error(f"--only: expected study names among {known}, got {unknown or args.only}")
    return args


def all_studies(flat: list[str], front_manager: str) -> list[Study]:
    """Every study of a full run, in its order."""
    return [*worker_studies(), *flat_studies(flat), *over_workers_studies(front_manager)]


def print_summary(summary: list[dict[str, Any]], rank_by: str) -> None:
    which = "best" if rank_by == "peak" else "last"
    print(
        f"| study | trials (complete / pruned) | env steps per trial | base config ({which} evaluation) | "
        f"best ({which} evaluation) | best trial | best trial by the last evaluation | trial minutes |"
    )
    print("|---|---|---|---:|---:|---:|---|---:|")
    for entry in summary:
        counts = entry["trials"]
        base = f"{entry['base_value']:.1f}" if entry["base_value"] is not None else "-"
        best = f"{entry['best_value']:.1f}" if entry["best_value"] is not None else "-"
        by_last = (
            f"{entry['best_trial_by_last']} ({entry['best_last_value']:.1f})"
            if entry["best_last_value"] is not None
            else "-"
        )
        print(
            f"| {entry['study']} | {counts.get('COMPLETE', 0)} / {counts.get('PRUNED', 0)} | "
            f"{entry['env_steps_per_trial'] or 'one evaluation'} | {base} | {best} | {entry['best_trial']} | "
            f"{by_last} | {entry['trial_minutes']:.0f} |"
        )


def selected_studies(args: argparse.Namespace) -> tuple[list[Study], list[Study], list[Study]]:
    """
    The worker, flat and over-the-workers studies to run: all, or ``--only``'s, with the worker studies that
    a selected study over the workers needs (it is tuned over workers trained from the tuned blocks).
    """
    workers, flats = worker_studies(), flat_studies(args.flat)
    over_workers = over_workers_studies(args.front_manager)
    if args.only is None:
        return workers, flats, over_workers
    chosen = set(args.only)
    over_workers = [study for study in over_workers if study.name in chosen]
    if over_workers:
        chosen |= {study.name for study in workers}
    return [s for s in workers if s.name in chosen], [s for s in flats if s.name in chosen], over_workers


def start_workers_training(args: argparse.Namespace) -> multiprocessing.process.BaseProcess:
    """Train the workers from the tuned worker blocks in a process of their own (resumed if begun)."""
    config = workers_config(args.out, worker_studies())
    run = RunOptions(timesteps=args.worker_timesteps, seed=args.seed, backend=args.backend, resume=True)
    trainer = multiprocessing.get_context("spawn").Process(
        target=train_workers, args=(args.out / "workers",), kwargs={"config": config, "run": run}
    )
    print("training the workers with the tuned blocks, beside the flat studies...", flush=True)
    trainer.start()
    return trainer


def main() -> None:
    args = parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    # The benchmark's own budgets (a flat agent's, a manager's, the front's): what each share is taken of.
    settings = BenchmarkSettings(
        methods=["hddpg", *args.flat],
        backend=args.backend,
        worker_timesteps=args.worker_timesteps,
        front_manager=args.front_manager,
        front_timesteps=args.front_timesteps,
    )
    summary: list[dict[str, Any]] = []

    def study_and_save(study: Study, workers: Path | None = None) -> None:
        target, tuned = run_study(args, study, settings, workers)
        if study.file is not None:
            save_best_config(tuned, target, args.out / study.file, args.rank_by)
        summary.append(summarise(study, target, tuned, args))

    workers, flats, over_workers = selected_studies(args)
    for study in workers:
        study_and_save(study)
    # The workers the managers and HAM are tuned over train (one process, from the tuned blocks) while the
    # flat studies run, so that no core waits for them.
    trainer = start_workers_training(args) if over_workers else None
    for study in flats:
        study_and_save(study)
    if trainer is not None:
        trainer.join()
        if trainer.exitcode != 0:
            raise SystemExit(f"training the workers failed (exit code {trainer.exitcode}); re-run to resume")
    for study in over_workers:
        # From the bundled manager block, not OUT's: once a manager study has saved its best block there, a
        # study started again (e.g. after deleting it) would start from that block instead.
        study_and_save(study, args.out / "workers")
    if args.only is None:
        (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    print_summary(summary, args.rank_by)


if __name__ == "__main__":
    main()
