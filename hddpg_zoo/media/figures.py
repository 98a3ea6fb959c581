"""
Every figure of sb3-hddpg (matplotlib, Agg backend, one PNG each, written atomically): the selection timeline,
learning curves and comparisons of a run, and the benchmark's learning curves with CI bands on both step axes,
the paper's Figure 9 (mean reward and trend slope per method) and Figure 10 (goal vs avoid reward of the goal-
and avoid-preferred managers), each read from a benchmark's results (:class:`~hddpg_zoo.records.BenchmarkResults`).
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from hddpg_zoo.media.overlay import worker_colour
from hddpg_zoo.records.results import BenchmarkResults
from sb3_hddpg.algorithms import REGISTRY
from sb3_hddpg.artifacts.io import atomic_write_bytes
from sb3_hddpg.media.trace import StepRecord
from sb3_hddpg.metric_labels import metric_label

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure


def _colour(name: str, names: Sequence[str] = ()) -> tuple[float, float, float]:
    return tuple(c / 255 for c in worker_colour(name, names))  # type: ignore[return-value]


def _save(fig: Figure, path: str | Path, dpi: int = 110) -> Path:
    plt = _pyplot()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi, bbox_inches="tight")
    plt.close(fig)
    return atomic_write_bytes(path, buffer.getvalue())


def _save_tight(fig: Figure, path: str | Path) -> Path:
    """The benchmark figures' layout (``tight_layout``) saved by :func:`_save`."""
    fig.tight_layout()
    return _save(fig, path)


def _pyplot() -> ModuleType:
    """pyplot with the file backend. Imported here, not at module level: it is slow to import, and most commands draw nothing."""
    import matplotlib

    matplotlib.use("Agg")  # files only: never open a window, work without a display
    import matplotlib.pyplot as plt

    return plt


def step_axis_label(records: Sequence[StepRecord]) -> str:
    """The timeline's x label: it mentions the black episode separators only when there are some."""
    n_episodes = len({r.episode for r in records})
    if n_episodes == 1:
        return "step of the episode"
    return f"step ({n_episodes} episodes one after another; black lines separate them)"


def plot_selection_timeline(
    records: Sequence[StepRecord],
    path: str | Path,
    names: Sequence[str] | None = None,
    title: str = "",
    sensor_range: float | None = None,
    touch_radius: float | None = None,
) -> Path:
    """
    Per step: the worker the manager chose and its probabilities (top), the clearance to the nearest
    obstacle (middle) and the distance to the goal (bottom), episodes one after another. The chosen worker
    also shades the two lower panels, so that a switch to avoidance can be read against closing obstacles.

    :param records: the steps, from :class:`~sb3_hddpg.media.trace.StepRecorder`.
    :param path: the PNG to write.
    :param names: the workers in the manager's order (default: those seen in ``records``).
    :param title: the figure's title.
    :param sensor_range: drawn as a dashed line in the clearance panel (the avoid reward's range).
    :param touch_radius: drawn as a dashed line in the goal panel (within it the goal counts as touched).
    :return: the path written.
    """
    if not records:
        raise ValueError("Expected at least one step record, actually: none")
    plt = _pyplot()
    names = list(names) if names else sorted({n for r in records for n in r.probabilities})
    x = np.arange(len(records))
    fig, axes = plt.subplots(3, 1, figsize=(11, 6.5), sharex=True, height_ratios=[1.2, 1, 1])

    _shade_selections_and_episodes(axes, records, names)
    _plot_probabilities(axes[0], records, x, names)

    middle, bottom = axes[1], axes[2]
    clearance = np.array([r.min_clearance for r in records])
    if np.isnan(clearance).all():
        # An env without the snake's clearance and goal distance: its reward terms, per step and summed.
        _plot_terms(records, x, middle, bottom, names)
    else:
        _plot_snake_panels(records, x, clearance, middle, bottom, sensor_range, touch_radius)
    bottom.set_xlabel(step_axis_label(records))
    bottom.set_xlim(-0.5, len(records) - 0.5)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)


def _selection_spans(records: Sequence[StepRecord]) -> list[tuple[int, int, str]]:
    """Runs of steps with the same chosen worker, as (first step, step after the last, worker name)."""
    spans: list[tuple[int, int, str]] = []
    start = 0
    for i in range(1, len(records) + 1):
        if i == len(records) or records[i].selected != records[start].selected:
            selected = records[start].selected
            if selected is not None:
                spans.append((start, i, selected))
            start = i
    return spans


def _shade_selections_and_episodes(
    axes: Sequence[Axes], records: Sequence[StepRecord], names: Sequence[str]
) -> None:
    """Shade each run of the same chosen worker in every panel, and separate episodes by black lines."""
    spans = _selection_spans(records)
    for ax_index, ax in enumerate(axes):
        for begin, end, name in spans:
            ax.axvspan(
                begin - 0.5, end - 0.5, color=_colour(name, names), alpha=0.28 if ax_index == 0 else 0.1, lw=0
            )
        for i in range(1, len(records)):
            if records[i].episode != records[i - 1].episode:
                ax.axvline(i - 0.5, color="black", lw=1.2)


def _plot_probabilities(
    top: Axes, records: Sequence[StepRecord], x: np.ndarray, names: Sequence[str]
) -> None:
    """The top panel: each worker's selection probability, and a legend of who acts."""
    from matplotlib.patches import Patch  # lazily, as pyplot (see _pyplot)

    # A HAM switch has no probabilities: then the top panel shows only who acts.
    with_probabilities = any(r.probabilities for r in records)
    for name in names if with_probabilities else []:
        p = [r.probabilities.get(name, np.nan) for r in records]
        top.plot(x, p, color=_colour(name, names), lw=1.4, label=f"P({name})")
    top.set_ylim(-0.02, 1.02)
    top.set_ylabel("manager\nprobability" if with_probabilities else "acting\nworker")
    if not with_probabilities:
        top.set_yticks([])
    handles, labels = top.get_legend_handles_labels()
    handles += [Patch(color=_colour(n, names), alpha=0.4) for n in names]
    labels += [f"{n} acts" for n in names]
    top.legend(handles, labels, loc="upper right", ncol=2 * max(1, len(names)), fontsize=8, framealpha=0.9)


def _plot_snake_panels(
    records: Sequence[StepRecord],
    x: np.ndarray,
    clearance: np.ndarray,
    middle: Axes,
    bottom: Axes,
    sensor_range: float | None,
    touch_radius: float | None,
) -> None:
    """The snake env's panels: the nearest obstacle's clearance (middle) and the goal distance (bottom)."""
    middle.plot(x, clearance, color="#444444", lw=1.3)
    hits = [i for i, r in enumerate(records) if r.collision]
    if hits:
        middle.scatter(hits, clearance[hits], color="#d62728", s=12, zorder=3, label="contact")
        middle.legend(loc="upper right", fontsize=8)
    middle.axhline(0.0, color="#d62728", lw=0.8)
    if sensor_range is not None:
        middle.axhline(sensor_range, color="#444444", lw=0.8, ls="--")
        middle.annotate("sensor range", (0, sensor_range), fontsize=7, va="bottom", color="#444444")
    middle.set_ylabel("nearest\nobstacle")

    distance = np.array([r.distance_to_goal for r in records])
    bottom.plot(x, distance, color=_colour("goal"), lw=1.3)
    if touch_radius is not None:
        bottom.axhline(touch_radius, color=_colour("goal"), lw=0.8, ls="--")
        bottom.annotate("touch radius", (0, touch_radius), fontsize=7, va="bottom", color=_colour("goal"))
    bottom.set_ylabel("distance\nto goal")


def _plot_terms(
    records: Sequence[StepRecord], x: np.ndarray, middle: Axes, bottom: Axes, names: Sequence[str]
) -> None:
    """Each reward term per step (middle) and its running sum within the episode (bottom), in the colour of
    the worker of the same name (workers are named after their terms)."""
    terms = list(records[0].reward_terms)
    episodes = np.array([r.episode for r in records])
    for term in terms:
        values = np.array([r.reward_terms.get(term, np.nan) for r in records])
        running = np.zeros_like(values)
        for episode in np.unique(episodes):
            mask = episodes == episode
            running[mask] = np.cumsum(values[mask])
        colour = _colour(term, [*names, *terms])
        middle.plot(x, values, color=colour, lw=1.1, label=term)
        bottom.plot(x, running, color=colour, lw=1.3, label=term)
    middle.set_ylabel("reward term\nper step")
    bottom.set_ylabel("reward term\nepisode sum")
    if terms:
        middle.legend(loc="upper right", fontsize=8)


def plot_learning_curves(
    histories: Mapping[str, Sequence[Mapping[str, float]]],
    path: str | Path,
    references: Mapping[str, float] | None = None,
    metric: str = "mean_reach_reward",
    title: str = "",
    note: str = "",
) -> Path:
    """
    The evaluation metric of each trained agent against its own training steps, with horizontal lines for
    untrained references (HAM, scripted, random).

    :param histories: agent name -> its evaluation history (``evaluations/<name>.json``).
    :param path: the PNG to write.
    :param references: name -> the metric's value.
    :param metric: the history key to plot; ``mean_reach_reward`` is comparable across agents.
    :param title: the figure's title.
    :param note: printed under the plot: what each point and line is measured on (episodes, seeds), so
        that a reader does not expect the last point to equal a table measured on other episodes.
    :return: the path written.
    """

    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    palette = ["#1f77b4", "#9467bd", "#8c564b", "#e377c2", "#17becf"]
    others = [n for n in histories if n not in ("goal", "avoid")]
    for name, history in histories.items():
        if not history:
            continue
        steps = [h["timesteps"] for h in history]
        values = [h[metric] for h in history]
        colour = _colour(name) if name in ("goal", "avoid") else palette[others.index(name) % len(palette)]
        ax.plot(steps, values, marker="o", ms=3, lw=1.5, color=colour, label=name)
    for j, (name, value) in enumerate((references or {}).items()):
        ax.axhline(value, ls=("--", ":", "-.")[j % 3], lw=1, color="#555555", label=name)
    ax.set_xlabel("training steps of that agent")
    ax.set_ylabel(metric_label(metric).header)
    ax.legend(fontsize=8, loc="best")
    ax.grid(alpha=0.3)
    ax.set_title(title or "Evaluation during training (same metric for every agent)")
    fig.tight_layout()
    if note:
        fig.text(0.01, -0.01, note, fontsize=7.5, color="#444444", va="top", wrap=True)
    return _save(fig, path)


def plot_comparison(summaries: Mapping[str, Mapping[str, float]], path: str | Path, title: str = "") -> Path:
    """
    The methods side by side on the same evaluation seeds: the combined reach reward (mean and std over
    episodes), the goal-touch rate and collisions per episode.

    :param summaries: method name -> :meth:`EvaluationResult.summary` on the shared env.
    :param path: the PNG to write.
    :param title: the figure's title.
    :return: the path written.
    """
    plt = _pyplot()
    names = list(summaries)
    y = np.arange(len(names))[::-1]
    fig, axes = plt.subplots(1, 3, figsize=(11, 0.45 * len(names) + 1.6), sharey=True)

    panels = (
        ("mean_reach_reward", f"{metric_label('mean_reach_reward').header}, higher is better", "#1f77b4"),
        ("goal_touch_rate", metric_label("goal_touch_rate").header, _colour("goal")),
        ("collisions_per_episode", metric_label("collisions_per_episode").header, _colour("avoid")),
    )
    for ax, (key, label, colour) in zip(axes, panels):
        # One unit per quantity, as in the printed tables: rates in percent.
        scale = 100.0 if metric_label(key).percent else 1.0
        values = [scale * summaries[n][key] for n in names]
        if key == "mean_reach_reward":
            # Every method earns most of the reward by existing: dots with std bars on a zoomed axis show the
            # differences that bars from zero would hide.
            error = [summaries[n].get("std_reach_reward", 0.0) for n in names]
            ax.errorbar(values, y, xerr=error, fmt="o", color=colour, capsize=3, ms=6)
            ax.set_ylim(-0.6, len(names) - 0.4)
        else:
            ax.barh(y, values, color=colour, alpha=0.8)
        ax.set_title(label, fontsize=10)
        ax.grid(axis="x", alpha=0.3)
    axes[0].set_yticks(y, names)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    return _save(fig, path)


#: One colour per method, the same in every figure: the fallback for results written before they carried
#: their methods' colours (``results["colours"]``, from the benchmark's method registry).
COLOURS = {
    "hddpg": "tab:red",
    "ham": "tab:gray",
    "ham-tuned": "black",
    "goal-only": "yellowgreen",
    "avoid-only": "gold",
    **{name: record.colour for name, record in REGISTRY.items()},
    "hddpg-goal": "tab:green",
    "hddpg-avoid": "tab:orange",
}


def method_colour(results: BenchmarkResults, method: str) -> str | None:
    """A method's colour: the one its results record, else :data:`COLOURS`' (``None``: matplotlib's next)."""
    return (results.colours or {}).get(method) or COLOURS.get(method.partition("@")[0])


def _first_preference(results: BenchmarkResults) -> str:
    preferences = results.settings.get("preferences")
    return f"@{preferences[0]}" if isinstance(preferences, list) and preferences else "@"


def benchmark_learning_curves(results: BenchmarkResults, path: str | Path) -> Path:
    """
    Mean combined reward over seeds with 95 % bootstrap CI bands, against the agent's own steps (left)
    and against all environment steps including worker pre-training (right). A method that does not learn
    (HAM, a worker alone: one evaluation) is a horizontal line at it (from its workers' steps on the right).

    :param results: the results with their ``curves``.
    :param path: the PNG to write.
    """
    figure, axes = _pyplot().subplots(1, 2, figsize=(12, 4.5), sharey=True)
    seeds = results.settings.get("seeds")
    n_seeds = (
        len(seeds) if isinstance(seeds, list) else len({s for m in results.methods.values() for s in m.seeds})
    )
    for axis, key, label in (
        (axes[0], "own_steps", "agent's own environment steps (manager / flat agent)"),
        (axes[1], "total_steps", "total environment steps (including worker pre-training)"),
    ):
        bands = (results.curves or {}).get(key, {})
        right = max((max(b["x"]) for b in bands.values() if b["x"]), default=1.0)
        for method, band in bands.items():
            line_colour = method_colour(results, method)
            x, mean, low, high = band["x"], band["mean"], band["low"], band["high"]
            if not x:
                continue
            if len(x) == 1:  # it does not learn
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


def figure9(results: BenchmarkResults, path: str | Path) -> Path:
    """
    Paper Figure 9: per method, the mean of the learning curve (dots, with 95 % CI) and its trend slope
    (stars, right axis), over the evaluation window every method shares.

    :param results: the results.
    :param path: the PNG to write.
    """
    methods = list(results.methods)
    figure, axis = _pyplot().subplots(figsize=(1.4 * len(methods) + 3, 4.5))
    slope_axis = axis.twinx()
    for i, method in enumerate(methods):
        stats = results.methods[method].stats
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
    slope_axis.set_ylabel(f"trend slope per {results.slope_unit_steps} steps (blue stars)", color="tab:blue")
    slope_axis.axhline(0.0, color="tab:blue", linewidth=0.5, alpha=0.5)
    axis.set_title(
        f"Average reward and trend slope (first {results.curve_window} own steps), 95 % CI over seeds"
    )
    axis.grid(alpha=0.3)
    return _save(figure, Path(path))


def figure10(results: BenchmarkResults, path: str | Path) -> Path | None:
    """
    Paper Figure 10: the goal and avoid parts of the combined reward (episode sums of the normalised
    terms, final test evaluation) for the goal-preferred, unbiased and avoid-preferred managers.

    :param results: the results.
    :param path: the PNG to write.
    :return: the PNG, or ``None`` (nothing written) when the run has none of those managers, as on another
        env, whose managers have no goal and avoid parts.
    """
    methods = [
        m
        for m in ("hddpg-goal", "hddpg", "hddpg-avoid")
        if m in results.methods and "goal_reach_reward" in results.methods[m].stats
    ]
    if not methods:
        return None
    figure, axes = _pyplot().subplots(1, 2, figsize=(10, 4.5))
    width = 0.38
    for i, method in enumerate(methods):
        stats = results.methods[method].stats
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
    bias = results.settings.get("bias")
    bias_text = f"{bias:.0%}" if isinstance(bias, (int, float)) else "?"
    axes[0].set_title(f"Biased managers ({bias_text} preference): reward parts")
    lows = [
        results.methods[m].stats[k]["ci_low"]
        for m in methods
        for k in ("goal_reach_reward", "avoid_reach_reward")
    ]
    highs = [
        results.methods[m].stats[k]["ci_high"]
        for m in methods
        for k in ("goal_reach_reward", "avoid_reach_reward")
    ]
    span = max(highs) - min(lows)
    axes[0].set_ylim(max(0.0, min(lows) - 0.5 * span - 1e-6), max(highs) + 0.3 * span + 1e-6)
    axes[0].legend(fontsize=8)
    axes[1].set_xlabel("contact steps per episode (test)")
    axes[1].set_ylabel("goal-touch rate (test)")
    axes[1].set_title("Objectives traded off")
    axes[1].legend(fontsize=8)
    for axis in axes:
        axis.grid(alpha=0.3)
    return _save(figure, Path(path))
