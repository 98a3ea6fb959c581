"""What a study found: trial counts, rankings, the best block as a config file, and Optuna's plots."""

from __future__ import annotations

import datetime
import functools
import importlib.util
import math
import re
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import optuna
import yaml
from optuna.trial import FrozenTrial, TrialState

from hddpg_zoo.study_storage import quiet_experimental
from hddpg_zoo.tuning.target import TuningTarget, merge_block
from sb3_hddpg.artifacts.io import atomic_write_bytes
from sb3_hddpg.artifacts.limits import MAX_JSON_BYTES, read_file_bytes
from sb3_hddpg.extras import INSTALL_EXTRA
from sb3_hddpg.training.config import MANAGER_KEY, load_config_file, load_hyperparams

#: How :func:`best_trials` ranks completed trials: ``last`` by the Optuna value, a trial's last evaluation
#: (rl_zoo3's objective); ``peak`` by its best evaluation, the checkpoint that ``train-*`` and the benchmark
#: keep. HAM's trial is one evaluation: both are the same there.
RANKINGS = ("last", "peak")


def trial_counts(study: optuna.Study) -> dict[str, int]:
    """How many trials are in each state, e.g. ``{"COMPLETE": 18, "PRUNED": 2}``."""
    counts: dict[str, int] = {}
    for trial in study.get_trials(deepcopy=False):
        counts[trial.state.name] = counts.get(trial.state.name, 0) + 1
    return counts


def trial_score(trial: FrozenTrial, rank_by: str = "last") -> float:
    """
    A completed trial's score under ``rank_by`` (see :data:`RANKINGS`): its value, or its best reported
    evaluation (its value when it reported none).
    """
    if rank_by not in RANKINGS:
        raise ValueError(f"Unknown ranking {rank_by!r}; choose from {list(RANKINGS)}")
    value = trial.value if trial.value is not None else -math.inf
    if rank_by == "peak":
        peaks = trial.user_attrs.get("seed_peaks")
        if peaks:  # each seed's best evaluation, averaged: not the luckiest seed's best
            return float(np.mean(peaks))
        return max([value, *trial.intermediate_values.values()])
    return value


def best_trials(study: optuna.Study, k: int = 5, rank_by: str = "last") -> list[FrozenTrial]:
    """The ``k`` best completed trials under ``rank_by`` (:data:`RANKINGS`), best first."""
    completed = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    return sorted(completed, key=lambda t: trial_score(t, rank_by), reverse=True)[:k]


def best_block(study: optuna.Study, target: TuningTarget, rank_by: str = "last") -> dict[str, Any]:
    """
    The best trial's config block: the base block with the best parameters, rebuilt by replaying the
    level's sampler on ``optuna.trial.FixedTrial(best.params)``.

    :param study: a study with at least one completed trial.
    :param target: what was tuned (not HAM, which has no block).
    :param rank_by: which trial is best (:data:`RANKINGS`).
    """
    if target.level == "ham":
        raise ValueError("HAM has no DDPG hyperparameters to save; its best threshold is in the study")
    best = best_trials(study, 1, rank_by)
    if not best:
        raise ValueError(f"Study {study.study_name!r} has no completed trial yet: no best parameters")
    changes = target.sampler(optuna.trial.FixedTrial(best[0].params))
    return merge_block(target.base_block(), changes)


def save_best_config(
    study: optuna.Study, target: TuningTarget, path: str | Path, rank_by: str = "last"
) -> Path:
    """
    Write the best parameters as a ``zoo_configs`` file that ``train-workers``, ``train-manager`` and
    ``train-flat --config`` accept as is.

    If ``path`` exists, only the tuned block's lines are replaced, every other line (comments included) kept
    as it was (so tuning ``goal`` and then ``avoid`` into one file collects both); otherwise the file starts as a copy of the base config, so that every other block
    (``default``, the other workers, ``manager``) is still there.

    :param study: the tuned study.
    :param target: what was tuned.
    :param path: the YAML file to write.
    :param rank_by: which trial is best (:data:`RANKINGS`).
    :return: the path written.
    """
    path = Path(path)
    if path.is_symlink():
        raise ValueError(f"--save-config: {str(path)!r} is a symbolic link; name the file itself")
    block = best_block(study, target, rank_by)
    key = str(target.block_key)
    best = best_trials(study, 1, rank_by)[0]
    which = "last" if rank_by == "last" else "best"
    note = (
        f"{TUNED_NOTE} block {key!r} from study {study.study_name!r}, trial {best.number}, {which} mean "
        f"evaluation reward {trial_score(best, rank_by):.4g} in {target.budget()} steps "
        f"({datetime.datetime.now().isoformat(timespec='seconds')})\n"
    )
    tuned = note + yaml.safe_dump({key: block}, sort_keys=False, default_flow_style=False)
    if path.exists():
        old = load_config_file(path)
        text = replace_block(read_file_bytes(path, MAX_JSON_BYTES).decode("utf-8"), key, tuned)
        check_only_block_changed(old, text, key, str(path))
    else:
        config = load_config_file(target.config_path)
        config[key] = block
        header = f"# RL Zoo format (zoo_configs/{target.algo}.yml), from {target.config_path.name}.\n"
        text = header + replace_block(
            yaml.safe_dump(config, sort_keys=False, default_flow_style=False), key, tuned
        )
    atomic_write_bytes(path, text.encode())
    # What we promise: the commands read it back as written.
    load_hyperparams(key, target.algo_class, path, manager=key == MANAGER_KEY)
    return path


#: The comment line the tuned block carries (and that the next ``--save-config`` replaces with it).
TUNED_NOTE = "# hddpg-cli tune:"
#: A top-level key of a YAML mapping: a line starting with neither a space, a comment nor a list item.
_TOP_LEVEL = re.compile(r"\A(?![\s#-])")


def replace_block(text: str, key: str, tuned: str) -> str:
    """
    ``text`` (a YAML config) with the top-level block ``key`` (its line, the lines indented below it, and
    the tuning note just above it) replaced by ``tuned``, or ``tuned`` appended if there is no such block;
    every other line, comments included, is kept as it was.

    :param text: the config file's text.
    :param key: the block's top-level key.
    :param tuned: the new block's text (a note line and ``key: ...``).
    """
    lines = text.splitlines(keepends=True)
    heads = [i for i, line in enumerate(lines) if _TOP_LEVEL.match(line) and line.strip()]
    start = next((i for i in heads if re.match(rf"""(['"]?){re.escape(key)}\1\s*:""", lines[i])), None)
    if start is None:
        return text + ("" if not text or text.endswith("\n") else "\n") + tuned
    end = next((i for i in heads if i > start), len(lines))
    # Comments and blank lines just above the next block belong to it.
    while end > start + 1 and (not lines[end - 1].strip() or lines[end - 1].lstrip().startswith("#")):
        if lines[end - 1].startswith(" ") and lines[end - 1].strip():
            break
        end -= 1
    if start > 0 and lines[start - 1].startswith(TUNED_NOTE):
        start -= 1
    return "".join(lines[:start]) + tuned + "".join(lines[end:])


def check_only_block_changed(before: Any, text: str, key: str, what: str) -> None:
    """
    Refuse (``ValueError`` naming the file) a rewrite of a config that changed any block but ``key``: a
    YAML anchor of the replaced block used elsewhere would have changed another block, or left its alias
    undefined.

    :param before: the config as it was, parsed.
    :param text: the rewritten file's text.
    :param key: the block that was replaced.
    :param what: the file, for the message.
    """
    try:
        after = yaml.safe_load(text)
    except yaml.YAMLError as error:
        raise ValueError(
            f"--save-config: replacing block {key!r} of {what!r} would break the file "
            f"({' '.join(str(error).split())[:200]}: an anchor of the block used elsewhere?); not written: "
            "name another file"
        ) from None
    if not isinstance(after, dict):
        raise ValueError(f"--save-config: {what!r} would no longer be a mapping of blocks; not written")
    changed = sorted(k for k in set(before) | set(after) if k != key and before.get(k) != after.get(k))
    if changed:
        raise ValueError(
            f"--save-config: replacing block {key!r} of {what!r} would change {changed} too (a YAML anchor of "
            "the block used there?); not written: name another file"
        )


#: The plots a study saves, in ``OUT/plots/NAME.png``.
PLOT_NAMES = ("optimization_history", "param_importances")


def save_plots(study: optuna.Study, out_dir: str | Path) -> dict[str, Path | str]:
    """
    Save the optimisation history and the parameter importances as PNG files in ``OUT/plots``.

    Importances are PED-ANOVA's (:class:`optuna.importance.PedAnovaImportanceEvaluator`), which, unlike the
    default fANOVA, needs no scikit-learn. Use a non-interactive matplotlib backend (``Agg``) on servers.

    :param study: the study.
    :param out_dir: the run folder.
    :return: plot name -> the PNG written, or the reason it was skipped.
    """
    # Lazily: matplotlib and Optuna's plotting are slow to import, and only this function needs them; without
    # the bench extra a study runs all the same, without its plots.
    if importlib.util.find_spec("matplotlib") is None:
        return {name: f"matplotlib is not installed: {INSTALL_EXTRA}" for name in PLOT_NAMES}
    import matplotlib.pyplot as plt
    from optuna.importance import PedAnovaImportanceEvaluator
    from optuna.visualization.matplotlib import plot_optimization_history, plot_param_importances

    folder = Path(out_dir) / "plots"
    n_completed = len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)))
    plots: dict[str, Callable[[], Any]] = {
        "optimization_history": functools.partial(plot_optimization_history, study),
        "param_importances": functools.partial(
            plot_param_importances, study, evaluator=PedAnovaImportanceEvaluator()
        ),
    }
    needed = dict(zip(PLOT_NAMES, (1, 2)))
    results: dict[str, Path | str] = {}
    for name, plot in plots.items():
        if n_completed < needed[name]:
            results[name] = f"needs at least {needed[name]} completed trials, the study has {n_completed}"
            continue
        try:
            # PED-ANOVA warns about the accuracy of importances from few trials; the plot still helps.
            with quiet_experimental(), warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)
                axes = plot()
        except (ValueError, RuntimeError, ZeroDivisionError) as error:
            results[name] = f"{type(error).__name__}: {error}"
            continue
        figure = axes.figure
        folder.mkdir(parents=True, exist_ok=True)
        figure.tight_layout()
        figure.savefig(folder / f"{name}.png", dpi=120)
        plt.close(figure)
        results[name] = folder / f"{name}.png"
    return results
