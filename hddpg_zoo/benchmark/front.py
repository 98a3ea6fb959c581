"""
The benchmark's ``front`` scenario: every hierarchy measured over the whole trade-off, not at one preference.

Per seed, over that seed's workers, on the benchmark's test episodes, on the snake arm or another env
(``benchmark --env``; its :class:`~.front_points.FrontSpec` says what is measured there):

- ``conditioned``: one preference-conditioned manager (``train_manager(manager_preferences=...)``) trained
  over the env's ``ratio-sweep`` (each worker in turn weighted 1 to 4 times the others; 7 preferences for
  two workers) and evaluated at each of its preferences;
- ``per-preference``: one manager trained for each preference of the sweep, each at its own preference
  (the reference; not trained when ``front_per_preference`` is off);
- the env's hand-written rule over a threshold sweep: HAM on the snake arm (``ham``), the time-to-collision
  switch on highway-env (``ttc``); the thresholds are those of a grid that are not dominated on the curve
  episodes (:data:`~sb3_hddpg.episode_sets.CURVE`), so no threshold is picked on the episodes that score it;
- each worker alone (one point each, named for its term);
- ``gpi``: generalized policy improvement over the same workers with their per-term critics, at each
  preference of the sweep (:mod:`.front_gpi`; no manager, so no env steps beyond the workers');
- with ``morl_python`` set, on an MO-Gymnasium env: MORL-baselines' CAPQL (``capql``, :mod:`.morl`), trained
  for the env steps of the workers and the conditioned manager together, at as many preferences.

The conditioned and per-preference managers are of one algorithm with one budget, the benchmark's
``front_manager`` and ``front_env_steps`` (by default the paper's DDPG manager on the manager's budget).
Every member's points and hypervolumes are in the planes of :mod:`.front_points`; the hypervolumes are
pymoo's against a reference point fixed per env and stated in every record, so runs compare.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, cast

import gymnasium as gym
import numpy as np

from hddpg_zoo.agent_settings import horizon_gamma, read_history
from hddpg_zoo.baselines.ttc import TTC_GRID, TTCSwitch
from hddpg_zoo.benchmark.env_methods import (
    combined_env,
    kinematics_scales,
    load_env_worker,
    ttc_switch,
)
from hddpg_zoo.benchmark.front_gpi import GPI_MEMBER, gpi_points
from hddpg_zoo.benchmark.front_points import (
    PLANES,
    SNAKE_FRONT,
    FrontPoint,
    FrontSpec,
    env_front,
    member_fields,
    non_dominated,
    sweep_labels,
)
from hddpg_zoo.benchmark.front_support import SUPPORT_METHOD, support_folder, support_sweep, support_weights
from hddpg_zoo.benchmark.method_inputs import MethodSettings, MethodTask
from hddpg_zoo.benchmark.methods import (
    Method,
    _manager_blocks,
    register_method,
    test_fields,
    workers_steps,
)
from hddpg_zoo.benchmark.morl import MORL_MEMBER, MorlRun, morl_member
from hddpg_zoo.records.results_leaves import (
    DecisionFigure,
    FrontManager,
)
from sb3_hddpg.artifacts.io import atomic_write_json
from sb3_hddpg.artifacts.limits import read_json_record
from sb3_hddpg.baselines.ham import HAMSwitch, load_ham, save_ham
from sb3_hddpg.envs.contract import env_contract, state_layout_of
from sb3_hddpg.envs.ids import SNAKE_REACH_ENV_ID
from sb3_hddpg.episode_sets import CURVE
from sb3_hddpg.evaluation import clearance_bands, evaluate
from sb3_hddpg.hierarchy.conditioning import PreferenceSpace
from sb3_hddpg.hierarchy.hierarchy import Hierarchy
from sb3_hddpg.hierarchy.loading import load_policy
from sb3_hddpg.policy import Policy
from sb3_hddpg.training.manager import train_manager

#: The snake's sweep: goal:avoid 4:1, 3:1, 2:1, 1:1, 1:2, 1:3, 1:4 at sum 2.
SWEEP = SNAKE_FRONT.sweep
#: How many non-dominated thresholds a rule keeps.
RULE_FRONT_POINTS = 9
#: Bootstrap resamples of the decides-by-state interval.
BOOTSTRAP_SAMPLES = 2000


#: The benchmark settings only the front scenario reads.
FRONT_SETTINGS = (
    "front_manager",
    "front_timesteps",
    "front_sweep",
    "front_motion",
    "front_option_steps",
    "front_per_preference",
    "front_support",
    "front_start",
    "front_critic_steps",
    "front_gpi",
    "morl_python",
)


def front_env(settings: MethodSettings) -> gym.Env:
    """The env a front is measured on: the snake arm, or the benchmark's other env with its combined reward."""
    shared = settings.terms_env
    return gym.make(SNAKE_REACH_ENV_ID) if shared is None else combined_env(shared)


def front_spec(settings: MethodSettings, env: gym.Env) -> FrontSpec:
    """What the front measures on ``env`` (:func:`front_env`): the snake's, or the other env's terms and rule."""
    shared = settings.terms_env
    # A sweep that lists preferences names the support's workers: the spec keeps the terms' ratio sweep.
    form = settings.front_sweep if "=" not in settings.front_sweep else "ratio-sweep"
    if shared is None:
        return replace(SNAKE_FRONT, sweep_form=form)
    # An adapter's time limit is its inner env's (gym.make keeps max_episode_steps for itself).
    steps = env.spec.max_episode_steps if env.spec is not None else None
    steps = steps or getattr(env.unwrapped, "episode_steps", None)
    rule = "ttc" if kinematics_scales(env) is not None else None
    spec = env_front(shared.terms, env_contract(env).reward_bounds, steps, rule)
    return replace(spec, sweep_form=form)


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
    return _dependence_figure(np.array(rows), worker, near_band, clear_band, seed)


def _dependence_figure(
    table: np.ndarray, worker: str, near_band: float, clear_band: float, seed: int
) -> DecisionFigure:
    """The figure of per-episode counts ``[worker near, all near, worker clear, all clear]``."""

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
    ones (goal touch up, contacts down) kept, at most :data:`RULE_FRONT_POINTS` spread over them.
    """
    grid = []
    for threshold in switch.threshold_grid(from_zero=True):
        switch.threshold = threshold
        summary = evaluate(switch, env, n_episodes=settings.eval_episodes, seed=CURVE.first_seed).summary()
        grid.append(
            {
                "threshold": switch.threshold,
                "goal_touch_rate": summary["goal_touch_rate"],
                "contacts_per_episode": summary["collisions_per_episode"],
            }
        )
    return _spread(cast(list[dict[str, float]], non_dominated(grid, PLANES["outcomes"])))


def _spread(kept: list[dict[str, float]]) -> list[dict[str, float]]:
    """At most :data:`RULE_FRONT_POINTS` of ``kept``, spread evenly over them."""
    if len(kept) > RULE_FRONT_POINTS:
        picks = np.linspace(0, len(kept) - 1, RULE_FRONT_POINTS).round().astype(int)
        kept = [kept[i] for i in sorted(set(picks.tolist()))]
    return kept


def _test_summary(policy: Policy, env: gym.Env, settings: MethodSettings) -> dict[str, float]:
    seeds = settings.test_set.seeds(settings.test_episodes or 1)
    return evaluate(policy, env, n_episodes=len(seeds), seed=seeds.start).summary()


def _test_point(
    label: str, policy: Policy, env: gym.Env, settings: MethodSettings, spec: FrontSpec
) -> FrontPoint:
    """``policy``'s point on the test episodes, its terms normalised by the bounds of ``env``."""
    summary = _test_summary(policy, env, settings)
    return FrontPoint.of(label, summary, env_contract(env).reward_bounds, spec.terms)


def _train_managers(
    task: MethodTask, settings: MethodSettings, folder: Path, sweep: PreferenceSpace, run_dir: Path
) -> tuple[Hierarchy, float, list[tuple[str, Hierarchy]]]:
    """
    The seed's conditioned manager over ``sweep`` and the workers of ``folder``, the seconds it trained, and
    one manager per preference of it (none when the settings' ``front_per_preference`` is off), in ``run_dir``.
    """
    start = settings.front_start if task.method == SUPPORT_METHOD else None
    run, algo = settings.front_run_options(task.seed, start), settings.front_manager
    shared = settings.terms_env
    steps = settings.front_option_steps
    # The managers act over the workers in the sweep's order, whatever the manifest's; options of another
    # length than the block's keep its horizon in env steps, as their budget is.
    env_options: dict[str, Any] = {
        "worker_names": sweep.names,
        "manager_motion": settings.front_motion,
        "option_steps": steps,
        "gamma": horizon_gamma(steps, algo) if steps is not None else None,
        "init_from_gpi": start == "gpi" or None,
    }
    if shared is not None:
        env_options.update(env_id=shared.env_id, env_kwargs=shared.env_kwargs)
    started = time.perf_counter()
    conditioned = train_manager(
        folder, run_dir / "conditioned", algo=algo, manager_preferences=sweep, run=run, **env_options
    ).hierarchy
    # A resumed task's conditioned manager trained before: its seconds are those of the earlier invocation.
    seconds = _conditioned_seconds(run_dir / "conditioned", time.perf_counter() - started)
    per_preference: list[tuple[str, Hierarchy]] = []
    for label, point in zip(sweep_labels(sweep), sweep.points) if settings.front_per_preference else ():
        factors = dict(zip(sweep.names, point))
        name = "manager-" + "-".join(f"{v:.3g}" for v in point)
        hierarchy = train_manager(
            folder, run_dir / name, algo=algo, preferences=factors, run=run, **env_options
        ).hierarchy
        per_preference.append((label, hierarchy))
    return conditioned, seconds, per_preference


def _conditioned_seconds(folder: Path, seconds: float) -> float:
    """
    The conditioned manager's training seconds: kept in ``folder`` the first time, read when resumed (a
    training interrupted and resumed counts only the invocation that finished it).
    """
    path = folder / "train-seconds.json"
    if path.exists():
        kept = read_json_record(path, f"{path}: not a seconds record")
        if isinstance(kept, dict) and isinstance(kept.get("seconds"), (int, float)):
            return float(kept["seconds"])
    atomic_write_json(path, {"seconds": seconds})
    return seconds


def run_front(task: MethodTask, settings: MethodSettings, folder: Path) -> dict[str, object]:
    """
    The ``front`` scenario's run of one seed (the method ``hddpg-front``): train the conditioned manager and
    one manager per sweep preference over the seed's workers, then measure every member's front on the test
    episodes (see the module's note).

    :return: the record's fields: the conditioned manager's ``history`` and ``test`` (at the unweighted
        preference), ``front`` (member -> points and hypervolumes), ``references`` and ``planes``,
        ``decides_by_state`` (the conditioned manager at each sweep preference, where the env reports
        obstacle clearance), ``rule`` and ``rule_thresholds``.
    """
    run_dir = folder / task.method
    support = task.method == SUPPORT_METHOD
    # The support method's managers and GPI act over its own copy of the workers, grown and given critics.
    workers_dir = support_folder(task, settings, folder) if support else folder
    env = front_env(settings)
    try:
        spec = front_spec(settings, env)
        sweep = support_sweep(settings, workers_dir) if support else spec.sweep
        conditioned, conditioned_seconds, per_preference = _train_managers(
            task, settings, workers_dir, sweep, run_dir
        )
        front: dict[str, object] = {}
        dependence: dict[str, DecisionFigure | None] = {}
        points = []
        seeds = settings.test_set.seeds(settings.test_episodes or 1)
        # Told the sweep's own factors, not its rounded labels: an extreme of the sweep rounded may lie
        # just outside the preferences the manager was trained over.
        for label, point in zip(sweep_labels(sweep), sweep.points):
            hierarchy = Hierarchy.load(run_dir / "conditioned" / "hierarchy.zip")
            hierarchy.set_preference(dict(zip(sweep.names, point)))
            points.append(_test_point(label, hierarchy, env, settings, spec))
            dependence[label] = decision_dependence(
                hierarchy, env, seeds, worker=spec.terms[-1], seed=task.seed
            )
        front["conditioned"] = member_fields(points, spec)
        if per_preference:
            front["per-preference"] = member_fields(
                [_test_point(label, h, env, settings, spec) for label, h in per_preference], spec
            )
        thresholds: list[dict[str, float]] = []
        if spec.rule is not None:
            rule_points, thresholds = _rule_front(spec, folder, run_dir, task.seed, env, settings)
            front[spec.rule] = member_fields(rule_points, spec)
        for worker in (*spec.terms, *(n for n in sweep.names if n not in spec.terms)):
            front[worker] = member_fields([_alone_point(worker, workers_dir, env, settings, spec)], spec)
        gpi = gpi_points(
            workers_dir,
            spec,
            lambda label, policy: _test_point(label, policy, env, settings, spec),
            run_dir / "gpi.zip",
            sweep,
            over_actions=settings.front_gpi == "actions",
        )
        if gpi is not None:  # GPI over the same workers: no manager, no env steps of its own
            front[GPI_MEMBER] = member_fields(gpi, spec)
        morl = None
        if settings.morl_python is not None:
            morl_front, morl = _morl_front(task, settings, folder, spec, env, points, conditioned_seconds)
            front[MORL_MEMBER] = member_fields(morl_front, spec)
        test = test_fields(Hierarchy.load(run_dir / "conditioned" / "hierarchy.zip"), env, settings)
    finally:
        env.close()
    return {
        "worker_timesteps": workers_steps(workers_dir),
        "manager": _manager_fields(settings, conditioned, sweep.names if support else None),
        "history": read_history(
            run_dir / "conditioned" / "evaluations" / "manager.json",
            conditioned.config.option_steps,
            workers_steps(workers_dir),
        ),
        **test,
        "front": front,
        "references": {plane: list(reference) for plane, reference in spec.references.items()},
        "planes": {plane: [list(o) for o in objectives] for plane, objectives in spec.planes.items()},
        "decides_by_state": dependence,
        "rule": spec.rule,
        "rule_thresholds": thresholds,
        **({"morl": morl} if morl is not None else {}),
    }


def _morl_front(
    task: MethodTask,
    settings: MethodSettings,
    folder: Path,
    spec: FrontSpec,
    env: gym.Env,
    conditioned: list[FrontPoint],
    conditioned_seconds: float,
) -> tuple[list[FrontPoint], MorlRun]:
    """MORL-baselines' learner for the env steps of one policy for every preference: workers and conditioned manager."""
    shared, python = settings.terms_env, settings.morl_python
    assert shared is not None and python is not None  # the settings allow it on an MO-Gymnasium env only
    return morl_member(
        python,
        shared,
        spec,
        env_contract(env).reward_bounds,
        conditioned,
        budget=workers_steps(folder) + settings.front_env_steps,
        seed=task.seed,
        test_seeds=settings.test_set.seeds(settings.test_episodes or 1),
        run_dir=folder / task.method,
        conditioned_train_s=conditioned_seconds,
    )


def _manager_fields(
    settings: MethodSettings, conditioned: Hierarchy, support: Sequence[str] | None = None
) -> FrontManager:
    """
    The front's managers as the record states them: algorithm, env steps each, options, discount, backend;
    for the support method, its workers and the managers' start.
    """
    start = settings.front_start if support is not None else None
    run = settings.front_run_options(0, start)
    steps = conditioned.config.option_steps
    fields: FrontManager = {
        "algo": settings.front_manager,
        "env_steps": run.timesteps * steps if run.timesteps else None,
        "backend": run.backend,
        "sweep": settings.front_sweep,
        "motion": settings.front_motion,
        "per_preference": settings.front_per_preference,
        "option_steps": steps,
        # Every manager algorithm, off- or on-policy, has the discount BaseAlgorithm does not declare.
        "gamma": float(cast(Any, conditioned.manager).gamma),
    }
    if support is not None:
        fields["start"] = start
        fields["workers"] = list(support)
    return fields


def _alone_point(
    worker: str, folder: Path, env: gym.Env, settings: MethodSettings, spec: FrontSpec
) -> FrontPoint:
    """The seed's ``worker`` alone: on the snake arm in the env its bundle makes, elsewhere on ``env``."""
    shared = settings.terms_env
    if shared is not None:
        return _test_point(worker, load_env_worker(folder, shared, worker), env, settings, spec)
    loaded = load_policy(folder / "workers" / f"{worker}.zip")
    worker_env = loaded.make_env(SNAKE_REACH_ENV_ID)
    try:
        return _test_point(worker, loaded.policy, worker_env, settings, spec)
    finally:
        worker_env.close()


def _rule_front(
    spec: FrontSpec, folder: Path, run_dir: Path, seed: int, env: gym.Env, settings: MethodSettings
) -> tuple[list[FrontPoint], list[dict[str, float]]]:
    """The env's rule at each threshold its sweep keeps on the curve episodes: its test points, those thresholds."""
    if spec.rule == "ham":
        n_links = state_layout_of(env)["joint_obstacle_distances"]
        ham_path = save_ham(
            run_dir / "ham.json",
            folder / "workers" / "manifest.json",
            threshold=(n_links.stop - n_links.start) / 2,  # replaced by each swept threshold below
            env_id=SNAKE_REACH_ENV_ID,
            metadata={"seed": seed},
        )
        ham = load_ham(ham_path)[0]
        switch: HAMSwitch | TTCSwitch = ham
        thresholds = ham_thresholds(ham, env, settings)
    else:
        shared = settings.terms_env
        assert shared is not None  # a rule other than HAM belongs to another env
        ttc = ttc_switch(folder, shared, env)
        switch = ttc
        thresholds = _ttc_thresholds(ttc, env, spec, settings)
    points = []
    for entry in thresholds:
        switch.threshold = entry["threshold"]
        label = f"threshold={entry['threshold']:g}"
        points.append(_test_point(label, switch, env, settings, spec))
    return points, thresholds


def _ttc_thresholds(
    switch: TTCSwitch, env: gym.Env, spec: FrontSpec, settings: MethodSettings
) -> list[dict[str, float]]:
    """The time-to-collision grid's thresholds not dominated in the terms plane on the curve episodes."""
    bounds = env_contract(env).reward_bounds
    grid = []
    for threshold in TTC_GRID:
        switch.threshold = threshold
        summary = evaluate(switch, env, n_episodes=settings.eval_episodes, seed=CURVE.first_seed).summary()
        grid.append({"threshold": threshold, **FrontPoint.of("", summary, bounds, spec.terms).values})
    kept = non_dominated(grid, spec.planes["terms"])
    return _spread([{"threshold": float(cast(float, g["threshold"]))} | _plane_values(g, spec) for g in kept])


def _plane_values(row: Mapping[str, object], spec: FrontSpec) -> dict[str, float]:
    return {key: float(cast(float, row[key])) for key, _ in spec.planes["terms"]}


#: The front scenario's method: one seed's conditioned and per-preference managers and every front.
FRONT_METHOD = "hddpg-front"


def _front_cost(settings: MethodSettings) -> int:
    # The conditioned manager and, unless left out, one manager per sweep preference, each the front's env steps.
    shared = settings.terms_env
    terms = SWEEP.names if shared is None else shared.terms
    form = settings.front_sweep
    size = len(form.split(";")) if "=" in form else len(PreferenceSpace.parse(form, terms).points)
    return (1 + (size if settings.front_per_preference else 0)) * settings.front_env_steps


def _support_cost(settings: MethodSettings) -> int:
    # The front's managers, each weighted worker's budget (about a per-term worker's) and the critics' rollouts.
    weighted = len(support_weights(settings))
    workers = len(SWEEP.names if settings.terms_env is None else settings.terms_env.terms) + weighted
    per_worker = settings.flat_budget - settings.manager_env_steps
    return (
        _front_cost(settings)
        + weighted * per_worker // max(workers - weighted, 1)
        + (workers * settings.front_critic_steps)
    )


def _front_blocks(settings: MethodSettings) -> dict[str, object]:
    return _manager_blocks(settings.front_manager, settings)


register_method(
    Method(
        FRONT_METHOD,
        run_front,
        _front_cost,
        needs_workers=True,
        colour="deeppink",
        # Its test is the conditioned manager at the unweighted preference: the hierarchy a user runs without
        # choosing a trade-off, so it is paired with every baseline as hddpg is.
        challenger=True,
        description=(
            "the front scenario: a preference-conditioned manager and a manager per preference over the "
            "preference sweep (the ratio sweep's 7 preferences for two workers by default), the env's rule "
            "over a threshold sweep (HAM on the snake arm) and each worker alone, with hypervolumes"
        ),
        config_blocks=_front_blocks,
        own_settings=FRONT_SETTINGS,
    )
)
register_method(
    Method(
        SUPPORT_METHOD,
        run_front,
        _support_cost,
        needs_workers=True,
        colour="darkviolet",
        challenger=True,
        description=(
            "the front scenario over a support: workers on weightings of the terms beside the per-term ones, "
            "a state-value critic for each, the conditioned manager over all of them (started from GPI with "
            "--front-start gpi), and GPI itself, with every member of the front"
        ),
        config_blocks=_front_blocks,
        own_settings=FRONT_SETTINGS,
    )
)
