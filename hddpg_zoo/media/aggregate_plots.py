"""The benchmark's headline figure in rliable's style: aggregate intervals and a performance profile."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from hddpg_zoo.records.results_leaves import Interval


def aggregate_figure(
    intervals: Mapping[str, Mapping[str, Interval]],
    profiles: Mapping[str, np.ndarray],
    profile_bands: Mapping[str, np.ndarray],
    taus: np.ndarray,
    colours: Mapping[str, str],
    unit: str,
    score: str,
    out: Path,
) -> list[Path]:
    """
    Two panels: per method the mean and IQM of the reach reward with their stratified bootstrap intervals
    (rliable's ``plot_interval_estimates``), and the performance profile, the fraction of scores above each
    threshold with its band (rliable's ``plot_performance_profiles``).

    :param intervals: method -> ``{"iqm": {"value", "ci_low", "ci_high"}, "mean": {...}}``.
    :param profiles: method -> the profile at ``taus``.
    :param profile_bands: method -> its band (2 x len(taus)).
    :param taus: the thresholds.
    :param colours: method -> colour.
    :param unit: what a score is, ``episode`` or ``seed`` (the profile's label).
    :param score: what the score is called (the snake arm's ``reach reward``, another env's return).
    :param out: the folder of the two PNGs, ``aggregates.png`` and ``performance_profile.png``.
    :return: their paths.
    """
    # matplotlib and rliable's plotting (seaborn) load only when a figure is drawn.
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D
    from rliable import plot_utils

    methods = list(intervals)
    names = ["mean", "iqm"]
    points = {m: np.array([intervals[m][n]["value"] for n in names]) for m in methods}
    bounds = {
        m: np.array([[intervals[m][n]["ci_low"] for n in names], [intervals[m][n]["ci_high"] for n in names]])
        for m in methods
    }
    fig, axes = plot_utils.plot_interval_estimates(
        points,
        bounds,
        metric_names=["Mean", "IQM"],
        algorithms=methods,
        colors=dict(colours),
        xlabel=f"{score} (test)",
    )
    # rliable's axes end at the extreme estimates: a method with no spread there (a policy that trains
    # nothing scores the same in every seed) would sit on the border, unseen.
    for axis in np.atleast_1d(axes):
        low, high = axis.get_xlim()
        axis.set_xlim(low - 0.04 * (high - low), high + 0.04 * (high - low))
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "aggregates.png", out / "performance_profile.png"]
    fig.savefig(paths[0], dpi=120, bbox_inches="tight")
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    plot_utils.plot_performance_profiles(
        dict(profiles),
        taus,
        performance_profile_cis=dict(profile_bands),
        colors=dict(colours),
        xlabel=rf"{score} ($\tau$)",
        ylabel=rf"fraction of {unit}s with score $> \tau$",
        ax=ax,
    )
    # rliable draws a line and a band per method: a legend of lines only, in each method's colour.
    handles = [Line2D([0], [0], color=colours[m], lw=2) for m in methods]
    ax.legend(handles, methods, loc="lower left", fontsize=8)
    fig.savefig(paths[1], dpi=120, bbox_inches="tight")
    plt.close(fig)
    return paths
