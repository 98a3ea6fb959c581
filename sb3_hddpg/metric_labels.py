"""
How evaluation metrics are shown to people: words instead of keys, one unit per quantity. Summaries keep
rates as fractions for programs; printed tables show percentages, with the unit in a header or a caption.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class MetricLabel:
    """
    :param label: the quantity in words.
    :param unit: its unit as printed (``""``: a count or a plain number).
    :param percent: the value is a fraction, shown as a percentage.
    :param digits: decimals shown.
    :param short: a shorter name for table columns (default: ``label``).
    """

    label: str
    unit: str
    percent: bool = False
    digits: int = 1
    short: str = ""

    def format(self, value: float) -> str:
        """The value in this quantity's unit, without the unit."""
        return f"{100 * value:.{self.digits}f}" if self.percent else f"{value:.{self.digits}f}"

    @property
    def header(self) -> str:
        """The short name with its unit, for an axis or a column."""
        name = self.short or self.label
        return f"{name} ({self.unit})" if self.unit else name


#: Summary key -> how it is shown. Keys not listed are shown by name, with three decimals.
METRIC_LABELS: dict[str, MetricLabel] = {
    "mean_reward": MetricLabel("reward (the env's own)", "per episode", short="reward"),
    # The reward terms, each normalised to [0, 1] and summed over the episode: one name on every env.
    "mean_reach_reward": MetricLabel("return (normalised terms)", "per episode", short="norm. return"),
    "mean_goal_reward": MetricLabel("goal reward", "per episode"),
    "mean_avoid_reward": MetricLabel("avoid reward", "per episode"),
    # Rates of steps matter at one decimal (3.0 % against 0.1 % goal touch).
    "goal_touch_rate": MetricLabel("touching the goal", "% of steps", percent=True, short="goal touch"),
    "goal_reached_rate": MetricLabel("goal touched at least once", "% of episodes", percent=True, digits=0),
    "collisions_per_episode": MetricLabel(
        "contact steps (steps touching an obstacle)", "per episode", short="contact steps"
    ),
    "success_rate": MetricLabel(
        "success: goal touched, no contact", "% of episodes", percent=True, digits=0, short="success"
    ),
    "min_clearance": MetricLabel(
        "min clearance to an obstacle", "arm lengths", digits=3, short="min clearance"
    ),
    "action_saturation": MetricLabel(
        "actor outputs pinned at ±1 (the ends of the tanh range: no longer learning)",
        "% of outputs",
        percent=True,
        digits=0,
        short="saturated",
    ),
    "mean_length": MetricLabel("episode length", "steps", digits=0),
}

#: What a manager's ``mean_reward`` is: its own reward, the normalised terms weighted by the preferences.
MANAGER_REWARD_LABEL = MetricLabel(
    "manager's reward (normalised terms weighted by the preferences)", "per episode", short="manager reward"
)

#: How one worker's share of the steps (``selection_rate``) is shown.
SELECTION_LABEL = MetricLabel(
    "steps run by the {name} worker", "% of steps", percent=True, digits=1, short="worker use"
)
#: How the contact steps made while one worker acted (``collisions_by_worker``) are shown.
CONTACTS_LABEL = MetricLabel(
    "contact steps while the {name} worker acts", "per episode", short="contacts by worker"
)


#: A manager whose one worker runs this share of the steps or more acts as that worker alone.
COLLAPSED_SHARE = 0.99
#: A manager whose outputs are pinned at ±1 this often or more no longer weighs its workers.
SATURATED_SHARE = 0.5


def manager_warnings(summary: Mapping[str, Any]) -> list[str]:
    """
    One sentence per way a hierarchy's manager does not decide between its workers, from its evaluation
    :meth:`~sb3_hddpg.evaluation.EvaluationResult.summary`: one worker on (nearly) every step, or its outputs
    pinned at the ends of their range. None for a policy without ``selection_rate``.
    """
    warnings: list[str] = []
    rates = summary.get("selection_rate")
    if not isinstance(rates, Mapping) or not rates:
        return warnings  # not a hierarchy: its saturation is an actor's, said by the table
    name, share = max(rates.items(), key=lambda item: item[1])
    if share >= COLLAPSED_SHARE:
        warnings.append(
            f"the manager chose {name} on {100 * share:.0f} % of steps: it acts as the {name} worker alone"
        )
    saturation = summary.get("action_saturation")
    if isinstance(saturation, (int, float)) and saturation >= SATURATED_SHARE:
        warnings.append(
            f"{100 * saturation:.0f} % of the manager's outputs are pinned at ±1, the ends of its tanh range "
            "where the gradient vanishes: it has stopped weighing its workers and repeats one choice"
        )
    return warnings


def units_caption(labels: Sequence[MetricLabel]) -> str:
    """The units of a table's columns in one line (``"per episode: reward; % of steps: goal touch"``)."""
    by_unit: dict[str, list[str]] = {}
    for label in labels:
        if label.unit:
            by_unit.setdefault(label.unit, []).append(label.short or label.label)
    return "; ".join(f"{unit}: {', '.join(names)}" for unit, names in by_unit.items())


def metric_label(key: str) -> MetricLabel:
    """How ``key`` is shown (a plain-words fallback for keys without an entry)."""
    if key in METRIC_LABELS:
        return METRIC_LABELS[key]
    term = re.fullmatch(r"mean_(\w+)_reward", key)
    if term:  # any env's reward term (evaluate reports one per term)
        return MetricLabel(f"{term.group(1)} reward", "per episode", short=f"{term.group(1)} term")
    return MetricLabel(key.replace("_", " "), "", digits=3)


def summary_rows(summary: Mapping[str, Any]) -> list[tuple[str, str, str]]:
    """
    An evaluation :meth:`~sb3_hddpg.evaluation.EvaluationResult.summary` as ``(quantity, value, unit)`` rows,
    in its order: the reward with its spread, rates as percentages, each worker's share of the steps.
    """
    rows: list[tuple[str, str, str]] = []
    same = same_returns(summary)
    for key, value in summary.items():
        if key in ("episodes", "std_reward", "std_reach_reward") or (same and key == "mean_reach_reward"):
            continue  # the episodes are in the title; a std is shown with its mean; one number once
        by_worker = {"selection_rate": SELECTION_LABEL, "collisions_by_worker": CONTACTS_LABEL}.get(key)
        if by_worker is not None and isinstance(value, Mapping):
            rows += [
                (by_worker.label.format(name=n), by_worker.format(v), by_worker.unit)
                for n, v in value.items()
            ]
            continue
        if isinstance(value, Mapping):
            rows += [(f"{key.replace('_', ' ')}: {name}", _plain(item), "") for name, item in value.items()]
            continue
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            rows.append((key.replace("_", " "), str(value), ""))
            continue
        label = metric_label(key)
        shown = label.format(value)
        spread = {"mean_reward": "std_reward", "mean_reach_reward": "std_reach_reward"}.get(key)
        if spread is not None and spread in summary:
            shown += f" ± {label.format(summary[spread])}"
        name = (
            f"{label.label} = {METRIC_LABELS['mean_reach_reward'].label}" if same and spread else label.label
        )
        rows.append((name, shown, label.unit))
    return rows


def same_returns(summary: Mapping[str, Any]) -> bool:
    """Whether the env's own reward is the return of the normalised terms (an env whose reward is that sum)."""
    reward, normalised = summary.get("mean_reward"), summary.get("mean_reach_reward")
    if not isinstance(reward, float) or not isinstance(normalised, float):
        return False
    return metric_label("mean_reward").format(reward) == metric_label("mean_reward").format(normalised)


def _plain(value: Any) -> str:
    return f"{value:.3f}" if isinstance(value, float) else str(value)
