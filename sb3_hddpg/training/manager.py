"""
Training the manager: a plain SB3 model on ``WorkerSelectionWrapper`` over pre-trained workers (paper
Algorithm 1, second half), saved as a hierarchy bundle.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, cast

from stable_baselines3.common.type_aliases import MaybeCallback

from sb3_hddpg.artifacts.io import atomic_write_json
from sb3_hddpg.artifacts.limits import read_json_file
from sb3_hddpg.artifacts.manifests import as_json, check_resumed_env
from sb3_hddpg.artifacts.run_folder import holds_run_folder
from sb3_hddpg.callbacks.checkpoint import read_checkpoint_state
from sb3_hddpg.callbacks.selection_stats import SelectionStatsCallback
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.training.agent import AgentPaths, TrainingOutcome, agent_run, callback_list, train_agent
from sb3_hddpg.training.imitation_start import HamStart, start_hook
from sb3_hddpg.training.manager_setup import (
    MANAGER_OPTION_NAMES,
    ManagerOptions,
    ManagerSetup,
    manager_options,
    setup_manager,
)
from sb3_hddpg.training.run_options import RunOptions, run_options

#: The manager's env and selection settings, kept beside its model so that a resumed run continues on the
#: same MDP.
MANAGER_SETTINGS_FILE = "manager_settings.json"


def _check_manager_resume(paths: AgentPaths, resume: bool, setup: ManagerSetup) -> None:
    """
    Keep the manager's MDP (env, workers, algorithm, selection settings) and its learner's settings (less
    the budget, which a resume may extend) beside its model; a resumed run whose MDP or learner differs is
    refused in one line naming the difference, since its replay buffer and network were made on the
    recorded ones.
    """
    block = setup.hyperparams
    noise = [block.noise_type, block.noise_std]
    learner = {"algo_kwargs": block.algo_kwargs, "policy": block.policy, "noise": noise}
    mdp: dict[str, Any] = {
        **setup.env_kwargs,
        "workers": list(setup.workers),
        "algo": setup.algo,
        "selection": asdict(setup.selection),
        "learner": cast(dict[str, Any], as_json(learner)),
    }
    path = paths.model_path.parent / MANAGER_SETTINGS_FILE
    if resume and read_checkpoint_state(paths.checkpoint_dir) is not None and path.is_file():
        stored = read_json_file(path)
        recorded = stored.get("env_kwargs") if isinstance(stored, dict) else None
        if isinstance(recorded, dict) and "learner" not in recorded:
            # A folder that does not record the learner's settings is compared on what it records.
            del mdp["learner"]
        check_resumed_env(stored, setup.env_id, mdp)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, {"env_id": setup.env_id, "env_kwargs": mdp})


@dataclass(frozen=True)
class ManagerResult:
    """
    What :func:`train_manager` made.

    :param hierarchy: the trained manager over its workers, as saved.
    :param path: the bundle's file (``out_dir/hierarchy.zip``).
    :param outcome: the manager's training outcome.
    """

    hierarchy: Hierarchy
    path: Path
    outcome: TrainingOutcome


@holds_run_folder(lambda call: call.arguments["out_dir"], "train_manager")
def train_manager(
    workers_dir: str | Path | ManagerSetup,
    out_dir: str | Path,
    options: ManagerOptions | None = None,
    *,
    run: RunOptions | None = None,
    callback: MaybeCallback = None,
    **changes: Any,
) -> ManagerResult:
    """
    Train the manager: a plain SB3 model on ``WorkerSelectionWrapper`` over pre-trained workers (paper
    Algorithm 1, second half), and write ``out_dir/hierarchy.zip``.

    :param workers_dir: the run folder of ``train-workers`` (or its ``workers`` folder), or the set-up
        :func:`~sb3_hddpg.training.manager_setup.prepare_manager` returned (then no manager options).
    :param out_dir: the run folder for the manager.
    :param options: what the manager is trained from
        (:class:`~sb3_hddpg.training.manager_setup.ManagerOptions`; default: its defaults).
    :param run: the run-control settings (:class:`~sb3_hddpg.training.run_options.RunOptions`).
    :param callback: more SB3 callbacks, as SB3's ``learn`` takes them.
    :param changes: fields of ``ManagerOptions`` or of ``RunOptions`` as keywords, over ``options``' and
        ``run``'s (``train_manager(w, out, prefer="goal", seed=3)``).
    :return: the saved hierarchy, its file and the training outcome.
    """
    manager_changes = {name: value for name, value in changes.items() if name in MANAGER_OPTION_NAMES}
    run = run_options(run, {k: v for k, v in changes.items() if k not in manager_changes}, "train_manager")
    setup = _setup_of(workers_dir, options, manager_changes)
    out_dir = Path(out_dir)
    paths = AgentPaths(out_dir, "manager", out_dir / "manager" / "manager.zip")
    _check_manager_resume(paths, run.resume, setup)
    factory = setup.env_factory()
    start_report: dict[str, Any] = {}
    outcome = train_agent(
        factory,
        setup.hyperparams,
        paths,
        algo=setup.algo,
        run=agent_run(run, paths, run.timesteps),
        callback=[SelectionStatsCallback(), *callback_list(callback)],
        prepare_model=(
            start_hook(setup.start, factory, run.seed, start_report, setup.workers.critics)
            if setup.start is not None
            else None
        ),
    )
    hierarchy = _manager_bundle(setup, outcome, run.seed, start_report)
    return ManagerResult(hierarchy, hierarchy.save(out_dir / "hierarchy.zip"), outcome)


def start_key(start: object) -> str:
    """The bundle metadata's key for a manager's start: ``init_from_ham`` or ``init_from_gpi``."""
    return "init_from_ham" if isinstance(start, HamStart) else "init_from_gpi"


def _setup_of(
    workers_dir: str | Path | ManagerSetup, options: ManagerOptions | None, changes: dict[str, Any]
) -> ManagerSetup:
    """The manager's set-up: the one given (then no options may be), else prepared from the options given."""
    if not isinstance(workers_dir, ManagerSetup):
        return setup_manager(workers_dir, manager_options(options, changes, "train_manager"))
    given = sorted(name for name, value in changes.items() if value is not None)
    if options is not None or given:
        raise ValueError(
            f"train_manager got a prepared set-up and also {given or 'options'}: give those to prepare_manager"
        )
    return workers_dir


def _manager_bundle(
    setup: ManagerSetup, outcome: TrainingOutcome, seed: int, start_report: dict[str, Any]
) -> Hierarchy:
    """The trained manager over its workers as a hierarchy, its metadata saying how it was trained."""
    return Hierarchy(
        outcome.model,
        setup.workers,
        setup.selection,
        env_id=setup.env_id,
        env_kwargs=setup.env_kwargs,
        worker_meta=setup.workers.bundle_meta(),
        metadata={
            "seed": seed,
            "timesteps_trained": outcome.num_timesteps,
            "config": setup.hyperparams.raw,
            "metrics": outcome.metrics,
            "backend": outcome.backend,
            **({start_key(setup.start): start_report} if start_report else {}),
        },
    )
