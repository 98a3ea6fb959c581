"""The run-control settings every training function shares (budget, seed, envs, resume, evaluation...)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from sb3_hddpg.artifacts.limits import MAX_SEED
from sb3_hddpg.artifacts.values import RUN_SETTINGS
from sb3_hddpg.evaluation import EVAL_SEED_BASE


@dataclass(frozen=True)
class RunOptions:
    """
    The run-control settings of one training run, checked when built.

    :param timesteps: the total budget (default: the config block's ``n_timesteps``).
    :param seed: seeds the model, the training envs and the exploration noise.
    :param n_envs: parallel training envs, run in subprocesses when more than one (default: the config's).
    :param resume: continue from the last checkpoint to ``timesteps`` in total.
    :param stop_on_plateau: stop when ``plateau_patience`` evaluations in a row bring no new best.
    :param plateau_patience: see ``stop_on_plateau``.
    :param eval_freq: environment steps between evaluations (0: none until the end).
    :param eval_episodes: episodes per evaluation.
    :param eval_seed: first seed of the fixed evaluation episodes.
    :param checkpoint_freq: environment steps between resumable checkpoints (0: only at interrupts and at
        the end).
    :param keep_best: save the best evaluated model as the result (else the final one).
    :param progress_bar: show SB3's rich progress bar.
    :param threads: torch threads for this process (1 is fastest for small MLPs on CPU; see docs).
    :param keep_checkpoints: keep the replay buffer in the last checkpoint of a finished run (70 MB for a
        worker of the bundled config), so that a later ``resume`` continues exactly as if never stopped;
        without it resuming refills the buffer first. Interrupted runs always keep theirs.
    :param backend: ``sb3`` or ``sbx`` (default: the config block's ``backend``, else ``sb3``); the saved
        model is an SB3 zip either way.
    """

    timesteps: int | None = None
    seed: int = 0
    n_envs: int | None = None
    resume: bool = False
    stop_on_plateau: bool = False
    plateau_patience: int = 3
    eval_freq: int = 5000
    eval_episodes: int = 5
    eval_seed: int = EVAL_SEED_BASE
    checkpoint_freq: int = 10_000
    keep_best: bool = True
    progress_bar: bool = False
    threads: int = 1
    keep_checkpoints: bool = False
    backend: str | None = None

    def __post_init__(self) -> None:
        for name, bound in RUN_SETTINGS.items():
            value = getattr(self, name)
            if value is not None:
                object.__setattr__(self, name, bound.check(value, name))
        if not 0 <= self.seed <= MAX_SEED:
            raise ValueError(f"Expected seed in [0, {MAX_SEED}], actually: {self.seed}")

    def replace(self, **changes: Any) -> RunOptions:
        """A copy with ``changes`` (field name -> value), checked as a new one is."""
        return dataclasses.replace(self, **changes)


#: The field names of :class:`RunOptions`, which the training functions also take as keywords.
RUN_OPTION_NAMES = frozenset(field.name for field in dataclasses.fields(RunOptions))


def run_options(run: RunOptions | None, changes: dict[str, Any], caller: str) -> RunOptions:
    """
    ``run`` (default: :class:`RunOptions`'s defaults) with the fields given as keywords on top, so that
    ``train_workers(out, seed=3)`` and ``train_workers(out, run=RunOptions(seed=3))`` mean the same.

    :param run: the options passed as one object, if any.
    :param changes: the function's other keyword arguments, each a :class:`RunOptions` field.
    :param caller: the function's name, for the error on a keyword that is not a field.
    """
    unknown = sorted(set(changes) - RUN_OPTION_NAMES)
    if unknown:
        raise TypeError(f"{caller}() got an unexpected keyword argument {unknown[0]!r}")
    base = run if run is not None else RunOptions()
    return base.replace(**changes) if changes else base
