"""
The benchmark's figures (matplotlib, Agg backend): learning curves with CI bands on both step axes, the
paper's Figure 9 (mean reward and trend slope per method) and Figure 10 (goal vs avoid reward of the
goal- and avoid-preferred managers). Each function reads a ``results.json`` dict and writes one PNG.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only: never open a window, even where a display exists

import matplotlib.pyplot as plt

from sb3_hddpg.artifacts.io import atomic_write

#: One colour per method, the same in every figure: the fallback for results written before they carried
#: their methods' colours (``results["colours"]``, from the benchmark's method registry).
COLOURS = {
    "hddpg": "tab:red",
    "ham": "tab:gray",
    "ddpg": "tab:blue",
    "td3": "tab:cyan",
    "sac": "tab:purple",
    "tqc": "tab:brown",
    "hddpg-goal": "tab:green",
    "hddpg-avoid": "tab:orange",
}


def method_colour(results: dict[str, Any], method: str) -> str | None:
    """A method's colour: the one its results record, else :data:`COLOURS`' (``None``: matplotlib's next)."""
    return results.get("colours", {}).get(method) or COLOURS.get(method.partition("@")[0])


def _save(figure: Any, path: Path) -> Path:
    figure.tight_layout()
    atomic_write(path, lambda tmp: figure.savefig(tmp, format="png", dpi=110))
    plt.close(figure)
    return path


def _first_preference(results: dict[str, Any]) -> str:
    preferences = results["settings"].get("preferences") or [""]
    return f"@{preferences[0]}"


def learning_curves(results: dict[str, Any], path: str | Path) -> Path:
    """
    Mean combined reward over seeds with 95 % bootstrap CI bands, against the agent's own steps (left)
    and against all environment steps including worker pre-training (right). HAM does not learn: it is a
    horizontal line at its evaluation (from its workers' steps on the right).

    :param results: a ``results.json`` dict with ``curves``.
    :param path: the PNG to write.
    """
    figure, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
    n_seeds = len(results["settings"]["seeds"])
    for axis, key, label in (
        (axes[0], "own_steps", "agent's own environment steps (manager / flat agent)"),
        (axes[1], "total_steps", "total environment steps (including worker pre-training)"),
    ):
        bands = results["curves"][key]
        right = max((max(b["x"]) for b in bands.values() if b["x"]), default=1.0)
        for method, band in bands.items():
            line_colour = method_colour(results, method)
            x, mean, low, high = band["x"], band["mean"], band["low"], band["high"]
            if not x:
                continue
            if method == "ham":
                start = x[0] if key == "total_steps" else 0.0
                x, mean, low, high = [start, right], mean[:1] * 2, low[:1] * 2, high[:1] * 2
                axis.plot(x, mean, "--", color=line_colour, label=method)
            else:
                # A second preference of the same method (transfer scenario) keeps its colour, dashed.
                style = "-o" if "@" not in method or method.endswith(_first_preference(results)) else "--s"
                axis.plot(x, mean, style, markersize=3, color=line_colour, label=method)
            axis.fill_between(x, low, high, color=line_colour, alpha=0.2, linewidth=0)
        axis.set_xlabel(label)
        axis.grid(alpha=0.3)
    axes[0].set_ylabel("combined normalised reward per episode")
    axes[0].legend(loc="lower right", fontsize=8)
    figure.suptitle(f"Learning curves: mean and 95 % bootstrap CI over {n_seeds} seeds")
    return _save(figure, Path(path))


def figure9(results: dict[str, Any], path: str | Path) -> Path:
    """
    Paper Figure 9: per method, the mean of the learning curve (dots, with 95 % CI) and its trend slope
    (stars, right axis), over the evaluation window every method shares.

    :param results: a ``results.json`` dict.
    :param path: the PNG to write.
    """
    methods = list(results["methods"])
    figure, axis = plt.subplots(figsize=(1.4 * len(methods) + 3, 4.5))
    slope_axis = axis.twinx()
    for i, method in enumerate(methods):
        stats = results["methods"][method]["stats"]
        curve, slope = stats["curve_mean"], stats["slope"]
        axis.errorbar(
            i - 0.1,
            curve["mean"],
            yerr=[[curve["mean"] - curve["ci_low"]], [curve["ci_high"] - curve["mean"]]],
            fmt="o",
            color="tab:red",
            capsize=4,
        )
        slope_axis.errorbar(
            i + 0.1,
            slope["mean"],
            yerr=[[slope["mean"] - slope["ci_low"]], [slope["ci_high"] - slope["mean"]]],
            fmt="*",
            markersize=10,
            color="tab:blue",
            capsize=4,
        )
    axis.set_xticks(range(len(methods)), methods)
    axis.set_ylabel("mean combined reward over the curve (red dots)", color="tab:red")
    slope_axis.set_ylabel(
        f"trend slope per {results['slope_unit_steps']} steps (blue stars)", color="tab:blue"
    )
    slope_axis.axhline(0.0, color="tab:blue", linewidth=0.5, alpha=0.5)
    axis.set_title(
        f"Average reward and trend slope (first {results['curve_window']} own steps), 95 % CI over seeds"
    )
    axis.grid(alpha=0.3)
    return _save(figure, Path(path))


def figure10(results: dict[str, Any], path: str | Path) -> Path:
    """
    Paper Figure 10: the goal and avoid parts of the combined reward (episode sums of the normalised
    terms, final test evaluation) for the goal-preferred, unbiased and avoid-preferred managers.

    :param results: a ``results.json`` dict.
    :param path: the PNG to write.
    """
    methods = [m for m in ("hddpg-goal", "hddpg", "hddpg-avoid") if m in results["methods"]]
    figure, axes = plt.subplots(1, 2, figsize=(10, 4.5))
    if not methods:
        for axis in axes:
            axis.text(0.5, 0.5, "no hddpg-goal / hddpg-avoid runs", ha="center", va="center")
        return _save(figure, Path(path))
    width = 0.38
    for i, method in enumerate(methods):
        stats = results["methods"][method]["stats"]
        for j, (key, colour) in enumerate(
            (("goal_reach_reward", "tab:green"), ("avoid_reach_reward", "tab:orange"))
        ):
            s = stats[key]
            axes[0].bar(
                i + (j - 0.5) * width,
                s["mean"],
                width,
                yerr=[[s["mean"] - s["ci_low"]], [s["ci_high"] - s["mean"]]],
                color=colour,
                capsize=4,
                label=key.split("_")[0] if i == 0 else None,
            )
        touch, collisions = stats["goal_touch_rate"], stats["collisions_per_episode"]
        axes[1].errorbar(
            collisions["mean"],
            touch["mean"],
            xerr=[[collisions["mean"] - collisions["ci_low"]], [collisions["ci_high"] - collisions["mean"]]],
            yerr=[[touch["mean"] - touch["ci_low"]], [touch["ci_high"] - touch["mean"]]],
            fmt="o",
            color=method_colour(results, method),
            capsize=4,
            label=method,
        )
    axes[0].set_xticks(range(len(methods)), methods)
    axes[0].set_ylabel("episode sum of the normalised term (test)")
    axes[0].set_title(f"Biased managers ({results['settings']['bias']:.0%} preference): reward parts")
    lows = [
        results["methods"][m]["stats"][k]["ci_low"]
        for m in methods
        for k in ("goal_reach_reward", "avoid_reach_reward")
    ]
    highs = [
        results["methods"][m]["stats"][k]["ci_high"]
        for m in methods
        for k in ("goal_reach_reward", "avoid_reach_reward")
    ]
    span = max(highs) - min(lows)
    axes[0].set_ylim(max(0.0, min(lows) - 0.5 * span - 1e-6), max(highs) + 0.3 * span + 1e-6)
    axes[0].legend(fontsize=8)
    axes[1].set_xlabel("collisions per episode (test)")
    axes[1].set_ylabel("goal-touch rate (test)")
    axes[1].set_title("Objectives traded off")
    axes[1].legend(fontsize=8)
    for axis in axes:
        axis.grid(alpha=0.3)
    return _save(figure, Path(path))
