"""
Training the manager: a plain SB3 model on ``WorkerSelectionWrapper`` over pre-trained workers (paper
Algorithm 1, second half), saved as a hierarchy bundle.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from sb3_hddpg.artifacts.io import (
    atomic_write_json,
    holds_folder_lock,
)
from sb3_hddpg.artifacts.limits import read_json_file
from sb3_hddpg.artifacts.manifests import check_resumed_env
from sb3_hddpg.callbacks.checkpoint import read_checkpoint_state
from sb3_hddpg.callbacks.selection_stats import SelectionStatsCallback
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.selection import OptionEnd
from sb3_hddpg.training.agent import AgentPaths, TrainingOutcome, agent_run, train_agent
from sb3_hddpg.training.ham_start import HamStart, ham_start_hook
from sb3_hddpg.training.manager_setup import ManagerSetup, prepare_manager
from sb3_hddpg.training.run_options import RunOptions, run_options

#: The manager's env and selection settings, kept beside its model so that a resumed run continues on the
#: same MDP.
MANAGER_SETTINGS_FILE = "manager_settings.json"


def _check_manager_resume(
    paths: AgentPaths, resume: bool, setup: ManagerSetup, selection: dict[str, Any]
) -> None:
    """
    Keep the manager's MDP (env, workers, algorithm, selection settings) beside its model; a resumed
    run whose MDP differs is refused in one line naming the difference
    (:func:`~sb3_hddpg.artifacts.manifests.check_resumed_env`), since its replay buffer and network were
    made on the recorded one.
    """
    mdp: dict[str, Any] = {
        **setup.env_kwargs,
        "workers": list(setup.workers),
        "algo": setup.algo,
        "selection": selection,
    }
    path = paths.model_path.parent / MANAGER_SETTINGS_FILE
    if resume and read_checkpoint_state(paths.checkpoint_dir) is not None and path.is_file():
        check_resumed_env(read_json_file(path), setup.env_id, mdp)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, {"env_id": setup.env_id, "env_kwargs": mdp})


@holds_folder_lock(lambda call: call.arguments["out_dir"])
def train_manager(
    workers_dir: str | Path | ManagerSetup,
    out_dir: str | Path,
    worker_names: Sequence[str] | None = None,
    prefer: str | None = None,
    bias: float | None = None,
    preferences: dict[str, float] | None = None,
    selection: str | None = None,
    option_steps: int | None = None,
    temperature: float | None = None,
    floor: float | None = None,
    config: str | Path | None = None,
    trusted: bool | None = None,
    env_id: str | None = None,
    env_kwargs: dict[str, Any] | None = None,
    algo: str | None = None,
    manager_preferences: str | PreferenceSpace | None = None,
    relabel_fraction: float | None = None,
    init_from_ham: float | HamStart | None = None,
    option_end: str | OptionEnd | None = None,
    *,
    run: RunOptions | None = None,
    extra_callbacks: Sequence[BaseCallback] = (),
    **run_changes: Any,
) -> tuple[Any, TrainingOutcome]:
    """
    Train the manager: a plain SB3 DDPG (or TD3 or SAC, ``algo``) on ``WorkerSelectionWrapper`` over
    pre-trained workers (paper Algorithm 1, second half), and write ``out_dir/hierarchy.zip``.

    Preference factors (paper Section 3.4): by default every worker's factor is 1; ``prefer=NAME`` makes
    that worker's ``1 + bias`` (the paper's 15 % by default); ``preferences`` sets every factor explicitly
    and wins over ``prefer``. A factor multiplies the worker's normalised reward term in the manager's
    reward, so the manager is paid more for the preferred worker's objective.

    :param workers_dir: the run folder of ``train-workers`` (or its ``workers`` folder), or the set-up
        :func:`prepare_manager` returned: then the workers it loaded are used as they are (nothing is loaded
        or checked twice) and the arguments of :func:`prepare_manager` below must be left out.
    :param out_dir: the run folder for the manager.
    :param worker_names: which workers, in the manager's action order (default: all in the manifest).
    :param prefer: a worker to prefer.
    :param bias: the preferred worker's extra factor, > 0 (default 0.15).
    :param preferences: explicit factors, name -> value.
    :param selection: a registered selection mode (default: the config's ``wrapper_kwargs``).
    :param option_steps: env steps per manager decision (default: the config's).
    :param temperature: the simplex map's temperature (default: the config's).
    :param floor: the probability floor (default: the config's).
    :param config: a ``zoo_configs`` file; its ``manager`` block is used.
    :param trusted: load the workers with SB3's full loader (default ``False``).
    :param env_id: the shared env the manager acts in (default: the workers manifest's ``shared_env``,
        else ``hddpg/SnakeReach-v0``).
    :param env_kwargs: its keyword arguments (default: the manifest's, with the config block's on top).
    :param algo: the manager's algorithm, one of :data:`MANAGER_ALGOS` (default ``ddpg``, the paper's);
        its bundled config ``zoo_configs/<algo>.yml`` is the default ``config``.
    :param manager_preferences: train one manager for every preference (see
        :class:`~sb3_hddpg.hierarchy.conditioning.PreferenceSpace`): ``"ratio-sweep"``,
        ``"dirichlet[:ALPHA]"``, ``"goal=1.6,avoid=0.4;goal=0.4,avoid=1.6"`` or a space. The manager observes
        the normalised preference weights, a preference is drawn every episode, and an off-policy manager
        replays stored steps at other preferences (``PreferenceRelabelingReplayBuffer``). The bundle records
        the space (``selection.manager_preferences``); ``Hierarchy.set_preference`` picks one at run time.
        ``preferences`` is then the one the bundle acts at first (default: the unweighted one).
    :param relabel_fraction: a conditioned off-policy manager's share of replayed steps given another
        preference (default 0.5).
    :param init_from_ham: start from the hand-written rule: HAM's threshold (or a
        :class:`~sb3_hddpg.training.ham_start.HamStart`); the manager imitates HAM's choices and its replay
        buffer is filled with them before RL (:mod:`sb3_hddpg.training.ham_start`). The bundle's metadata
        keeps the settings and how often the fitted manager agrees with HAM.
    :param option_end: options that also end by state: ``"distance=0.5"`` (an obstacle comes within half
        the sensor range or leaves it), ``"touch"`` (the goal is touched or lost), both (``"distance=0.5,touch"``)
        or an :class:`~sb3_hddpg.hierarchy.selection.OptionEnd`; ``option_steps`` stays the longest option.
    :param run: the run-control settings (:class:`~sb3_hddpg.training.run_options.RunOptions`) for the manager's DDPG; the bundle holds an SB3 manager whichever ``backend`` trains it.
    :param run_changes: :class:`~sb3_hddpg.training.run_options.RunOptions` fields as keywords (e.g.
        ``seed=3``), over ``run``'s.
    :param extra_callbacks: more SB3 callbacks (e.g. progress reporting).
    :return: the saved :class:`~sb3_hddpg.hierarchy.hierarchy.Hierarchy` and the training outcome.
    """
    run = run_options(run, run_changes, "train_manager")
    preparation: dict[str, Any] = {
        key: value
        for key, value in (
            ("worker_names", worker_names),
            ("prefer", prefer),
            ("bias", bias),
            ("preferences", preferences),
            ("selection", selection),
            ("option_steps", option_steps),
            ("temperature", temperature),
            ("floor", floor),
            ("config", config),
            ("trusted", trusted),
            ("env_id", env_id),
            ("env_kwargs", env_kwargs),
            ("algo", algo),
            ("manager_preferences", manager_preferences),
            ("relabel_fraction", relabel_fraction),
            ("init_from_ham", init_from_ham),
            ("option_end", option_end),
        )
        if value is not None
    }
    if isinstance(workers_dir, ManagerSetup):
        if preparation:
            raise ValueError(
                f"train_manager got a prepared set-up and also {sorted(preparation)}: give those to prepare_manager"
            )
        setup = workers_dir
    else:
        setup = prepare_manager(workers_dir, **preparation)
    workers = setup.workers
    hyperparams, selection_config, env_kwargs = setup.hyperparams, setup.selection, setup.env_kwargs
    factory = setup.env_factory()
    out_dir = Path(out_dir)
    paths = AgentPaths(out_dir, "manager", out_dir / "manager" / "manager.zip")
    _check_manager_resume(paths, run.resume, setup, asdict(selection_config))
    ham_report: dict[str, Any] = {}
    outcome = train_agent(
        factory,
        hyperparams,
        paths,
        algo=setup.algo,
        run=agent_run(run, paths, run.timesteps),
        extra_callbacks=[SelectionStatsCallback(), *extra_callbacks],
        prepare_model=(
            ham_start_hook(setup.ham_start, factory, run.seed, ham_report)
            if setup.ham_start is not None
            else None
        ),
    )
    hierarchy = Hierarchy(
        outcome.model,
        workers,
        selection_config,
        env_id=setup.env_id,
        env_kwargs=env_kwargs,
        worker_meta=workers.bundle_meta(),
        metadata={
            "seed": run.seed,
            "timesteps_trained": outcome.num_timesteps,
            "config": hyperparams.raw,
            "metrics": outcome.metrics,
            "backend": outcome.backend,
            **({"init_from_ham": ham_report} if ham_report else {}),
        },
    )
    hierarchy.save(out_dir / "hierarchy.zip")
    return hierarchy, outcome
