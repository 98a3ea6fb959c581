"""
Equal tuning effort for every method of the benchmark (docs/TUNING.md): the same Optuna budget, the same
number of trials of the same env steps each, for the two workers, the manager, HAM's threshold and the flat
DDPG, TD3 and SAC; every study starts from its method's bundled config (its first trial, ``enqueue_base``).

    python studies/equal_effort_tuning.py --n-trials 10 --timesteps 40000 --backend sbx --n-jobs 2 \\
        --out runs/equal-tuning

Order: the goal and avoid workers, then the flat agents (each on its own study) while two workers are trained
with the tuned worker blocks at their full budget (seed 0); over those the manager and HAM are tuned. A
manager's trial counts env steps (decisions x ``option_steps``) like every other; a HAM trial trains nothing
and costs one evaluation. Everything resumes: re-run the same command after an interruption.
``--seeds-per-trial K`` trains every trial K times (seeds ``--seed`` to ``--seed + K - 1``) and ranks it by
the mean: a study over one seed picked a manager block that ran the goal worker in that seed and worse mixes
in three of five others (docs/MANAGER.md).

Writes ``OUT/ddpg.yml`` (the tuned goal, avoid, flat and manager blocks over the bundled file), ``OUT/td3.yml``,
``OUT/sac.yml``, ``OUT/summary.json`` (per study: trials by state, steps per trial, the base config's value,
the best value and parameters; HAM's best threshold) and prints the summary as a Markdown table.

The best trial of each study is the one with the best evaluation (``--rank-by peak``, the default): the
benchmark keeps each run's best-evaluated checkpoint, and ranking by the last evaluation let a policy stuck on
one constant action win the flat DDPG study by 1.4 points (docs/TUNING.md). The summary also names the best
trial by the last evaluation.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import shutil
import time
from pathlib import Path
from typing import Any

from sb3_hddpg.experiments.study_storage import default_storage_url
from sb3_hddpg.experiments.tuning import (
    RANKINGS,
    StudySettings,
    TuningTarget,
    best_trials,
    save_best_config,
    trial_counts,
    trial_score,
    tune,
)
from sb3_hddpg.training.run_options import RunOptions
from sb3_hddpg.training.workers import train_workers

#: The studies of the workers, then of the flat agents: (level, worker, algorithm, file the best block goes to).
WORKER_STUDIES: list[tuple[str, str | None, str, str]] = [
    ("worker", "goal", "ddpg", "ddpg.yml"),
    ("worker", "avoid", "ddpg", "ddpg.yml"),
]
FLAT_STUDIES: list[tuple[str, str | None, str, str]] = [
    ("flat", None, "ddpg", "ddpg.yml"),
    ("flat", None, "td3", "td3.yml"),
    ("flat", None, "sac", "sac.yml"),
]
#: The studies over the workers trained with the tuned worker blocks.
OVER_WORKERS: list[tuple[str, str | None, str, str | None]] = [
    ("manager", None, "ddpg", "ddpg.yml"),
    ("ham", None, "ddpg", None),
]


def run_study(
    args: argparse.Namespace,
    level: str,
    worker: str | None,
    algo: str,
    config: Path | None,
    workers: Path | None,
) -> tuple[TuningTarget, Any]:
    """One method's study (resumed if it exists), with the shared budget."""
    target = TuningTarget(
        level=level,
        worker=worker,
        workers_dir=str(workers) if workers is not None else None,
        config=str(config) if config is not None else None,
        timesteps=args.timesteps,
        n_evaluations=args.n_evaluations,
        eval_episodes=args.eval_episodes,
        seed=args.seed,
        algo=algo,
        backend=args.backend if level != "ham" else None,
        n_seeds=args.seeds_per_trial if level != "ham" else 1,
    )
    folder = args.out / "studies" / target.name
    folder.mkdir(parents=True, exist_ok=True)
    settings = StudySettings(
        storage=default_storage_url(folder),
        study_name=target.name,
        n_trials=args.n_trials,
        pruner=args.pruner,
        seed=args.seed,
    )
    started = time.perf_counter()
    study = tune(target, settings, folder, n_jobs=args.n_jobs)
    print(f"{target.name}: {trial_counts(study)} in {time.perf_counter() - started:.0f} s", flush=True)
    return target, study


def summarise(target: TuningTarget, study: Any, args: argparse.Namespace) -> dict[str, Any]:
    """What the docs report of a study: its budget, trials by state, the base config's value and the best."""
    base = [t for t in study.trials if t.user_attrs.get("base_config") and t.value is not None]
    best = best_trials(study, 1, args.rank_by)
    by_last = best_trials(study, 1)
    return {
        "study": target.name,
        "level": target.level,
        "algo": target.algo,
        "trials": trial_counts(study),
        "env_steps_per_trial": None if target.level == "ham" else args.timesteps,
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
            for t in study.trials
            if t.datetime_complete is not None and t.datetime_start is not None
        ),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--n-trials", type=int, default=10, help="finished trials per method")
    p.add_argument("--timesteps", type=int, default=40_000, help="env steps per trial, every method")
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
    p.add_argument("--out", type=Path, default=Path("runs/equal-tuning"), help="output folder")
    args = p.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    summary: list[dict[str, Any]] = []
    for level, worker, algo, file in WORKER_STUDIES:
        target, study = run_study(args, level, worker, algo, None, None)
        save_best_config(study, target, args.out / file, args.rank_by)
        summary.append(summarise(target, study, args))

    # The workers the manager and HAM are tuned over train (one process, from their own copy of the tuned
    # blocks) while the flat studies run, so that no core waits for them.
    workers_config = args.out / "workers.yml"
    shutil.copyfile(args.out / "ddpg.yml", workers_config)
    run = RunOptions(timesteps=args.worker_timesteps, seed=args.seed, backend=args.backend, resume=True)
    trainer = multiprocessing.get_context("spawn").Process(
        target=train_workers, args=(args.out / "workers",), kwargs={"config": workers_config, "run": run}
    )
    print("training the workers with the tuned blocks, beside the flat studies...", flush=True)
    trainer.start()
    for level, worker, algo, file in FLAT_STUDIES:
        target, study = run_study(args, level, worker, algo, None, None)
        save_best_config(study, target, args.out / file, args.rank_by)
        summary.append(summarise(target, study, args))
    trainer.join()
    if trainer.exitcode != 0:
        raise SystemExit(f"training the workers failed (exit code {trainer.exitcode}); re-run to resume")

    workers = args.out / "workers"
    for level, worker, algo, maybe_file in OVER_WORKERS:
        # From the bundled manager block, not OUT/ddpg.yml's: once a manager study has saved its best block
        # there, a study started again (e.g. after deleting it) would start from that block instead.
        target, study = run_study(args, level, worker, algo, None, workers)
        if maybe_file is not None:  # HAM has no config block: its threshold is in the summary
            save_best_config(study, target, args.out / maybe_file, args.rank_by)
        summary.append(summarise(target, study, args))

    (args.out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    which = "best" if args.rank_by == "peak" else "last"
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


if __name__ == "__main__":
    main()
