"""
The front scenario's tables and figure, from :func:`~.front_statistics.front_results`' output: what the results pages
and ``fronts.png`` show, on the snake arm or another env (each plane's objectives are in the results).
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any, cast

import numpy as np

from hddpg_zoo.benchmark.front_mixtures import points_beyond
from hddpg_zoo.benchmark.front_points import PLANES, label_factors
from hddpg_zoo.records.results_leaves import FrontResults, Summary
from hddpg_zoo.stats import EQUIVALENCE_MARGIN, paired_t_interval, verdict_word
from sb3_hddpg.envs.contract import mix_terms

#: Colours of the snake's members; another env's members take the next ones of matplotlib's cycle.
MEMBER_COLOURS = {
    "conditioned": "tab:red",
    "per-preference": "tab:purple",
    "gpi": "tab:brown",
    "ham": "tab:gray",
    "ttc": "tab:gray",
    "goal": "tab:blue",
    "avoid": "tab:green",
}


def result_planes(front: FrontResults) -> dict[str, list[tuple[str, bool]]]:
    """The planes of ``front``: plane -> its objectives (a snake front stored before they were: the snake's)."""
    stored = cast(Mapping[str, Any], front).get("planes")
    if not stored:
        return {plane: list(objectives) for plane, objectives in PLANES.items()}
    return {
        plane: [(str(key), bool(larger)) for key, larger in objectives]
        for plane, objectives in stored.items()
    }


def _plane_title(objectives: list[tuple[str, bool]]) -> str:
    return ", ".join(key.replace("_", " ") for key, _ in objectives)


def front_table(front: FrontResults) -> list[str]:
    """The front table of the generated results pages: Markdown lines."""
    planes = result_planes(front)
    lines = [
        "| member | "
        + " | ".join(f"hypervolume, {plane} plane ({_plane_title(o)})" for plane, o in planes.items())
        + " |",
        "|---|" + "---|" * len(planes),
    ]
    for member in front["members"]:
        cells = []
        for plane in planes:
            stats = front["hypervolume"][member][plane]
            cells.append(f"{stats['mean']:.4g} [{stats['ci_low']:.4g}, {stats['ci_high']:.4g}]")
        lines.append(f"| {member} | " + " | ".join(cells) + " |")
    lines.extend(_safe_touch_lines(front))
    lines.extend(_equal_weight_lines(front))
    lines.extend(_morl_lines(front))
    manager = front.get("manager")
    if manager is not None:
        budget = f", {manager['env_steps']:,} env steps each" if manager["env_steps"] else ""
        backend = f" ({str(manager.get('backend')).upper()})" if manager.get("backend") else ""
        sweep = f", over {manager['sweep']}" if manager.get("sweep", "ratio-sweep") != "ratio-sweep" else ""
        motion = f", seeing motion (x{manager['motion']:g})" if manager.get("motion") else ""
        options = manager.get("option_steps")
        deciding = "" if options is None else f", deciding every {options} env step" + "s" * (options != 1)
        deciding += f" (discount {manager['gamma']:.3g} a decision)" if "gamma" in manager else ""
        lines.append("")
        trained = (
            "conditioned and per preference" if manager.get("per_preference", True) else "conditioned only"
        )
        lines.append(
            f"The front's managers ({trained}): {manager['algo'].upper()}{backend}{budget}{deciding}{sweep}{motion}."
        )
    references = front.get("references", {})
    if references:
        lines.append("")
        lines.append(
            "Reference points: "
            + "; ".join(f"{plane} {tuple(point)}" for plane, point in references.items())
            + ". Mean over seeds with the 95 % bootstrap interval."
        )
    comparisons = front.get("comparisons", {})
    if any("p_holm" in c for entry in comparisons.values() for c in entry["planes"].values()):
        who = "the conditioned manager" + (
            " and GPI" if any(k.startswith("gpi vs") for k in comparisons) else ""
        )
        lines.append(
            f"Comparisons: per plane, {who} against each other member, paired by seed; a paired "
            "t test each, Holm's step-down over the plane's comparisons, each interval at its Holm-consistent "
            "level (it excludes 0 exactly where the word is ahead or behind); level only where it lies within "
            f"+-{EQUIVALENCE_MARGIN:.0%} of the other member's mean."
        )
    for name, entry in comparisons.items():
        seeds = len(entry["seeds"])
        for plane, c in entry["planes"].items():
            if "p_holm" not in c:  # results written before the rule: the unadjusted interval, no word
                lines.append(
                    f"- {name} ({plane} plane): difference {c['difference']:.4g} [{c['ci_low']:.4g}, "
                    f"{c['ci_high']:.4g}] (paired t over seeds), better in {c['wins']} of {seeds} seeds"
                )
                continue
            word = verdict_word(
                c["difference"],
                c["ci_low_adjusted"],
                c["ci_high_adjusted"],
                c["p_holm"],
                seeds,
                c["wins"],
                c.get("equivalence_margin"),
            )
            lines.append(
                f"- {name} ({plane} plane): {word}; difference {c['difference']:.4g} "
                f"[{c['ci_low_adjusted']:.4g}, {c['ci_high_adjusted']:.4g}], Holm p {c['p_holm']:.3f}, "
                f"better in {c['wins']} of {seeds} seeds"
            )
    return lines


def _safe_touch_lines(front: FrontResults) -> list[str]:
    """The safe end per member: its mean most goal touch over the seeds whose front reaches it, and how many do."""
    safe = front.get("safe_touch")
    if safe is None:
        return []
    lines = ["", f"The safe end, at most {safe['contacts']:g} contacts per episode:"]
    best = safe.get("best_reach", {})
    for member, per_seed in safe["per_seed"].items():
        reached = [v for v in per_seed.values() if v is not None]
        mean = f"{100 * sum(reached) / len(reached):.1f} %" if reached else "-"
        line = f"- {member}: most goal touch {mean} (reached in {len(reached)} of {len(per_seed)} seeds)"
        points = [p for p in best.get(member, {}).values() if p is not None]
        if points:
            reach = sum(p["reach"] for p in points) / len(points)
            touch = sum(p["touch"] for p in points) / len(points)
            line += f"; highest reach reward {reach:.1f}, with {100 * touch:.1f} % touch at that point"
        lines.append(line)
    return lines


def _term_weights(label: str, terms: list[str]) -> dict[str, float] | None:
    """
    The terms' coefficients of a GPI point's preference over workers (each worker's reward by its factor, as
    the manager's reward weighs them: :func:`~sb3_hddpg.envs.contract.mix_terms`): a per-term worker is named
    by its term, a weighted one ``mix-`` and each term with its percentage. ``None`` for a label over other
    names.
    """
    factors = label_factors(label)
    specs: dict[str, str | dict[str, float]] = {}
    for name in factors:
        if name in terms:
            specs[name] = name
            continue
        if not name.startswith("mix-"):
            return None
        weights: dict[str, float] = {}
        for part in name[len("mix-") :].split("-"):
            term = max((t for t in terms if part.startswith(t)), key=len, default=None)
            if term is None:
                return None
            weights[term] = float(part[len(term) :].replace("p", "."))
        if not sum(weights.values()) > 0:  # not a weighting a worker is named by
            return None
        specs[name] = weights
    return {**dict.fromkeys(terms, 0.0), **mix_terms(specs, factors)}


def _equal_weight_lines(front: FrontResults) -> list[str]:
    """
    GPI at the equal weighting of the terms (the unweighted preference) against each per-term worker alone,
    paired by seed: the sum of the terms' per-step normalised means and, where measured, the reach reward
    (the episode's unweighted normalised return, which also counts how long the episode lasts).
    """
    terms = [str(key).removesuffix("_term") for key, _ in front.get("planes", {}).get("terms", [])]
    by_seed = {s: m for s, m in front.get("points", {}).items() if "gpi" in m and all(t in m for t in terms)}
    if not terms or not by_seed:
        return []
    per_seed: dict[str, dict[str, float]] = {}
    for seed, members in by_seed.items():
        for point in members["gpi"]:
            weights = _term_weights(str(point["label"]), terms)
            if weights is not None and np.ptp(list(weights.values())) <= 1e-9 * max(weights.values()):
                per_seed[seed] = {k: float(cast(float, v)) for k, v in point.items() if k != "label"}
    seeds = sorted(per_seed)
    if len(seeds) < 2:
        return []
    measures = [m for m in ("terms_sum", "mean_reach_reward") if m == "terms_sum" or m in per_seed[seeds[0]]]

    def value(point: Mapping[str, Any], measure: str) -> float:
        if measure == "terms_sum":
            return sum(float(point[f"{t}_term"]) for t in terms)
        return float(point[measure])

    pairs = [(worker, measure) for worker in terms for measure in measures]
    lines = [
        "",
        "GPI at the equal weighting of the terms (the unweighted preference) against each worker alone"
        + (" and each flat agent" if front.get("flat") else "")
        + ", paired by seed; each a paired t test at 95 %, not adjusted, since each answers its own question:",
    ]
    for worker, measure in pairs:
        c = paired_t_interval(
            [value(per_seed[s], measure) for s in seeds],
            [value(by_seed[s][worker][0], measure) for s in seeds],
        )
        higher = sum(value(per_seed[s], measure) > value(by_seed[s][worker][0], measure) for s in seeds)
        word = verdict_word(c["difference"], c["ci_low"], c["ci_high"], c["p_value"], len(seeds), higher)
        what = "normalised terms a step, summed" if measure == "terms_sum" else "reach reward"
        lines.append(
            f"- gpi vs {worker} ({what}): {word}; difference {c['difference']:.4g} "
            f"[{c['ci_low']:.4g}, {c['ci_high']:.4g}], p {c['p_value']:.3f}"
        )
    return lines + _flat_lines(front, per_seed)


def _flat_lines(front: FrontResults, gpi: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """
    GPI's equal-weighting reach reward against each flat agent of the workers' benchmark (same test episodes,
    paired by seed), with both sides' env steps: GPI's are every worker's and critic's.
    """
    lines = []
    for method, flat in front.get("flat", {}).items():
        seeds = sorted(set(flat) & set(gpi))
        if len(seeds) < 2 or not all("mean_reach_reward" in gpi[s] for s in seeds):
            continue
        ours = [float(gpi[s]["mean_reach_reward"]) for s in seeds]
        theirs = [flat[s]["mean_reach_reward"] for s in seeds]
        c = paired_t_interval(ours, theirs)
        higher = sum(a > b for a, b in zip(ours, theirs, strict=True))
        word = verdict_word(c["difference"], c["ci_low"], c["ci_high"], c["p_value"], len(seeds), higher)
        steps = sorted({int(flat[s]["env_steps"]) for s in seeds})
        budget = f"{steps[0]:,}" if len(steps) == 1 else f"{steps[0]:,} to {steps[-1]:,}"
        lines.append(
            f"- gpi vs {method} (reach reward; {method} of the workers' benchmark, {budget} env steps a seed): "
            f"{word}; "
            f"difference {c['difference']:.4g} [{c['ci_low']:.4g}, {c['ci_high']:.4g}], p {c['p_value']:.3f}"
        )
    return lines


def _morl_lines(front: FrontResults) -> list[str]:
    """A MORL library's learner beside the conditioned manager: the library's indicators and the wall-clock."""
    morl = front.get("morl")
    if morl is None:
        return []

    def cell(stats: Summary) -> str:
        return f"{stats['mean']:.4g} [{stats['ci_low']:.4g}, {stats['ci_high']:.4g}]"

    steps = sorted(set(morl["env_steps"]))
    budget = f"{steps[0]:,}" if len(steps) == 1 else f"{steps[0]:,} to {steps[-1]:,}"
    lines = [
        "",
        f"{morl['algorithm'].upper()} (MORL-baselines) beside the conditioned manager, trained for the same env "
        f"steps ({budget} per seed: the workers' and the conditioned manager's), scored by MORL-baselines' own "
        f"indicators from the reference point {tuple(morl['ref_point'])}. The hierarchy's wall-clock (its "
        "workers' task and its conditioned manager) includes their learning-curve evaluations; CAPQL's is "
        "training alone:",
        "",
        "| member | hypervolume | expected utility | training wall-clock, s |",
        "|---|---|---|---|",
    ]
    for member, scores in morl["scores"].items():
        seconds = morl["train_seconds"].get(member)
        lines.append(
            f"| {member} | {cell(scores['hypervolume'])} | {cell(scores['expected_utility'])} "
            f"| {cell(seconds) if seconds else '-'} |"
        )
    return lines + _beyond_mixture_lines(front, str(morl["algorithm"]))


#: The margin below which a point counts as reached by a mixture: the linear programme's round-off.
MIXTURE_TOLERANCE = 1e-6


def _beyond_mixture_lines(front: FrontResults, learner: str) -> list[str]:
    """
    Per seed, the learner's points beyond every mixture of the other members' points in the ``terms`` plane
    (the normalised terms, where one margin is comparable across objectives), and the largest margin.
    """
    plane = "terms"
    objectives = result_planes(front).get(plane)
    if not objectives:
        return []
    keys, larger = [key for key, _ in objectives], [better for _, better in objectives]
    counts: list[str] = []
    widest: tuple[float, str, str] | None = None
    for seed, members in front.get("points", {}).items():
        own = members.get(learner, [])
        others = [point for member, points in members.items() if member != learner for point in points]
        if not own or not others:
            continue
        margins = points_beyond(
            [[float(p[k]) for k in keys] for p in own], [[float(p[k]) for k in keys] for p in others], larger
        )
        counts.append(f"{sum(m > MIXTURE_TOLERANCE for m in margins)} of {len(margins)}")
        best = int(np.argmax(margins))
        if margins[best] > MIXTURE_TOLERANCE and (widest is None or margins[best] > widest[0]):
            widest = (margins[best], seed, str(own[best].get("label", best)))
    if not counts:
        return []
    line = (
        f"{learner.upper()}'s points beyond every mixture of the hierarchy's (the convex combinations of the "
        f"other members' points, which a manager switching between those policies reaches to first order), "
        f"{plane} plane, per seed: {', '.join(counts)}"
    )
    if widest is not None:
        line += (
            f"; the farthest lies {widest[0]:.3g} beyond the best mixture on every objective at once "
            f"(seed {widest[1]}, preference `{widest[2]}`)"
        )
    return ["", line + "."]


def decides_table(front: FrontResults) -> list[str]:
    """
    The decides-by-state table of the generated pages: per seed and preference, the avoid worker's share of
    decisions near an obstacle and with none in range, and their ratio with its bootstrap interval.
    """
    lines = [
        "| seed | preference | avoid share near | avoid share clear | ratio [95 % bootstrap CI] | decisions near / clear |",
        "|---|---|---|---|---|---|",
    ]
    for seed, by_preference in front.get("decides_by_state", {}).items():
        for preference, figure in by_preference.items():
            if figure is None:
                continue
            ratio = "-" if figure["ratio"] is None else f"{figure['ratio']:.2f}"
            interval = figure.get("ratio_ci")
            if interval:
                ratio += f" [{interval[0]:.2f}, {interval[1]:.2f}]"
            shares = [
                "-" if share is None else f"{share:.1%}"
                for share in (figure["near_share"], figure["clear_share"])
            ]
            lines.append(
                f"| {seed} | `{preference}` | {shares[0]} | {shares[1]} | {ratio} "
                f"| {figure['near_decisions']} / {figure['clear_decisions']} |"
            )
    return lines


#: The ratio a manager that decides by state reaches: the avoid worker chosen at least twice as often near
#: an obstacle as on a clear path.
DECIDES_RATIO = 2.0


def _ratio_heading(preference: str) -> str:
    """A two-worker preference as its ratio (``goal=1.6,avoid=0.4`` -> ``4:1``); any other as written."""
    factors = list(label_factors(preference).values())
    if len(factors) != 2 or min(factors) <= 0:
        return f"`{preference}`"
    first, second = factors
    return f"{first / second:.3g}:1" if first >= second else f"1:{second / first:.3g}"


def decides_matrix(front: FrontResults) -> list[str]:
    """
    The decides-by-state table in short: one row per seed, one column per preference, each cell the ratio of
    the avoid worker's share of decisions near an obstacle to its share on a clear path, in bold where its
    bootstrap interval's lower end is at least :data:`DECIDES_RATIO`.
    """
    by_seed = front.get("decides_by_state", {})
    preferences = list(dict.fromkeys(p for by_preference in by_seed.values() for p in by_preference))
    if not preferences:
        return []
    lines = [
        f"Ratio of the avoid worker's share of decisions near an obstacle to its share on a clear path, per seed "
        f"(rows) and preference (columns, goal:avoid); bold where its 95 % bootstrap interval lies at or above "
        f"{DECIDES_RATIO:g} (a ratio without an interval is one whose bootstrap draws mostly never chose the "
        "avoid worker on a clear path); '-' where it was never chosen there, so there is no ratio.",
        "",
        "| seed | " + " | ".join(_ratio_heading(p) for p in preferences) + " |",
        "|---|" + "---|" * len(preferences),
    ]
    for seed, by_preference in by_seed.items():
        cells = []
        for preference in preferences:
            figure = by_preference.get(preference)
            if figure is None or figure["ratio"] is None:
                cells.append("-")
                continue
            text = f"{figure['ratio']:.3g}"
            interval = figure.get("ratio_ci")
            cells.append(f"**{text}**" if interval and interval[0] >= DECIDES_RATIO else text)
        lines.append(f"| {seed} | " + " | ".join(cells) + " |")
    return lines


def _draw_member(axis: Any, xs: list[np.ndarray], ys: list[np.ndarray], colour: str, member: str) -> None:
    """
    One member's front on ``axis``: the mean over seeds point by point where every seed has the same points
    (a preference sweep, a worker alone), else each seed's own front (a rule keeps as many thresholds as are
    not dominated in that seed, so its points do not pair up across seeds).
    """
    if len({len(x) for x in xs}) == 1:
        mean_x, mean_y = np.mean(xs, axis=0), np.mean(ys, axis=0)
        order = np.argsort(mean_x)
        axis.plot(mean_x[order], mean_y[order], "o-", color=colour, label=member)
        return
    for seed, (x, y) in enumerate(zip(xs, ys, strict=True)):
        order = np.argsort(x)
        axis.plot(x[order], y[order], "-", color=colour, alpha=0.5, label=member if seed == 0 else None)


def front_figure(front: FrontResults, path: Path, colours: Mapping[str, str] | None = None) -> Path:
    """
    The fronts in each plane (its first and last objectives), every seed's points, each member's mean over
    seeds as a line (matplotlib).

    :param front: :func:`~.front_statistics.front_results`' output.
    :param path: the PNG to write.
    :param colours: member -> colour.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {**MEMBER_COLOURS, **(colours or {})}
    planes = result_planes(front)
    figure, axes = plt.subplots(1, len(planes), figsize=(5.5 * len(planes), 4.5), squeeze=False)
    cycle = iter(plt.rcParams["axes.prop_cycle"].by_key()["color"][4:] * 4)
    for member in front["members"]:
        colours.setdefault(member, next(cycle))
    for axis, (plane, objectives) in zip(axes[0], planes.items()):
        (x_key, _), (y_key, _) = objectives[0], objectives[-1]
        for member in front["members"]:
            rows = [front["points"][s][member] for s in front["points"]]
            xs = [np.array([float(cast(float, p[x_key])) for p in row]) for row in rows]
            ys = [np.array([float(cast(float, p[y_key])) for p in row]) for row in rows]
            axis.scatter(np.concatenate(xs), np.concatenate(ys), s=8, alpha=0.3, color=colours[member])
            _draw_member(axis, xs, ys, colours[member], member)
        axis.set_xlabel(x_key.replace("_", " "))
        axis.set_ylabel(y_key.replace("_", " "))
        axis.set_title(f"{plane} plane")
        axis.grid(alpha=0.3)
    axes[0][0].legend(fontsize=8)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)
    return path


__all__ = [
    "DECIDES_RATIO",
    "MEMBER_COLOURS",
    "decides_matrix",
    "decides_table",
    "front_figure",
    "front_table",
    "result_planes",
]
