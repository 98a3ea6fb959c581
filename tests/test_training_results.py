"""``train_workers``, ``train_flat`` and ``train_manager`` each return one typed result and take ``callback=``."""

from __future__ import annotations

from stable_baselines3.common.callbacks import BaseCallback

from sb3_hddpg.training.flat import FlatResult, train_flat
from sb3_hddpg.training.manager import ManagerResult, train_manager
from sb3_hddpg.training.manager_setup import ManagerOptions
from sb3_hddpg.training.workers import WorkersResult, train_workers

QUICK = {"timesteps": 60, "eval_freq": 0, "eval_episodes": 1, "checkpoint_freq": 0}


class StepCounter(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.steps = 0

    def _on_step(self) -> bool:
        self.steps += 1
        return True


def test_each_training_function_returns_its_record_and_runs_the_callbacks_given(tmp_path):
    counter, calls = StepCounter(), []

    def count(local_vars, global_vars) -> bool:
        calls.append(local_vars["self"].num_timesteps)
        return True

    workers = train_workers(tmp_path / "w", seed=1, callback=[counter, count], **QUICK)
    assert isinstance(workers, WorkersResult)
    assert (
        workers.manifest_path == tmp_path / "w" / "workers" / "manifest.json"
        and workers.manifest_path.is_file()
    )
    assert set(workers.outcomes) == set(workers.manifest["workers"]) == {"goal", "avoid"}
    trained = sum(outcome.num_timesteps for outcome in workers.outcomes.values())
    assert counter.steps == len(calls) == trained >= 2 * QUICK["timesteps"]  # every env step of both workers
    # On resume a finished worker is kept: it is in the manifest, with no outcome of this call.
    assert train_workers(tmp_path / "w", seed=1, resume=True, **QUICK).outcomes == {}

    flat = train_flat(tmp_path / "f", seed=1, callback=counter, **QUICK)
    assert isinstance(flat, FlatResult) and flat.model_path == tmp_path / "f" / "flat" / "ddpg.zip"
    assert flat.outcome is not None and flat.outcome.num_timesteps >= QUICK["timesteps"]
    assert counter.steps == trained + flat.outcome.num_timesteps
    assert train_flat(tmp_path / "f", seed=1, resume=True, **QUICK).outcome is None

    manager = train_manager(
        tmp_path / "w",
        tmp_path / "m",
        ManagerOptions(prefer="goal"),
        option_steps=2,
        seed=1,
        callback=count,
        **QUICK,
    )
    assert isinstance(manager, ManagerResult) and manager.path == tmp_path / "m" / "hierarchy.zip"
    assert (
        manager.hierarchy.preferences == {"goal": 1.15, "avoid": 1.0}
        and manager.hierarchy.config.option_steps == 2
    )
    assert len(calls) == trained + manager.outcome.num_timesteps
