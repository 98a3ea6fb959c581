"""
The benchmark's ``front`` scenario: every hierarchy measured over the whole trade-off, not at one preference.

Per seed, over that seed's workers, on the benchmark's test episodes:

- ``conditioned``: one preference-conditioned manager (``train_manager(manager_preferences="ratio-sweep")``)
  evaluated at every preference of :data:`SWEEP` (7 goal:avoid ratios from 4:1 to 1:4, sum 2);
- ``per-preference``: one manager trained for each preference of :data:`SWEEP` (today's managers), each at
  its own preference;
- ``ham``: the hand-written switch over a threshold sweep; the thresholds are those of a grid that are not
  dominated on the curve episodes (:data:`~sb3_hddpg.episode_sets.CURVE`), so no threshold is picked on the
  episodes that score it;
- ``goal`` / ``avoid``: each worker alone (one point each).

The conditioned and per-preference managers are of one algorithm with one budget, the benchmark's
``front_manager`` and ``front_timesteps`` (by default the paper's DDPG manager on the manager's budget).

Every member is a set of points in two planes: ``outcomes`` (goal touch rate, to maximise; contacts per
episode, to minimise) and ``terms`` (the per-step means of the normalised goal and avoid terms, both to
maximise). A set's hypervolume is pymoo's (:class:`pymoo.indicators.hv.HV`) against a reference point fixed
per env (:data:`REFERENCE_POINTS`, stated in every record), so hypervolumes of different runs compare.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import cast

import gymnasium as gym
import numpy as np

from sb3_hddpg.artifacts.records import JsonObject
from sb3_hddpg.artifacts.records.results_leaves import (
    DecisionFigure,
    FrontComparison,
    FrontManager,
    FrontResults,
)
from sb3_hddpg.baselines.ham import HAMSwitch, load_ham, save_ham
from sb3_hddpg.callbacks.evaluation import read_history
from sb3_hddpg.envs.contract import env_contract, state_layout_of
from sb3_hddpg.episode_sets import CURVE
from sb3_hddpg.evaluation import clearance_bands, evaluate
from sb3_hddpg.experiments.benchmark.method_inputs import MethodSettings, MethodTask
from sb3_hddpg.experiments.benchmark.methods import Method, register_method, test_fields, workers_steps
from sb3_hddpg.experiments.stats import paired_t_interval, probability_of_improvement, summarise
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.loading import load_policy
from sb3_hddpg.policy import Policy
from sb3_hddpg.training.config import MANAGER_KEY
from sb3_hddpg.training.flat import FLAT_ENV_ID
from sb3_hddpg.training.manager import train_manager
from sb3_hddpg.training.manager_setup import manager_hyperparams

#: The preferences every front is swept over: goal:avoid 4:1, 3:1, 2:1, 1:1, 1:2, 1:3, 1:4 at sum 2.
SWEEP = PreferenceSpace.parse("ratio-sweep", ["goal", "avoid"])
#: The two planes of a front: per objective, its summary key and whether larger is better.
PLANES: dict[str, tuple[tuple[str, bool], tuple[str, bool]]] = {
    "outcomes": (("goal_touch_rate", True), ("contacts_per_episode", False)),
    "terms": (("goal_term", True), ("avoid_term", True)),
}
#: Per env, each plane's reference point (the worst point counted): fixed, so hypervolumes compare across
#: runs. The snake: no touch and 20 contacts per episode (the goal worker alone makes about 14); both
#: normalised terms at 0 (their least value per step).
REFERENCE_POINTS: dict[str, dict[str, tuple[float, float]]] = {
    FLAT_ENV_ID: {"outcomes": (0.0, 20.0), "terms": (0.0, 0.0)},
}
#: HAM's threshold grid step on the summed distances, and how many non-dominated thresholds are kept.
HAM_FRONT_STEP = 0.25
HAM_FRONT_POINTS = 9
#: The members of a front, in the order of the tables and figures.
MEMBERS = ("conditioned", "per-preference", "ham", "goal", "avoid")
#: The paired hypervolume comparisons: challenger, baseline.
FRONT_PAIRS = (("conditioned", "ham"), ("conditioned", "per-preference"), ("conditioned", "goal"))
#: The safe end of the trade-off: a front's most goal touch with at most this many contacts per episode.
SAFE_CONTACTS = 2.0
#: Bootstrap resamples of the decides-by-state interval.
BOOTSTRAP_SAMPLES = 2000


@dataclass(frozen=True)
class FrontPoint:
    """
    One policy's point on a front.

    :param label: what it is (a preference, a threshold, a worker).
    :param goal_touch_rate: the share of steps touching the goal.
    :param contacts_per_episode: obstacle contacts per episode.
    :param goal_term: the per-step mean of the normalised goal term.
    :param avoid_term: the per-step mean of the normalised avoid term.
    :param mean_reach_reward: the episode sum of both normalised terms (the benchmark's metric).
    """

    label: str
    goal_touch_rate: float
    contacts_per_episode: float
    goal_term: float
    avoid_term: float
    mean_reach_reward: float

    @classmethod
    def of(
        cls, label: str, summary: Mapping[str, float], bounds: Mapping[str, Sequence[float]]
    ) -> FrontPoint:
        """The point of an evaluation summary (:meth:`~sb3_hddpg.evaluation.EvaluationResult.summary`)."""
        terms = {}
        for term in ("goal", "avoid"):
            low, high = bounds[term]
            terms[term] = (summary[f"mean_{term}_reward"] / summary["mean_length"] - low) / (high - low)
        return cls(
            label,
            float(summary["goal_touch_rate"]),
            float(summary["collisions_per_episode"]),
            float(terms["goal"]),
            float(terms["avoid"]),
            float(summary["mean_reach_reward"]),
        )


def hypervolume(points: Sequence[FrontPoint], plane: str, reference: Sequence[float]) -> float:
    """
    The hypervolume of a set of points in one plane, against ``reference`` (pymoo's exact 2-D indicator).

    :param points: the set's points (dominated ones add nothing; points worse than the reference neither).
    :param plane: ``outcomes`` or ``terms`` (:data:`PLANES`).
    :param reference: the plane's reference point, in the objectives' own units.
    """
    from pymoo.indicators.hv import HV  # imported when measured: pymoo loads numba-free but not instantly

    objectives = PLANES[plane]
    # pymoo minimises: a larger-is-better objective enters negated, and so does its reference.
    sign = np.array([-1.0 if larger else 1.0 for _, larger in objectives])
    values = np.array([[getattr(p, key) for key, _ in objectives] for p in points], dtype=np.float64)
    if values.size == 0:
        return 0.0
    return float(HV(ref_point=sign * np.asarray(reference, dtype=np.float64))(values * sign))


def member_fields(
    points: Sequence[FrontPoint], references: Mapping[str, Sequence[float]]
) -> dict[str, object]:
    """A member's record: its points and its hypervolume in each plane."""
    return {
        "points": [asdict(p) for p in points],
        "hypervolume": {plane: hypervolume(points, plane, references[plane]) for plane in PLANES},
    }


def preference_label(factors: Mapping[str, float]) -> str:
    """A preference as the front's records and exports write it: ``goal=1.6,avoid=0.4``."""
    return ",".join(f"{name}={float(value):.4g}" for name, value in factors.items())


def sweep_labels() -> list[str]:
    """The sweep's preferences as text, ``goal=1.6,avoid=0.4`` ..."""
    return [preference_label(dict(zip(SWEEP.names, p))) for p in SWEEP.points]


def decision_dependence(
    hierarchy: Hierarchy, env: gym.Env, seeds: range, worker: str = "avoid", seed: int = 0
) -> DecisionFigure | None:
    """
    Whether the manager decides by state, counted per **decision** (not per env step): ``worker``'s share of
    the decisions made with an obstacle within half the sensor range against its share of those with none
    in range, their ratio, and a bootstrap 95 % interval of the ratio over episodes.

    :param hierarchy: the hierarchy (its current preference).
    :param env: the shared env (with the proximity capability; ``None`` is returned otherwise).
    :param seeds: the episodes' seeds.
    :param worker: the worker whose share is compared.
    :param seed: the bootstrap's seed.
    """
    near_band, clear_band = clearance_bands(env, None, None)
    if near_band is None or clear_band is None or worker not in hierarchy.names:
        return None
    rows = []  # per episode: [worker near, all near, worker clear, all clear]
    for episode_seed in seeds:
        obs, info = env.reset(seed=episode_seed)
        hierarchy.reset_episode()
        clearance = float(info.get("min_clearance", np.nan))
        counts = np.zeros(4)
        done = False
        while not done:
            action, _ = hierarchy.predict(obs, deterministic=True)
            if hierarchy.last_decided:
                chosen = hierarchy.last_selection == worker
                if clearance <= near_band:
                    counts[0:2] += (chosen, 1)
                if clearance >= clear_band:
                    counts[2:4] += (chosen, 1)
            obs, _, terminated, truncated, info = env.step(action)
            clearance = float(info.get("min_clearance", np.nan))
            done = terminated or truncated
        rows.append(counts)
    table = np.array(rows)

    def ratio(sample: np.ndarray) -> float:
        totals = sample.sum(axis=0)
        if totals[1] == 0 or totals[3] == 0 or totals[2] == 0:
            return float("nan")
        return float((totals[0] / totals[1]) / (totals[2] / totals[3]))

    totals = table.sum(axis=0)
    rng = np.random.default_rng(seed)
    draws = np.array(
        [ratio(table[rng.integers(len(table), size=len(table))]) for _ in range(BOOTSTRAP_SAMPLES)]
    )
    finite = draws[np.isfinite(draws)]
    value = ratio(table)
    return {
        "worker": worker,
        "near_share": float(totals[0] / totals[1]) if totals[1] else None,
        "clear_share": float(totals[2] / totals[3]) if totals[3] else None,
        "near_decisions": int(totals[1]),
        "clear_decisions": int(totals[3]),
        "ratio": value if np.isfinite(value) else None,
        "ratio_ci": [float(np.quantile(finite, 0.025)), float(np.quantile(finite, 0.975))]
        if finite.size >= 0.9 * BOOTSTRAP_SAMPLES
        else None,
        "near_clearance": near_band,
        "clear_clearance": clear_band,
        "unit": "decisions",
    }


def ham_thresholds(switch: HAMSwitch, env: gym.Env, settings: MethodSettings) -> list[dict[str, float]]:
    """
    HAM's thresholds for its front: every grid threshold evaluated on the curve episodes, the non-dominated
    ones (goal touch up, contacts down) kept, at most :data:`HAM_FRONT_POINTS` spread over them.
    """
    distances = state_layout_of(env)["joint_obstacle_distances"]
    n_links = distances.stop - distances.start
    grid = []
    for step in range(0, round(n_links / HAM_FRONT_STEP) + 1):
        switch.threshold = step * HAM_FRONT_STEP
        summary = evaluate(switch, env, n_episodes=settings.eval_episodes, seed=CURVE.first_seed).summary()
        grid.append(
            {
                "threshold": switch.threshold,
                "goal_touch_rate": summary["goal_touch_rate"],
                "contacts_per_episode": summary["collisions_per_episode"],
            }
        )
    kept = [
        g
        for g in grid
        if not any(
            o["goal_touch_rate"] >= g["goal_touch_rate"]
            and o["contacts_per_episode"] <= g["contacts_per_episode"]
            and (
                o["goal_touch_rate"] > g["goal_touch_rate"]
                or o["contacts_per_episode"] < g["contacts_per_episode"]
            )
            for o in grid
        )
    ]
    if len(kept) > HAM_FRONT_POINTS:
        picks = np.linspace(0, len(kept) - 1, HAM_FRONT_POINTS).round().astype(int)
        kept = [kept[i] for i in sorted(set(picks.tolist()))]
    return kept


def _test_summary(policy: Policy, env: gym.Env, settings: MethodSettings) -> dict[str, float]:
    seeds = settings.test_set.seeds(settings.test_episodes or 1)
    return evaluate(policy, env, n_episodes=len(seeds), seed=seeds.start).summary()


def run_front(task: MethodTask, settings: MethodSettings, folder: Path) -> dict[str, object]:
    """
    The ``front`` scenario's run of one seed (the method ``hddpg-front``): train the conditioned manager and
    one manager per sweep preference over the seed's workers, then measure every member's front on the test
    episodes (see the module's note).

    :return: the record's fields: the conditioned manager's ``history`` and ``test`` (at the unweighted
        preference), ``front`` (member -> points and hypervolumes), ``references``, ``decides_by_state`` (the
        conditioned manager at each sweep preference) and ``ham_thresholds``.
    """
    run_dir = folder / task.method
    run, algo = settings.front_run_options(task.seed), settings.front_manager
    conditioned, _ = train_manager(
        folder, run_dir / "conditioned", algo=algo, manager_preferences=SWEEP, run=run
    )
    per_preference: list[tuple[str, Hierarchy]] = []
    for label, point in zip(sweep_labels(), SWEEP.points):
        factors = dict(zip(SWEEP.names, point))
        name = "manager-" + "-".join(f"{v:.3g}" for v in point)
        hierarchy, _ = train_manager(folder, run_dir / name, algo=algo, preferences=factors, run=run)
        per_preference.append((label, hierarchy))
    offset = workers_steps(folder)
    references = REFERENCE_POINTS[FLAT_ENV_ID]
    env = gym.make(FLAT_ENV_ID)
    try:
        bounds = env_contract(env).reward_bounds
        front: dict[str, object] = {}
        dependence: dict[str, DecisionFigure | None] = {}
        points = []
        seeds = settings.test_set.seeds(settings.test_episodes or 1)
        for label in sweep_labels():
            hierarchy = Hierarchy.load(run_dir / "conditioned" / "hierarchy.zip")
            hierarchy.set_preference(_factors(label))
            points.append(FrontPoint.of(label, _test_summary(hierarchy, env, settings), bounds))
            dependence[label] = decision_dependence(hierarchy, env, seeds, seed=task.seed)
        front["conditioned"] = member_fields(points, references)
        front["per-preference"] = member_fields(
            [FrontPoint.of(label, _test_summary(h, env, settings), bounds) for label, h in per_preference],
            references,
        )
        ham_points, thresholds = _ham_front(folder, run_dir, task.seed, env, settings)
        front["ham"] = member_fields(ham_points, references)
        for worker in ("goal", "avoid"):
            loaded = load_policy(folder / "workers" / f"{worker}.zip")
            worker_env = loaded.make_env(FLAT_ENV_ID)
            try:
                alone = FrontPoint.of(worker, _test_summary(loaded.policy, worker_env, settings), bounds)
            finally:
                worker_env.close()
            front[worker] = member_fields([alone], references)
        unweighted = Hierarchy.load(run_dir / "conditioned" / "hierarchy.zip")
        test = test_fields(unweighted, env, settings)
    finally:
        env.close()
    steps = conditioned.config.option_steps
    return {
        "worker_timesteps": offset,
        "manager": {
            "algo": algo,
            "env_steps": run.timesteps * steps if run.timesteps else None,
            "backend": run.backend,
        },
        "history": read_history(run_dir / "conditioned" / "evaluations" / "manager.json", steps, offset),
        **test,
        "front": front,
        "references": {plane: list(point) for plane, point in references.items()},
        "decides_by_state": dependence,
        "ham_thresholds": thresholds,
    }


def _ham_front(
    folder: Path, run_dir: Path, seed: int, env: gym.Env, settings: MethodSettings
) -> tuple[list[FrontPoint], list[dict[str, float]]]:
    """HAM over the seed's workers at each threshold :func:`ham_thresholds` keeps: its points, and those thresholds."""
    n_links = state_layout_of(env)["joint_obstacle_distances"]
    ham_path = save_ham(
        run_dir / "ham.json",
        folder / "workers" / "manifest.json",
        threshold=(n_links.stop - n_links.start) / 2,  # replaced by each swept threshold below
        env_id=FLAT_ENV_ID,
        metadata={"seed": seed},
    )
    switch, _ = load_ham(ham_path)
    thresholds = ham_thresholds(switch, env, settings)
    bounds = env_contract(env).reward_bounds
    points = []
    for entry in thresholds:
        switch.threshold = entry["threshold"]
        label = f"threshold={entry['threshold']:g}"
        points.append(FrontPoint.of(label, _test_summary(switch, env, settings), bounds))
    return points, thresholds


def _factors(label: str) -> dict[str, float]:
    return {name: float(value) for name, _, value in (part.partition("=") for part in label.split(","))}


def safe_touch(points: Sequence[Mapping[str, object]], contacts: float = SAFE_CONTACTS) -> float | None:
    """
    The most goal touch among a front's ``points`` with at most ``contacts`` contacts per episode: what the
    front offers a user who cannot afford more (``None``: no point is that safe).
    """
    touches = [
        float(cast(float, p["goal_touch_rate"]))
        for p in points
        if float(cast(float, p["contacts_per_episode"])) <= contacts
    ]
    return max(touches) if touches else None


def front_results(runs: Mapping[int, JsonObject]) -> FrontResults:
    """
    The front scenario's statistics over seeds: per member and plane the per-seed hypervolumes and their
    summary (mean, 95 % bootstrap CI, IQM), the paired differences of :data:`FRONT_PAIRS` (Student t
    interval over seeds, probability of improvement) and per seed the decides-by-state ratios.

    :param runs: seed -> the ``hddpg-front`` record.
    """
    seeds = sorted(runs)
    per_seed = {
        member: {
            plane: {str(s): runs[s]["front"][member]["hypervolume"][plane] for s in seeds} for plane in PLANES
        }
        for member in MEMBERS
        if all(member in runs[s]["front"] for s in seeds)
    }
    summaries = {
        member: {plane: summarise(list(values.values())) for plane, values in planes.items()}
        for member, planes in per_seed.items()
    }
    comparisons: dict[str, FrontComparison] = {}
    for a, b in FRONT_PAIRS:
        if a not in per_seed or b not in per_seed or len(seeds) < 2:
            continue  # one seed makes no paired interval
        entry: dict[str, object] = {"seeds": seeds}  # a FrontComparison once both planes are in
        for plane in PLANES:
            xa = np.array([per_seed[a][plane][str(s)] for s in seeds])
            xb = np.array([per_seed[b][plane][str(s)] for s in seeds])
            interval = paired_t_interval(xa, xb)
            entry[plane] = {
                **{k: interval[k] for k in ("difference", "ci_low", "ci_high", "p_value")},
                "wins": int(np.sum(xa > xb)),
                "probability_of_improvement": probability_of_improvement(xa, xb),
            }
        comparisons[f"{a} vs {b}"] = cast(FrontComparison, entry)
    results: FrontResults = {
        "members": list(per_seed),
        "references": runs[seeds[0]]["references"] if seeds else {},
        "hypervolume_per_seed": per_seed,
        "hypervolume": summaries,
        "comparisons": comparisons,
        "decides_by_state": {str(s): runs[s].get("decides_by_state", {}) for s in seeds},
        "points": {str(s): {m: runs[s]["front"][m]["points"] for m in per_seed} for s in seeds},
    }
    if seeds and "manager" in runs[seeds[0]]:
        results["manager"] = cast(FrontManager, runs[seeds[0]]["manager"])
    results["safe_touch"] = {
        "contacts": SAFE_CONTACTS,
        "per_seed": {m: {str(s): safe_touch(runs[s]["front"][m]["points"]) for s in seeds} for m in per_seed},
    }
    return results


def front_table(front: FrontResults) -> list[str]:
    """The front table of the generated results pages: Markdown lines."""
    lines = [
        "| member | hypervolume (goal touch, contacts) | hypervolume (goal term, avoid term) |",
        "|---|---|---|",
    ]
    for member in front["members"]:
        cells = []
        for plane in PLANES:
            stats = front["hypervolume"][member][plane]
            cells.append(f"{stats['mean']:.4g} [{stats['ci_low']:.4g}, {stats['ci_high']:.4g}]")
        lines.append(f"| {member} | " + " | ".join(cells) + " |")
    lines.extend(_safe_touch_lines(front))
    manager = front.get("manager")
    if manager is not None:
        budget = f", {manager['env_steps']:,} env steps each" if manager["env_steps"] else ""
        backend = f" ({str(manager.get('backend')).upper()})" if manager.get("backend") else ""
        lines.append("")
        lines.append(
            "The front's managers (conditioned and per preference): "
            f"{manager['algo'].upper()}{backend}{budget}."
        )
    references = front.get("references", {})
    if references:
        lines.append("")
        lines.append(
            "Reference points: "
            + "; ".join(f"{plane} {tuple(point)}" for plane, point in references.items())
            + ". Mean over seeds with the 95 % bootstrap interval."
        )
    for name, entry in front.get("comparisons", {}).items():
        for plane, c in (("outcomes", entry["outcomes"]), ("terms", entry["terms"])):
            lines.append(
                f"- {name} ({plane} plane): difference {c['difference']:.4g} [{c['ci_low']:.4g}, "
                f"{c['ci_high']:.4g}] (paired t over seeds), better in {c['wins']} of {len(entry['seeds'])} seeds"
            )
    return lines


def _safe_touch_lines(front: FrontResults) -> list[str]:
    """The safe end per member: its mean most goal touch over the seeds whose front reaches it, and how many do."""
    safe = front.get("safe_touch")
    if safe is None:
        return []
    lines = ["", f"Most goal touch with at most {safe['contacts']:g} contacts per episode:"]
    for member, per_seed in safe["per_seed"].items():
        reached = [v for v in per_seed.values() if v is not None]
        mean = f"{100 * sum(reached) / len(reached):.1f} %" if reached else "-"
        lines.append(f"- {member}: {mean} (reached in {len(reached)} of {len(per_seed)} seeds)")
    return lines


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


def front_figure(front: FrontResults, path: Path, colours: Mapping[str, str] | None = None) -> Path:
    """
    The fronts in both planes, every seed's points, each member's mean over seeds as a line (matplotlib).

    :param front: :func:`front_results`' output.
    :param path: the PNG to write.
    :param colours: member -> colour.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = dict(colours or {})
    default = dict(zip(MEMBERS, ("tab:red", "tab:purple", "tab:gray", "tab:blue", "tab:green")))
    figure, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    for axis, plane in zip(axes, PLANES):
        (x_key, _), (y_key, _) = PLANES[plane]
        for member in front["members"]:
            colour = colours.get(member, default.get(member, "black"))
            seeds = list(front["points"])
            rows = [front["points"][s][member] for s in seeds]
            xs = np.array([[p[x_key] for p in row] for row in rows])
            ys = np.array([[p[y_key] for p in row] for row in rows])
            axis.scatter(xs.ravel(), ys.ravel(), s=8, alpha=0.3, color=colour)
            order = np.argsort(xs.mean(axis=0))
            axis.plot(xs.mean(axis=0)[order], ys.mean(axis=0)[order], "o-", color=colour, label=member)
        axis.set_xlabel(x_key.replace("_", " "))
        axis.set_ylabel(y_key.replace("_", " "))
        axis.set_title(f"{plane} plane")
        axis.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)
    return path


#: The front scenario's method: one seed's conditioned and per-preference managers and every front.
FRONT_METHOD = "hddpg-front"


def _front_cost(settings: MethodSettings) -> int:
    # The conditioned manager and one manager per sweep preference, each the front's env steps.
    return (1 + len(SWEEP.points)) * settings.front_env_steps


def _front_blocks(settings: MethodSettings) -> dict[str, object]:
    algo = settings.front_manager
    return {f"{algo}.yml[{MANAGER_KEY}]": manager_hyperparams(algo).raw}


register_method(
    Method(
        FRONT_METHOD,
        run_front,
        _front_cost,
        needs_workers=True,
        colour="tab:red",
        description=(
            "the front scenario: a preference-conditioned manager and a manager per preference over 7 "
            "preferences, HAM over a threshold sweep and each worker alone, with hypervolumes"
        ),
        config_blocks=_front_blocks,
    )
)
