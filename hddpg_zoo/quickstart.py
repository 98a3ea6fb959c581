"""
``run_quickstart``: the whole method on a small budget, in one run folder.

Both workers are trained side by side (one process each), then the two managers and the flat DDPG baseline;
the HAM switch needs no training. The main hierarchy's manager is the selector that decides by state: a DQN
choosing a worker by index, started from HAM's switch (it imitates HAM's choices before RL), told the
preference at run time (trained over the ``ratio-sweep:16`` preferences, so ``evaluate --preference
goal=1,avoid=3`` answers) and seeing how its state moved, with the paper's simplex DDPG manager beside it as its
own row. Every method is then evaluated on the same seeds of ``hddpg/SnakeReach-v0``, and the run folder
receives the figures, a GIF of the hierarchy at work, the bundles and ``results.json``::

    RUN/
      config.yml              the hyperparameters used (RL Zoo format): workers, flat DDPG, simplex manager
      config-dqn.yml          the main manager's (the bundled dqn.yml, with the budget's overrides)
      workers/                goal.zip, avoid.zip, manifest.json
      manager/manager.zip     the main manager alone
      hierarchy.zip           the bundle: main manager + workers + manifest (load with Hierarchy.load)
      simplex/                the paper's simplex DDPG manager: hierarchy.zip, manager/, evaluations/...
      flat/                   flat-ddpg.zip, manifest.json (the single-DDPG baseline)
      ham.json                the HAM switch (when the HAM baseline is installed)
      zoo/                    the workers and flat DDPG in RL Zoo's layout (rl_zoo3.enjoy -f RUN/zoo)
      results.json            every method's metrics on the shared seeds, budget, timings, versions
      comparison.png  learning_curves.png  selection.png  hierarchy.gif
      evaluations/  tensorboard/  best/
      checkpoints/            each agent's last model (its replay buffer too with keep_checkpoints)
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import yaml

from hddpg_zoo.agent_settings import backend_for, manager_option_steps, read_history
from hddpg_zoo.media.figures import plot_comparison, plot_learning_curves, plot_selection_timeline
from hddpg_zoo.media.video import RecordingResult
from hddpg_zoo.packaging import write_zoo_layout
from hddpg_zoo.quickstart_figures import record_hierarchy, shown_episode
from hddpg_zoo.quickstart_jobs import (
    ENV_STEPS_PER_STEP,
    QuickstartObserver,
    run_training_jobs,
)
from sb3_hddpg.artifacts.io import atomic_write_bytes, atomic_write_json
from sb3_hddpg.artifacts.manifests import read_workers_manifest, save_manifest
from sb3_hddpg.artifacts.provenance import library_versions
from sb3_hddpg.artifacts.records import QUICKSTART_RESULTS_VERSION, models_manifest
from sb3_hddpg.artifacts.run_folder import holds_run_folder
from sb3_hddpg.baselines.ham import DEFAULT_MARGIN, save_ham
from sb3_hddpg.envs import MAX_EPISODE_STEPS
from sb3_hddpg.envs.contract import Proximity, state_layout_of
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID, WORKER_ENV_IDS
from sb3_hddpg.evaluation import EVAL_SEED_BASE, EvaluationResult, evaluate
from sb3_hddpg.hierarchy.loading import LoadedPolicy, load_policy
from sb3_hddpg.training.backends import check_backend
from sb3_hddpg.training.config import default_config, load_config_file
from sb3_hddpg.training.imitation_start import HamStart

#: The stages, in order; the overall progress bar counts them.
STAGES = ("train workers", "train managers + flat DDPG", "evaluate on shared seeds", "record GIF", "figures")

#: The comparison's label of the main hierarchy (its manager decides by state, for any preference) and of the
#: paper's (a DDPG manager on the simplex, for the one preference it was trained with).
MAIN_HIERARCHY = "hierarchy"
PAPER_HIERARCHY = "HDDPG"
#: The main manager: DQN choosing a worker by index, trained over the ratio sweep of preferences up to 16:1
#: (told the preference as an input, so that one manager answers every trade-off at run time) and seeing how
#: its state moved (an obstacle coming or going), the recipe of docs/MANAGER.md; it starts from HAM's switch
#: (:func:`main_manager_options`). From a random start, at the small budget, it ran the avoid worker on 1-17 %
#: of the steps, under 10 % in 2 seeds of 4 (20 development episodes each): RL rarely found the few decisions
#: near an obstacle where the avoid worker pays. Started from HAM it did on 22-36 %, most of them near an
#: obstacle, at the same reach reward as HAM's and with fewer contacts than from a random start.
MAIN_MANAGER: dict[str, Any] = {
    "algo": "dqn",
    "manager_preferences": "ratio-sweep:16",
    "manager_motion": 20.0,
}


@dataclass(frozen=True)
class QuickstartBudget:
    """
    How much a quickstart trains and evaluates.

    :param name: ``small`` or ``tiny``.
    :param worker_timesteps: steps per worker.
    :param manager_timesteps: the manager's env steps (it decides once per ``option_steps`` of them).
    :param flat_timesteps: steps of the flat DDPG baseline (``None``: the hierarchy's total env steps, every
        worker's and the manager's, as in the benchmark).
    :param eval_freq: steps between evaluations during training.
    :param eval_episodes: episodes per evaluation during training.
    :param compare_episodes: episodes per method in the final comparison (the same seeds for all).
    :param gif_episodes: episodes in the GIF (the selection timeline shows the same ones).
    :param gif_max_steps: cut the GIF's episodes to this many steps (``None``: full episodes).
    :param overrides: hyperparameters replaced in every block of the bundled config.
    :param ham_start_decisions: the main manager's decisions driven by HAM's switch before RL (it imitates
        them, and they fill its replay buffer); part of ``manager_timesteps``, not in addition to it.
    """

    name: str
    worker_timesteps: int
    manager_timesteps: int
    eval_freq: int
    eval_episodes: int
    compare_episodes: int
    flat_timesteps: int | None = None
    gif_episodes: int = 1
    gif_max_steps: int | None = None
    overrides: dict[str, Any] = field(default_factory=dict)
    ham_start_decisions: int = 2_000


#: ``small`` finishes in about ten minutes on two idle CPU cores; ``tiny`` in well under a minute (tests).
BUDGETS: dict[str, QuickstartBudget] = {
    "small": QuickstartBudget(
        "small",
        worker_timesteps=30_000,
        manager_timesteps=30_000,
        eval_freq=5_000,
        eval_episodes=5,
        compare_episodes=20,
    ),
    "tiny": QuickstartBudget(
        "tiny",
        worker_timesteps=300,
        manager_timesteps=300,
        eval_freq=150,
        eval_episodes=1,
        compare_episodes=2,
        gif_max_steps=40,
        ham_start_decisions=25,
        overrides={
            "learning_starts": 100,
            "batch_size": 32,
            "buffer_size": 5_000,
            "policy_kwargs": "dict(net_arch=[16])",
        },
    ),
}


@dataclass
class QuickstartResult:
    """
    What :func:`run_quickstart` produced.

    :param run_dir: the run folder.
    :param summaries: method name -> its evaluation summary on the shared seeds.
    :param methods: method name -> facts about it (kind, file, training steps and seconds).
    :param files: label -> path of every figure, video, bundle and ``results.json``.
    :param stage_seconds: stage name -> wall time.
    :param wall_seconds: the whole run's wall time.
    """

    run_dir: Path
    summaries: dict[str, dict[str, Any]]
    methods: dict[str, dict[str, Any]]
    files: dict[str, Path]
    stage_seconds: dict[str, float]
    wall_seconds: float


def flat_budget(budget: QuickstartBudget) -> int:
    """
    The flat DDPG's steps: the budget's own, or the hierarchy's total env steps (both workers' and the
    manager's), so that the flat agent sees as much data as the whole hierarchy, as in the benchmark.
    """
    if budget.flat_timesteps is not None:
        return budget.flat_timesteps
    return len(WORKER_ENV_IDS) * budget.worker_timesteps + budget.manager_timesteps


def ham_threshold() -> float:
    """
    HAM's default threshold on the snake arm: its joint count less :data:`DEFAULT_MARGIN` (on the summed
    joint-to-obstacle distances), the quickstart's HAM row and its main manager's start alike.
    """
    probe = gym.make(SNAKE_REACH_ENV_ID)
    n_joints = len(state_layout_of(probe).indices(["joint_obstacle_distances"]))
    probe.close()
    return n_joints - DEFAULT_MARGIN


def main_manager_options(budget: QuickstartBudget) -> dict[str, Any]:
    """
    The main manager's :func:`~sb3_hddpg.training.manager.train_manager` options at ``budget``:
    :data:`MAIN_MANAGER`, started from HAM's switch. Before RL the manager imitates HAM's choices over
    ``budget.ham_start_decisions`` decisions, which also fill its replay buffer, so that RL starts from a
    switch that calls the avoid worker near obstacles and keeps it where it pays (docs/MANAGER.md).
    """
    return {**MAIN_MANAGER, "init_from_ham": HamStart(ham_threshold(), decisions=budget.ham_start_decisions)}


# ---------------------------------------------------------------------------------------- the parent
def write_config(path: Path, overrides: dict[str, Any], algo: str = "ddpg") -> Path:
    """
    The bundled config of ``algo`` with ``overrides`` applied to every block, written to ``path`` (RL Zoo
    format).
    """

    config = load_config_file(default_config(algo))
    for block in config.values():
        block.update(overrides)
    header = f"# The hyperparameters of this quickstart run (the bundled zoo_configs/{algo}.yml"
    header += f" with {overrides}).\n" if overrides else ").\n"
    return atomic_write_bytes(path, (header + yaml.safe_dump(config, sort_keys=False)).encode())


# The workers train side by side in this folder: the lock is taken here, once, and shared with them.
@holds_run_folder(lambda call: call.arguments["out_dir"], "quickstart")
def run_quickstart(
    out_dir: str | Path,
    budget: str | QuickstartBudget = "small",
    seed: int = 0,
    processes: int = 2,
    observer: QuickstartObserver | None = None,
    keep_checkpoints: bool = False,
    backend: str = "sb3",
    ray_address: str | None = None,
) -> QuickstartResult:
    """
    Train both workers, the manager and the baselines, compare them on the same seeds and write everything
    into ``out_dir`` (see the module docstring for the layout). The folder must not hold results already.

    :param out_dir: the run folder.
    :param budget: a name in :data:`BUDGETS` or a :class:`QuickstartBudget`.
    :param seed: training seed of every agent (evaluation seeds are the library's fixed ones).
    :param processes: training processes at a time (2: the workers side by side, then manager and flat DDPG).
    :param observer: receives progress (default: none).
    :param keep_checkpoints: keep every agent's replay buffer in ``checkpoints/`` (about 70 MB each at the
        ``small`` budget), so that ``hddpg-cli train-* --resume`` can extend an agent's training exactly;
        by default only the model checkpoints stay and the run folder is about 6 MB.
    :param backend: the training backend of every agent, ``sb3`` or ``sbx`` (saved models are SB3 either way).
    :param ray_address: train the agents as Ray tasks on the cluster at this address (``auto`` or
        ``HOST:PORT``; every node must see ``out_dir`` at the same path), ``processes`` at a time; the
        evaluation, GIF and figures stay in this process. ``None``: local processes.
    :return: the metrics, the files written and the timings.
    """

    if isinstance(budget, str):
        if budget not in BUDGETS:
            raise ValueError(f"Unknown budget {budget!r}; choose from {list(BUDGETS)}")
        budget = BUDGETS[budget]
    if processes < 1:
        raise ValueError(f"Expected `processes` >= 1, actually: {processes}")
    backend = check_backend(backend)
    observer = observer or QuickstartObserver()
    run_dir = Path(out_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    clock = _StageClock(observer, processes)
    files: dict[str, Path] = {"config": write_config(run_dir / "config.yml", budget.overrides)}
    files["main_config"] = write_config(run_dir / "config-dqn.yml", budget.overrides, MAIN_MANAGER["algo"])
    common = dict(
        run_dir=str(run_dir),
        config=str(files["config"]),
        seed=seed,
        eval_freq=budget.eval_freq,
        eval_episodes=budget.eval_episodes,
        keep_checkpoints=keep_checkpoints,
        backend=backend,
    )
    launch = functools.partial(
        run_training_jobs, processes=processes, observer=observer, ray_address=ray_address
    )
    trained = _train_stages(run_dir, budget, common, launch, clock)
    files["bundle"] = run_dir / "hierarchy.zip"
    files["paper_bundle"] = run_dir / "simplex" / "hierarchy.zip"
    clock.start(2)
    policies, sources = _comparison_policies(run_dir, files)
    summaries, methods = _compare(policies, sources, trained, run_dir, budget, observer)
    clock.done(2)
    clock.start(3)
    shown, title = shown_episode(methods[MAIN_HIERARCHY], SNAKE_REACH_ENV_ID)
    recording, proximity = record_hierarchy(
        policies[MAIN_HIERARCHY], run_dir, (shown, budget.gif_episodes, budget.gif_max_steps), observer, files
    )
    clock.done(3)
    clock.start(4)
    names = list(policies[MAIN_HIERARCHY].policy.names)  # type: ignore[attr-defined]
    _plot_figures(run_dir, (budget, title), recording, proximity, names, summaries, files)
    clock.done(4)
    files["zoo"] = _write_zoo(run_dir)
    wall = time.monotonic() - started
    files["results"] = run_dir / "results.json"
    results = _results_json(run_dir, budget, seed, processes, summaries, methods, files, clock, wall)
    atomic_write_json(files["results"], results)
    return QuickstartResult(run_dir, summaries, methods, files, clock.seconds, wall)


def _results_json(
    run_dir: Path,
    budget: QuickstartBudget,
    seed: int,
    processes: int,
    summaries: dict[str, dict[str, Any]],
    methods: dict[str, dict[str, Any]],
    files: dict[str, Path],
    clock: _StageClock,
    wall: float,
) -> dict[str, Any]:
    """``results.json``: every method's metrics on the shared seeds, the budget, the files, timings, versions."""
    return {
        "schema_version": QUICKSTART_RESULTS_VERSION,
        "kind": "sb3-hddpg-quickstart",
        "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "env_id": SNAKE_REACH_ENV_ID,
        "budget": {**vars(budget), "flat_timesteps": flat_budget(budget)},
        "seed": seed,
        "eval_seeds": list(range(EVAL_SEED_BASE, EVAL_SEED_BASE + budget.compare_episodes)),
        "deterministic": True,
        "methods": {label: {**methods[label], "summary": summaries[label]} for label in summaries},
        "files": {label: str(_relative(path, run_dir)) for label, path in files.items()},
        "stage_seconds": clock.seconds,
        # CPU seconds per stage (the slowest job for side-by-side training): the wall time on idle cores.
        "stage_cpu_seconds": clock.cpu,
        "wall_seconds": wall,
        "processes": processes,
        "versions": library_versions(),
    }


class _StageClock:
    """Each stage's wall and CPU time, and its start reported to the observer."""

    def __init__(self, observer: QuickstartObserver, processes: int) -> None:
        self.observer = observer
        self.processes = processes
        self.seconds: dict[str, float] = {}
        self.cpu: dict[str, float] = {}

    def start(self, index: int) -> None:
        self.seconds[STAGES[index]] = time.monotonic()
        self.cpu[STAGES[index]] = time.process_time()
        self.observer.on_stage(index, STAGES[index])

    def done(self, index: int, jobs: dict[str, dict[str, Any]] | None = None) -> None:
        name = STAGES[index]
        self.seconds[name] = time.monotonic() - self.seconds[name]
        # Side-by-side jobs take as long as the slowest one on an idle machine.
        self.cpu[name] = time.process_time() - self.cpu[name]
        if jobs and self.processes > 1:  # in-process jobs are already in this process's CPU time
            self.cpu[name] += max(job["cpu_seconds"] for job in jobs.values())


def _train_stages(
    run_dir: Path,
    budget: QuickstartBudget,
    common: dict[str, Any],
    launch: Callable[[list[dict[str, Any]]], dict[str, dict[str, Any]]],
    clock: _StageClock,
) -> dict[str, dict[str, Any]]:
    """
    The two training stages: the workers side by side, then the manager (over the merged workers) and the
    flat DDPG side by side.

    :param launch: runs a list of training jobs (:func:`run_training_jobs`).
    :return: agent name -> its training job's result.
    """
    # Each worker's process writes workers/manifest.json with its own entry only; the merged manifest is
    # written once both are done.
    clock.start(0)
    worker_jobs = [
        {"kind": "worker", "name": name, "timesteps": budget.worker_timesteps, **common}
        for name in WORKER_ENV_IDS
    ]
    trained = launch(worker_jobs)
    clock.done(0, trained)
    manifest = models_manifest("workers", {name: trained[name]["entry"] for name in WORKER_ENV_IDS})
    save_manifest(run_dir / "workers" / "manifest.json", manifest)
    clock.start(1)
    managers: dict[str, dict[str, Any]] = {
        "manager": {**main_manager_options(budget), "config": str(run_dir / "config-dqn.yml")},
        "simplex manager": {"out_dir": str(run_dir / "simplex")},
    }
    jobs = []
    for name, options in managers.items():
        config = options.get("config", common["config"])
        option_steps = manager_option_steps(config, options.get("algo", "ddpg"))
        # HAM's decisions before RL are part of the manager's budget.
        start = options.get("init_from_ham")
        decisions = budget.manager_timesteps // option_steps - (start.decisions if start else 0)
        # SB3 counts a manager's steps, and its evaluation period, in decisions of option_steps env steps.
        jobs.append(
            {
                "kind": "manager",
                "name": name,
                **common,
                # SBX trains no DQN: that manager trains on SB3 whatever the other agents train on.
                "backend": backend_for(options.get("algo", "ddpg"), common["backend"]),
                "manager": options,
                "timesteps": max(1, decisions),
                "eval_freq": max(1, budget.eval_freq // option_steps),
                ENV_STEPS_PER_STEP: option_steps,
            }
        )
    jobs.append({"kind": "flat", "name": "flat-ddpg", "timesteps": flat_budget(budget), **common})
    second = launch(jobs)
    trained.update(second)
    clock.done(1, second)
    return trained


def _comparison_policies(
    run_dir: Path, files: dict[str, Path]
) -> tuple[dict[str, LoadedPolicy], dict[str, Path | str]]:
    """
    Every method compared, loaded with the loaders a user's ``hddpg-cli evaluate`` uses (hashes verified, no
    pickle); the HAM switch is written here (``files["ham"]``).

    :return: label -> the loaded policy, and label -> where it was loaded from.
    """
    sources: dict[str, Path | str] = {
        MAIN_HIERARCHY: run_dir / "hierarchy.zip",
        PAPER_HIERARCHY: run_dir / "simplex" / "hierarchy.zip",
    }
    files["ham"] = sources["HAM"] = _build_ham(run_dir)
    sources["flat DDPG"] = run_dir / "flat" / "flat-ddpg.zip"
    for name in WORKER_ENV_IDS:
        sources[f"{name} worker"] = run_dir / "workers" / f"{name}.zip"
    sources["scripted"] = "scripted"
    sources["random"] = "random"
    return {label: load_policy(source) for label, source in sources.items()}, sources


def _compare(
    policies: dict[str, LoadedPolicy],
    sources: dict[str, Path | str],
    trained: dict[str, dict[str, Any]],
    run_dir: Path,
    budget: QuickstartBudget,
    observer: QuickstartObserver,
) -> tuple[dict[str, dict[str, Any]], dict[str, dict[str, Any]]]:
    """
    Every method on the same seeds of the same env.

    :return: label -> its evaluation summary, and label -> facts about it (kind, source, training, episodes).
    """
    trained_by = {
        MAIN_HIERARCHY: ["goal", "avoid", "manager"],
        PAPER_HIERARCHY: ["goal", "avoid", "simplex manager"],
        "flat DDPG": ["flat-ddpg"],
    }
    trained_by.update({f"{n} worker": [n] for n in WORKER_ENV_IDS})
    summaries: dict[str, dict[str, Any]] = {}
    methods: dict[str, dict[str, Any]] = {}
    for label, result in _evaluate_on_shared_seeds(policies, budget.compare_episodes, observer).items():
        summary = result.summary()
        summary["std_reach_reward"] = float(np.std([e.reach_reward for e in result.episodes]))
        summaries[label] = summary
        agents = trained_by.get(label, [])
        methods[label] = {
            "kind": policies[label].kind,
            "source": str(_relative(sources[label], run_dir)),
            "train_timesteps": sum(trained[a]["timesteps"] for a in agents),
            "train_seconds": sum(trained[a]["seconds"] for a in agents),
            "episodes": [e.reach_reward for e in result.episodes],
        }
        if result.episodes[0].selections:  # a hierarchy: the episodes in which it called several workers
            both = [i for i, e in enumerate(result.episodes) if sum(n > 0 for n in e.selections.values()) > 1]
            methods[label]["switching_episodes"] = [EVAL_SEED_BASE + i for i in both]
    return summaries, methods


def _plot_figures(
    run_dir: Path,
    shown: tuple[QuickstartBudget, str],
    recording: RecordingResult,
    proximity: Proximity | None,
    names: list[str],
    summaries: dict[str, dict[str, Any]],
    files: dict[str, Path],
) -> None:
    """
    The selection timeline (titled by ``shown``), the learning curves (every curve over env steps) and the
    comparison.
    """
    budget, title = shown
    files["selection"] = plot_selection_timeline(
        recording.records,
        run_dir / "selection.png",
        names=names,
        title=title,
        sensor_range=proximity.sensor_range if proximity else None,
        touch_radius=proximity.touch_radius if proximity else None,
    )
    # A manager's history counts decisions.
    option_steps = {
        "manager": manager_option_steps(files["main_config"], MAIN_MANAGER["algo"]),
        "simplex manager": manager_option_steps(files["config"]),
    }
    curves = {
        "goal": run_dir / "evaluations" / "goal.json",
        "avoid": run_dir / "evaluations" / "avoid.json",
        "manager": run_dir / "evaluations" / "manager.json",
        "simplex manager": run_dir / "simplex" / "evaluations" / "manager.json",
        "flat-ddpg": run_dir / "evaluations" / "flat-ddpg.json",
    }
    # The main manager's RL starts after HAM's decisions, which are env steps of its budget too.
    ham_steps = {"manager": budget.ham_start_decisions * option_steps["manager"]}
    histories = {
        agent: [
            {**point, "timesteps": point["timesteps"] + ham_steps.get(agent, 0)}
            for point in read_history(path, option_steps.get(agent, 1))
        ]
        for agent, path in curves.items()
        if path.exists()
    }
    references = {
        f"{label} (untrained)": summaries[label]["mean_reach_reward"]
        for label in ("HAM", "scripted", "random")
        if label in summaries
    }
    last_compare_seed = EVAL_SEED_BASE + budget.compare_episodes - 1
    note = (
        f"Each point: the agent at that step, mean over {budget.eval_episodes} evaluation episodes (seeds "
        f"{EVAL_SEED_BASE}..{EVAL_SEED_BASE + budget.eval_episodes - 1}). Horizontal lines and the printed "
        f"table: {budget.compare_episodes} episodes (seeds {EVAL_SEED_BASE}..{last_compare_seed}); the table "
        "scores each agent's saved (best-evaluated) model, so a hierarchy's row need not equal its manager's "
        "last point."
    )
    files["learning_curves"] = plot_learning_curves(
        histories, run_dir / "learning_curves.png", references, note=note
    )
    files["comparison"] = plot_comparison(
        summaries,
        run_dir / "comparison.png",
        title=f"{SNAKE_REACH_ENV_ID}: {budget.compare_episodes} episodes per method, seeds "
        f"{EVAL_SEED_BASE}..{last_compare_seed}",
    )


def _write_zoo(run_dir: Path) -> Path:
    """The workers and the flat DDPG in RL Zoo's layout, each under the env it was trained on."""
    zoo_models: dict[str, str | Path] = {
        env: run_dir / "workers" / f"{n}.zip" for n, env in WORKER_ENV_IDS.items()
    }
    zoo_models[SNAKE_REACH_ENV_ID] = run_dir / "flat" / "flat-ddpg.zip"
    entries = read_workers_manifest(run_dir / "workers" / "manifest.json").entries
    zoo_env_kwargs = {
        env: entries[n].get("env_kwargs") or {} for n, env in WORKER_ENV_IDS.items() if n in entries
    }
    return write_zoo_layout(zoo_models, run_dir / "zoo", env_kwargs=zoo_env_kwargs)


def _evaluate_on_shared_seeds(
    policies: dict[str, LoadedPolicy], episodes: int, observer: QuickstartObserver
) -> dict[str, EvaluationResult]:
    """Every policy on the same ``episodes`` seeds of the comparison env, progress to ``observer``."""
    total_steps = len(policies) * episodes * _episode_steps()
    done_steps = 0

    def tick(_env: gym.Env, _info: dict[str, Any]) -> None:
        nonlocal done_steps
        done_steps += 1
        if done_steps % 50 == 0:
            observer.on_task("evaluation", done_steps, total_steps)

    results = {}
    for label, loaded in policies.items():
        env = loaded.make_env(SNAKE_REACH_ENV_ID)
        try:
            results[label] = evaluate(
                loaded.policy, env, n_episodes=episodes, seed=EVAL_SEED_BASE, on_step=tick
            )
        finally:
            env.close()
    observer.on_task("evaluation", total_steps, total_steps)
    return results


def _build_ham(run_dir: Path) -> Path:
    """Write the HAM switch over the run's workers to ``run_dir/ham.json``, with its default threshold."""
    return save_ham(
        run_dir / "ham.json",
        run_dir / "workers" / "manifest.json",
        threshold=ham_threshold(),
        metadata={"made_by": "quickstart"},
    )


def _episode_steps() -> int:
    return MAX_EPISODE_STEPS


def _relative(path: Path | str, root: Path) -> Path:
    path = Path(path)
    try:
        return path.relative_to(root)
    except ValueError:
        return path
