"""
The quickstart's training jobs: each agent trained in a process of the runner (or a Ray task), its progress
relayed to the quickstart's observer in env steps.
"""

from __future__ import annotations

import time
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from hddpg_zoo.agent_settings import manager_option_steps
from hddpg_zoo.executors import make_executor
from hddpg_zoo.runner import Job, report_progress, run_jobs
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.training.flat import train_flat
from sb3_hddpg.training.imitation_start import HamStart
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.run_options import RunOptions
from sb3_hddpg.training.workers import train_workers


class QuickstartObserver:
    """
    What :func:`run_quickstart` reports while it runs; every method does nothing here. The CLI subclasses it
    with rich progress bars.
    """

    def on_stage(self, index: int, name: str) -> None:
        """Stage ``index`` (of :data:`STAGES`) starts."""

    def on_task(self, task: str, completed: float, total: float) -> None:
        """A task of the current stage (an agent's training, an evaluation) has done ``completed`` of ``total``."""

    def on_message(self, message: str) -> None:
        """Something worth a line: an agent finished, a file was written."""


# ---------------------------------------------------------------------------------------- child processes
class _ProgressReporter(BaseCallback):
    """Reports the step count at most every ``interval`` seconds (and at the end) to the runner."""

    def __init__(self, interval: float = 0.5) -> None:
        super().__init__()
        self.interval = interval
        self._last = 0.0

    def _on_step(self) -> bool:
        now = time.monotonic()
        if now - self._last >= self.interval:
            self._last = now
            report_progress(int(self.num_timesteps))
        return True

    def _on_training_end(self) -> None:
        report_progress(int(self.num_timesteps))


def _train_job(
    kind: str,
    name: str,
    run_dir: str,
    config: str,
    timesteps: int,
    seed: int,
    eval_freq: int,
    eval_episodes: int,
    keep_checkpoints: bool = False,
    backend: str = "sb3",
    manager: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """
    Train one agent (``kind``: worker, manager or flat); runs in a process of the runner.

    :param manager: a manager's own options: ``out_dir`` (its run folder, default ``run_dir``), ``config`` (its
        config file, default ``config``) and :func:`~sb3_hddpg.training.manager.train_manager`'s options
        (``algo``, ``manager_preferences``...).
    """

    started, cpu_started = time.monotonic(), time.process_time()
    run = RunOptions(
        timesteps=timesteps,
        seed=seed,
        eval_freq=eval_freq,
        eval_episodes=eval_episodes,
        keep_checkpoints=keep_checkpoints,
        backend=backend,
    )
    common: dict[str, Any] = dict(config=config, run=run, callback=_ProgressReporter())
    if kind == "worker":
        # The paper's DDPG for every worker: the quickstart's config is the bundled ddpg.yml, and its zoo/
        # layout serves each worker to `rl_zoo3.enjoy --algo ddpg`.
        workers = train_workers(run_dir, workers=[name], algos={name: "ddpg"}, **common)
        out: dict[str, Any] = {"entry": workers.manifest["workers"][name]}
        steps = out["entry"]["timesteps_trained"]
    elif kind == "manager":
        options = dict(manager or {})
        out_dir = options.pop("out_dir", run_dir)
        common["config"] = options.pop("config", config)
        outcome = train_manager(run_dir, out_dir, **options, **common).outcome
        # Env steps, as every other agent's: each decision runs option_steps of them, HAM's before RL too.
        start = options.get("init_from_ham")
        decisions = outcome.num_timesteps + (start.decisions if isinstance(start, HamStart) else 0)
        steps = decisions * manager_option_steps(common["config"], options.get("algo", "ddpg"))
        out = {"metrics": outcome.metrics}
    else:
        # The single-DDPG baseline on the comparison env (both terms, normalised and summed).
        flat = train_flat(run_dir, algo="ddpg", name=name, env_id=SNAKE_REACH_ENV_ID, **common)
        out = flat.manifest["models"][name]
        steps = out["timesteps_trained"]
    out.update(
        {
            "timesteps": int(steps),
            "seconds": time.monotonic() - started,
            # CPU time: what the job needs on an idle core, whatever else shares the machine.
            "cpu_seconds": time.process_time() - cpu_started,
        }
    )
    return out


#: A training job's env steps per SB3 step (the manager's: its option steps), for progress in env steps.
ENV_STEPS_PER_STEP = "env_steps_per_step"


def run_training_jobs(
    jobs: list[dict[str, Any]],
    processes: int,
    observer: QuickstartObserver,
    ray_address: str | None = None,
) -> dict[str, dict[str, Any]]:
    """
    Run training jobs on the process runner, ``processes`` at a time (in this process when 1, or as Ray
    tasks on the cluster at ``ray_address``), relaying their progress to ``observer`` in env steps (a job's
    ``env_steps_per_step``: the manager's SB3 steps are decisions of several env steps); the first failure
    is re-raised.
    """
    scale = {job["name"]: int(job.get(ENV_STEPS_PER_STEP, 1)) for job in jobs}
    totals = {job["name"]: job["timesteps"] * scale[job["name"]] for job in jobs}
    for name, total in totals.items():
        observer.on_task(name, 0, total)

    def progress(name: str, steps: float) -> None:
        observer.on_task(name, min(steps * scale[name], totals[name]), totals[name])

    def event(kind: str, job: Job, result: Any) -> None:
        if kind == "done":
            observer.on_task(job.key, totals[job.key], totals[job.key])
            observer.on_message(f"{job.key}: {result['timesteps']:,} env steps in {result['seconds']:.0f} s")

    def arguments(job: dict[str, Any]) -> dict[str, Any]:
        return {key: value for key, value in job.items() if key != ENV_STEPS_PER_STEP}

    outcome = run_jobs(
        [Job(job["name"], _train_job, kwargs=arguments(job), cost=totals[job["name"]]) for job in jobs],
        # A stopped quickstart is not resumed: a running job is left to end however it ends.
        make_executor(
            min(processes, len(jobs)),
            interrupt_grace=None,
            inline=processes <= 1,
            ray_address=ray_address,
        ),
        on_event=event,
        on_progress=progress,
        fail_fast=True,
    )
    return outcome.results
