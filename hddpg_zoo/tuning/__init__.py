"""
Hyperparameter tuning with Optuna at every level: a worker, the manager, the flat baseline, and HAM's switch.

One trial samples a ``zoo_configs`` block with :func:`~hddpg_zoo.hyperparams_opt.sampler_for` (one sampler per
level; per algorithm for the levels that train one, as its record names), trains it with :func:`~sb3_hddpg.training.agent.train_agent` (the same code as ``train-*``), reports ``n_evaluations``
evaluations to the pruner through :class:`~hddpg_zoo.tuning.pruning.TrialPruningCallback`, and returns the last
evaluation's mean reward (rl_zoo3's objective: the best of several noisy evaluations would favour lucky
configurations). Which trial is *best* is a separate choice (:data:`RANKINGS`): by that value, or by the
trial's best evaluation, the checkpoint every ``train-*`` command keeps. A policy stuck on one constant
action scores the same at every evaluation, and can win the first ranking by a point over one that
learns and swings. A trial that diverges (NaN reward or weights, or an exception about NaN) is pruned, not
failed: it is a bad configuration, not a bug. HAM trains nothing: its trial is one evaluation.

:func:`tune` runs ``n_jobs`` processes (not threads: training holds the GIL between torch calls) on one
study in a shared storage (see :mod:`hddpg_zoo.study_storage`). ``n_trials`` is the *study's* target of
finished (complete or pruned) trials, so a re-run after an interruption completes the same study, and any
number of processes, on any number of machines, together finish exactly that many.

The package follows a study's parts, each a module: :mod:`.target` (what is tuned, each trial's env),
:mod:`.study` (settings, sampler, pruner, the trial processes), :mod:`.trial` (the objective) and
:mod:`.results` (rankings, the best config, plots); it re-exports their public names.
"""

from hddpg_zoo.tuning.results import (
    RANKINGS,
    best_block,
    best_trials,
    save_best_config,
    save_plots,
    trial_counts,
    trial_score,
)
from hddpg_zoo.tuning.study import (
    FINISHED_STATES,
    PRUNERS,
    SAMPLERS,
    StudySettings,
    enqueue_base_trial,
    make_pruner,
    make_sampler,
    open_study,
    run_trials,
    tune,
)
from hddpg_zoo.tuning.target import (
    HAM_COMPONENT,
    LEVELS,
    TargetError,
    TuningTarget,
    check_budget_fraction,
    merge_block,
)
from hddpg_zoo.tuning.trial import objective

__all__ = [
    "FINISHED_STATES",
    "HAM_COMPONENT",
    "LEVELS",
    "PRUNERS",
    "RANKINGS",
    "SAMPLERS",
    "StudySettings",
    "TargetError",
    "TuningTarget",
    "best_block",
    "best_trials",
    "check_budget_fraction",
    "enqueue_base_trial",
    "make_pruner",
    "make_sampler",
    "merge_block",
    "objective",
    "open_study",
    "run_trials",
    "save_best_config",
    "save_plots",
    "trial_counts",
    "trial_score",
    "tune",
]
