"""
Time to skill: how long a user waits for a worker's skill, per learner and backend.

For each learner given (``ALGO:BACKEND``, e.g. ``crossq:sbx``) and seed, the worker (``--worker``, the goal
worker by default) trains as ``hddpg-cli train-workers --workers goal --algo goal=ALGO --backend BACKEND``
does (the algorithm's bundled config, or ``--config``), with its periodic evaluation on the curve episodes
(the evaluation seeds that pick the best model, never the benchmark's test episodes). The run's time to
skill is the env steps and the wall-clock seconds (since the run's process started, so JAX's compilation
and the evaluations count: they are part of the wait) at the first evaluation from which the skill holds
for ``--hold`` consecutive evaluations: the goal worker's touch rate ``>= --threshold``, or the avoid
worker's contacts per episode ``<= --threshold`` with fewer than ``--max-saturation`` of its outputs
saturated. Each run's final model is then scored on the development episodes (held out from the curve),
and ``curves.png`` draws every learner's curves with bands over its seeds. Runs go seed by seed, each learner in turn, one process each, so a
machine's drift touches every learner alike; run it with nothing else on the machine. The report gives each
seed's steps and seconds, the median per learner, and the ratios of those medians to the baseline's (today's
DDPG goal worker, ``ddpg:sb3``, unless ``--baseline`` says otherwise). A run that never reaches the skill
counts as its whole budget, marked, so it can only make its learner look faster than it is if the budget is
too short: give budgets that let the baseline reach it.

    python benchmarks/time_to_skill.py --learners ddpg:sb3,ddpg:sbx,crossq:sbx,sac:sbx,tqc:sbx \
        [--seeds 5] [--timesteps 150000] [--eval-freq 5000] [--eval-episodes 10] [--out DIR]

With ``--stop-at-skill`` a run ends as soon as the skill has held for ``--hold`` evaluations, so the
measurement costs what the wait does; each run's final model is then the model at that point (its
development score says what the skill is worth, not what the whole budget would have made).

A finished run's result is kept in ``--out`` and reused, so an interrupted measurement continues where it
stopped; wall-clock figures are comparable only within one uninterrupted measurement.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from typing import Any, NamedTuple

from sb3_hddpg.artifacts.io import atomic_write_json

#: The learner every ratio is taken against: today's goal worker.
BASELINE = "ddpg:sb3"


class Learner(NamedTuple):
    """
    One learner: an algorithm on a backend, from its bundled config or ``config`` (a zoo_configs file).

    :param algo: the algorithm's registry name.
    :param backend: ``sb3`` or ``sbx``.
    :param config: a config file for this learner only (``None``: ``--config``, else the bundled one).
    """

    algo: str
    backend: str
    config: str | None = None

    @property
    def label(self) -> str:
        """``ddpg:sbx``, or ``ddpg:sbx@goal-prior`` for a learner of config ``goal-prior/config.yml``."""
        return f"{self.algo}:{self.backend}" + (f"@{self.config_name}" if self.config else "")

    @property
    def folder(self) -> str:
        """Its runs' folder under ``--out``."""
        return f"{self.algo}-{self.backend}" + (f"-{self.config_name}" if self.config else "")

    @property
    def config_name(self) -> str:
        """The config file's name without suffix, or its folder's for a ``config.yml``."""
        path = Path(self.config or "")
        return path.parent.name if path.stem == "config" and path.parent.name else path.stem


def parse_learners(text: str) -> list[Learner]:
    """
    ``ddpg:sb3,crossq:sbx,ddpg:sbx@prior.yml`` -> ``[Learner("ddpg", "sb3"), Learner("crossq", "sbx"),
    Learner("ddpg", "sbx", "prior.yml")]``, each checked against the records (``@FILE``: that learner's own
    config file, e.g. to time a variant of a block beside the bundled one).
    """
    from sb3_hddpg.algorithms import algorithm
    from sb3_hddpg.training.backends import BACKENDS, check_algo

    learners = []
    for part in filter(None, (piece.strip() for piece in text.split(","))):
        part, _, config = part.partition("@")
        if config and not Path(config).is_file():
            raise ValueError(f"No config file {config!r} (in {part}@{config})")
        algo, _, backend = part.partition(":")
        backend = backend or "sb3"
        if backend not in BACKENDS:
            raise ValueError(f"Expected a backend among {list(BACKENDS)} in {part!r}, actually {backend!r}")
        name = algorithm(algo).name
        check_algo(name, backend)
        learners.append(Learner(name, backend, config or None))
    if not learners:
        raise ValueError(f"Expected learners as ALGO:BACKEND separated by commas, actually {text!r}")
    return learners


def result_label(result: dict[str, Any]) -> str:
    """The label of the learner that made a run's result."""
    return Learner(result["algo"], result["backend"], result.get("config")).label


#: The default skill threshold of each worker: the goal worker's touch rate, the avoid worker's contacts.
DEFAULT_THRESHOLDS = {"goal": 0.5, "avoid": 0.3}


def has_skill(entry: dict[str, Any], worker: str, threshold: float, max_saturation: float) -> bool:
    """
    Whether one evaluation shows the skill: the goal worker touches on ``>= threshold`` of its steps; the
    avoid worker makes ``<= threshold`` contacts per episode with fewer than ``max_saturation`` of its
    outputs saturated (keeping clear by pushing every joint to its limit is not the skill). An evaluation
    without ``action_saturation`` is of a discrete action, which has no limit to be pinned at.
    """
    if worker == "goal":
        return bool(entry.get("goal_touch_rate", 0.0) >= threshold)
    contacts = entry.get("collisions_per_episode", float("inf"))
    return bool(contacts <= threshold and entry.get("action_saturation", 0.0) < max_saturation)


def time_to_skill(
    history: list[dict[str, Any]],
    clock: dict[int, float],
    threshold: float,
    hold: int,
    worker: str = "goal",
    max_saturation: float = 0.2,
) -> tuple[int | None, float | None]:
    """
    The env steps and seconds at the first evaluation from which the skill (:func:`has_skill`) holds for
    ``hold`` evaluations in a row; ``(None, None)`` if it never does.

    :param history: the evaluations (``timesteps`` and the metrics), in order.
    :param clock: env steps -> seconds since the run started, taken right after each evaluation.
    """
    for i in range(len(history) - hold + 1):
        window = history[i : i + hold]
        if all(has_skill(entry, worker, threshold, max_saturation) for entry in window):
            steps = int(history[i]["timesteps"])
            return steps, clock.get(steps)
    return None, None


def run_one(learner: Learner, seed: int, args: dict[str, Any]) -> dict[str, Any]:
    """Train one worker, timing each evaluation; returns the result (also saved, and reused)."""
    started = time.perf_counter()
    algo, backend = learner.algo, learner.backend
    out = Path(args["out"]) / learner.folder / f"seed-{seed}"
    result_path = out / "result.json"
    if result_path.exists():
        result = json.loads(result_path.read_text())
        if "development" not in result:  # a run measured before the held-out score was part of it
            result["development"] = development_score(out, args["development_episodes"], args["worker"])
            atomic_write_json(result_path, result)
        return result
    worker = args["worker"]
    from stable_baselines3.common.callbacks import BaseCallback

    from sb3_hddpg.training.workers import train_workers

    history_path = out / "evaluations" / f"{worker}.json"

    class Clock(BaseCallback):
        """
        Seconds since the run started at every evaluation (called after the evaluator on each step); with
        ``stop_at_skill``, it ends the run once the evaluations written so far show the skill held.
        """

        def __init__(self) -> None:
            super().__init__()
            self.seen: dict[int, float] = {}
            self.evaluations = 0

        def _on_step(self) -> bool:
            self.seen.setdefault(int(self.model.num_timesteps), time.perf_counter() - started)
            if (
                not args["stop_at_skill"]
                or self.model.num_timesteps % args["eval_freq"]
                or not history_path.exists()
            ):
                return True
            history = json.loads(history_path.read_text())
            if len(history) == self.evaluations:
                return True
            self.evaluations = len(history)
            steps, _ = time_to_skill(
                history, self.seen, args["threshold"], args["hold"], worker, args["max_saturation"]
            )
            return steps is None

    clock = Clock()
    trained = train_workers(
        out,
        workers=[worker],
        config=learner.config or args["config"],
        algos={worker: algo},
        timesteps=args["timesteps"],
        seed=seed,
        eval_freq=args["eval_freq"],
        eval_episodes=args["eval_episodes"],
        checkpoint_freq=0,
        keep_best=False,
        backend=backend,
        progress_bar=False,
        callback=clock,
    )
    trained_steps = int(trained.manifest["workers"][worker]["timesteps_trained"])
    history = json.loads((out / "evaluations" / f"{worker}.json").read_text())
    steps, seconds = time_to_skill(
        history, clock.seen, args["threshold"], args["hold"], worker, args["max_saturation"]
    )
    if seconds is None:  # never reached, or reached at the closing evaluation after learning stopped
        seconds = time.perf_counter() - started
    result = {
        "worker": worker,
        "algo": algo,
        "backend": backend,
        **({"config": learner.config} if learner.config else {}),
        "seed": seed,
        "stopped_at_skill": bool(args["stop_at_skill"]),
        "reached": steps is not None,
        "steps": steps if steps is not None else trained_steps,
        "seconds": seconds,
        "curve": [
            {
                "timesteps": e["timesteps"],
                "goal_touch_rate": e.get("goal_touch_rate"),
                "collisions_per_episode": e.get("collisions_per_episode"),
                "action_saturation": e.get("action_saturation"),
                "seconds": clock.seen.get(e["timesteps"]),
            }
            for e in history
        ],
    }
    result["development"] = development_score(out, args["development_episodes"], worker)
    atomic_write_json(result_path, result)
    return result


def development_score(out: Path, episodes: int, worker: str = "goal") -> dict[str, Any]:
    """
    The trained worker's final model scored on the development episodes (never the final test set): the
    held-out figure a learner is chosen by, beside the curve's, which picks nothing here.
    """
    from sb3_hddpg.episode_sets import DEVELOPMENT
    from sb3_hddpg.evaluation import evaluate
    from sb3_hddpg.hierarchy.loading import load_policy

    loaded = load_policy(out / "workers" / f"{worker}.zip")
    summary = evaluate(
        loaded.policy, loaded.make_env(), n_episodes=episodes, seed=DEVELOPMENT.seeds(episodes).start
    ).summary()
    keys = ("goal_touch_rate", "collisions_per_episode", "action_saturation", "mean_reward")
    return {"episode_set": DEVELOPMENT.describe(episodes), **{key: summary.get(key) for key in keys}}


def _mark(result: dict[str, Any]) -> str:
    """``>`` before a run's figures when it never reached the skill: its whole budget, a lower bound."""
    return "" if result["reached"] else ">"


def report(results: list[dict[str, Any]], learners: list[Learner], baseline: str) -> str:
    """A Markdown table: per learner, each seed's steps and seconds, the medians, and their ratios."""
    rows = [
        "| learner | seeds reached | steps per seed | seconds per seed | median steps | median s | "
        f"steps / {baseline} | s / {baseline} | development touch per seed | contacts / episode | saturated |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    medians: dict[str, tuple[float, float]] = {}
    for learner in learners:
        mine = sorted((r for r in results if result_label(r) == learner.label), key=lambda r: r["seed"])
        if mine:
            medians[learner.label] = (
                statistics.median(r["steps"] for r in mine),
                statistics.median(r["seconds"] for r in mine),
            )
    base = medians.get(baseline)
    for learner in learners:
        name = learner.label
        mine = sorted((r for r in results if result_label(r) == name), key=lambda r: r["seed"])
        if not mine:
            continue
        steps = ", ".join(f"{_mark(r)}{r['steps']}" for r in mine)
        seconds = ", ".join(f"{_mark(r)}{r['seconds']:.0f}" for r in mine)
        m_steps, m_seconds = medians[name]
        ratios = (
            (f"{m_steps / base[0]:.2f}", f"{m_seconds / base[1]:.2f}")
            if base and base[0] and base[1]
            else ("-", "-")
        )
        reached = sum(r["reached"] for r in mine)
        held_out = [r.get("development") or {} for r in mine]
        touch = ", ".join(f"{d['goal_touch_rate']:.1%}" if d else "-" for d in held_out)
        contacts = ", ".join(f"{d['collisions_per_episode']:.1f}" if d else "-" for d in held_out)
        saturated = ", ".join(
            f"{d['action_saturation']:.0%}" if d.get("action_saturation") is not None else "-"
            for d in held_out
        )
        rows.append(
            f"| {name} | {reached}/{len(mine)} | {steps} | {seconds} | {m_steps:.0f} | {m_seconds:.0f} | "
            f"{ratios[0]} | {ratios[1]} | {touch} | {contacts} | {saturated} |"
        )
    return "\n".join(rows)


def plot_curves(out: Path, learners: list[Learner], path: Path, worker: str = "goal") -> None:
    """
    The learning curves of every learner on its curve episodes: goal touch, contacts per episode and the
    share of saturated outputs over
    env steps, the mean over seeds with a 95 % t-interval band (seeds are few: a t-interval, not a
    bootstrap over them).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from scipy import stats

    from sb3_hddpg.algorithms import algorithm

    figure, axes = plt.subplots(1, 3, figsize=(15, 4), constrained_layout=True)
    # A bundled block in its algorithm's colour, the first backend of it only; another backend of the same
    # algorithm, or a block of its own file, in a colour no other learner has.
    colours: dict[str, str] = {}
    for learner in learners:
        own = algorithm(learner.algo).colour
        if not learner.config and own not in colours.values():
            colours[learner.label] = own
    spare = iter(c for c in matplotlib.colors.TABLEAU_COLORS if c not in colours.values())
    for learner in learners:
        colours.setdefault(learner.label, next(spare, "black"))
    for learner in learners:
        runs = [
            json.loads(history.read_text())
            for history in sorted((out / learner.folder).glob(f"seed-*/evaluations/{worker}.json"))
        ]
        runs = [run for run in runs if run]
        if not runs:
            continue
        length = min(len(run) for run in runs)
        steps = np.array([entry["timesteps"] for entry in runs[0][:length]])
        for axis, key in zip(axes, ("goal_touch_rate", "collisions_per_episode", "action_saturation")):
            values = np.array([[entry.get(key, np.nan) for entry in run[:length]] for run in runs])
            mean = values.mean(axis=0)
            colour = colours[learner.label]
            axis.plot(steps, mean, label=f"{learner.label} ({len(runs)} seeds)", color=colour)
            if len(runs) > 1:
                half = stats.t.ppf(0.975, len(runs) - 1) * values.std(axis=0, ddof=1) / np.sqrt(len(runs))
                axis.fill_between(steps, mean - half, mean + half, color=colour, alpha=0.2)
    titles = ("goal touch (share of steps)", "contacts per episode", "saturated outputs (share)")
    for axis, title in zip(axes, titles):
        axis.set_xlabel("env steps")
        axis.set_title(title)
        axis.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize="small")
    figure.suptitle(f"The {worker} worker on its curve episodes")
    figure.savefig(path, dpi=110)
    plt.close(figure)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--learners",
        default=f"{BASELINE},crossq:sbx,sac:sbx,tqc:sbx",
        help="ALGO:BACKEND[@CONFIG_FILE], comma-separated (@: that learner's own config file).",
    )
    parser.add_argument("--baseline", default=BASELINE, help="The learner the ratios are taken against.")
    parser.add_argument("--seeds", type=int, default=5, help="Seeds per learner (0 .. N-1).")
    parser.add_argument("--timesteps", type=int, default=150_000, help="Budget per run (env steps).")
    parser.add_argument("--eval-freq", type=int, default=5000, help="Env steps between evaluations.")
    parser.add_argument("--eval-episodes", type=int, default=10, help="Curve episodes per evaluation.")
    parser.add_argument(
        "--development-episodes",
        type=int,
        default=20,
        help="Development episodes that score each run's final model (held out from the curve).",
    )
    parser.add_argument(
        "--worker", default="goal", choices=sorted(DEFAULT_THRESHOLDS), help="The worker to train and time."
    )
    parser.add_argument(
        "--threshold",
        type=float,
        default=None,
        help="The skill: the goal worker's touch rate (default 0.5), the avoid worker's contacts per "
        "episode (default 0.3).",
    )
    parser.add_argument(
        "--max-saturation",
        type=float,
        default=0.2,
        help="The avoid worker's skill also needs fewer saturated outputs than this share.",
    )
    parser.add_argument("--hold", type=int, default=1, help="Evaluations in a row that must hold it.")
    parser.add_argument(
        "--stop-at-skill",
        action="store_true",
        help="End each run once the skill holds (its final model is then the model at that point).",
    )
    parser.add_argument(
        "--config", default=None, help="A zoo_configs file (default: each algorithm's bundled one)."
    )
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="Train nothing: report (and draw) the runs already finished in --out.",
    )
    parser.add_argument(
        "--n-jobs", type=int, default=1, help="Runs at a time (1 for clean wall-clock figures)."
    )
    parser.add_argument(
        "--out", default="runs/time_to_skill", help="Results folder (finished runs are reused)."
    )
    args = parser.parse_args(argv)
    for name in (
        "seeds",
        "timesteps",
        "eval_freq",
        "eval_episodes",
        "development_episodes",
        "hold",
        "n_jobs",
    ):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}")
    if args.threshold is None:
        args.threshold = DEFAULT_THRESHOLDS[args.worker]
    if not 0.0 <= args.threshold <= (1.0 if args.worker == "goal" else 1e6):
        parser.error(f"--threshold must be in [0, 1] for the goal worker and >= 0, got {args.threshold}")
    if not 0.0 < args.max_saturation <= 1.0:
        parser.error(f"--max-saturation must be in (0, 1], got {args.max_saturation}")
    try:
        learners = parse_learners(args.learners)
    except ValueError as error:
        parser.error(f"--learners: {error}")
    try:
        baselines = parse_learners(args.baseline)
    except ValueError as error:
        parser.error(f"--baseline: {error}")
    if len(baselines) != 1:
        parser.error(f"--baseline takes one learner, got {len(baselines)}: {args.baseline!r}")
    (baseline,) = baselines
    settings = {
        key: getattr(args, key)
        for key in (
            "out",
            "config",
            "timesteps",
            "eval_freq",
            "eval_episodes",
            "development_episodes",
            "threshold",
            "hold",
            "worker",
            "max_saturation",
            "stop_at_skill",
        )
    }
    # Seed by seed, every learner in turn: drift on the machine touches them alike.
    jobs = [(learner, seed) for seed in range(args.seeds) for learner in learners]
    if args.report_only:
        done = [Path(args.out) / learner.folder / f"seed-{seed}" / "result.json" for learner, seed in jobs]
        results = [json.loads(path.read_text()) for path in done if path.is_file()]
    else:
        # One fresh process per run: each pays its own start-up and compilation, as a user's run does.
        with ProcessPoolExecutor(args.n_jobs, mp_context=get_context("spawn"), max_tasks_per_child=1) as pool:
            results = list(pool.map(run_one, *zip(*jobs), [settings] * len(jobs)))
    table = report(results, learners, baseline.label)
    Path(args.out, "report.md").write_text(table + "\n")
    plot_curves(Path(args.out), learners, Path(args.out) / "curves.png", args.worker)
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
