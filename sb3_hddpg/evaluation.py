"""
``evaluate(policy, env)``: the environment's own metrics over fixed evaluation seeds, and
:func:`state_dependence`, whether a hierarchy's choice of worker depends on the state.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any, cast

import gymnasium as gym
import numpy as np
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

from sb3_hddpg.artifacts.limits import check_count
from sb3_hddpg.envs.contract import Proximity, TermNormaliser, env_contract, proximity_of
from sb3_hddpg.episode_metrics import SATURATION_LEVEL as SATURATION_LEVEL
from sb3_hddpg.episode_metrics import EpisodeMetrics, EpisodeTally, finite_episode
from sb3_hddpg.episode_sets import CURVE
from sb3_hddpg.metric_labels import MetricLabel, metric_label, same_returns, summary_rows, units_caption
from sb3_hddpg.policy import Policy

#: The evaluation seeds are ``EVAL_SEED_BASE + k`` for episode ``k`` unless a seed is given: far from
#: training seeds, and the same for every method so that comparisons are paired.
EVAL_SEED_BASE = CURVE.first_seed
#: The worker whose share :func:`state_dependence` reports by default: the snake env's obstacle avoider.
DEPENDENCE_WORKER = "avoid"


class EvaluationSummary(dict[str, Any]):
    """The means of an evaluation: a JSON-ready dict (rates as fractions), printed as a table with units."""

    def __str__(self) -> str:
        rows = summary_rows(self)
        width = max((len(quantity) for quantity, _, _ in rows), default=0)
        lines = [f"{self.get('episodes', 0)} episodes"]
        lines += [f"  {quantity:<{width}}  {value} {unit}".rstrip() for quantity, value, unit in rows]
        return "\n".join(lines)


@dataclass
class EvaluationResult:
    """Metrics over several episodes; :meth:`summary` gives means."""

    episodes: list[EpisodeMetrics]
    #: The clearance bands of ``selections_near`` / ``selections_clear`` (``None`` when not measured).
    near_clearance: float | None = None
    clear_clearance: float | None = None

    def summary(self) -> EvaluationSummary:
        """Means (and the reward's std) over episodes, and how often each worker acted, as a fraction."""
        eps = self.episodes
        rewards = np.array([e.reward for e in eps])
        out: dict[str, Any] = {
            "episodes": len(eps),
            "mean_reward": float(rewards.mean()),
            "std_reward": float(rewards.std()),
            "mean_reach_reward": float(np.mean([e.reach_reward for e in eps])),
        }
        for term in eps[0].term_rewards:
            out[f"mean_{term}_reward"] = float(np.mean([e.term_rewards[term] for e in eps]))
        if eps[0].goal_touch_rate is not None:  # the env reports touches and collisions (the snake env)
            out["goal_touch_rate"] = float(np.mean([e.goal_touch_rate for e in eps]))
            out["goal_reached_rate"] = float(np.mean([e.goal_touched for e in eps]))
            out["collisions_per_episode"] = float(np.mean([e.collisions for e in eps]))
            out["success_rate"] = float(np.mean([e.success for e in eps]))
        if eps[0].min_clearance is not None:
            out["min_clearance"] = float(np.mean([e.min_clearance for e in eps]))
        saturation = [e.action_saturation for e in eps if e.action_saturation is not None]
        if saturation:
            out["action_saturation"] = float(np.mean(saturation))
        out["mean_length"] = float(np.mean([e.length for e in eps]))
        total: Counter[str] = Counter()
        for e in eps:
            total.update(e.selections)
        if total:
            steps = sum(total.values())
            out["selection_rate"] = {name: count / steps for name, count in sorted(total.items())}
            for band in ("near", "clear"):
                counts = sum((Counter(getattr(e, f"selections_{band}")) for e in eps), Counter[str]())
                out[f"selections_{band}"] = {name: counts.get(name, 0) for name in sorted(total)}
            if eps[0].collisions is not None:
                # Which worker acted at each contact: a goal worker left in charge near obstacles shows here.
                out["collisions_by_worker"] = {
                    name: float(np.mean([e.collisions_by_worker.get(name, 0) for e in eps]))
                    for name in sorted(total)
                }
            out["near_clearance"] = self.near_clearance
            out["clear_clearance"] = self.clear_clearance
        return EvaluationSummary(out)

    def to_dict(self) -> dict[str, Any]:
        """Summary and every episode, JSON-ready."""
        return {"summary": self.summary(), "episodes": [asdict(e) for e in self.episodes]}


def evaluate(
    policy: Policy,
    env: gym.Env | VecEnv | None = None,
    n_episodes: int = 20,
    seed: int = EVAL_SEED_BASE,
    deterministic: bool = True,
    on_step: Callable[[gym.Env, dict[str, Any]], None] | None = None,
    near_clearance: float | None = None,
    clear_clearance: float | None = None,
) -> EvaluationResult:
    """
    Run ``policy`` for ``n_episodes`` on ``env``, resetting episode ``k`` with seed ``seed + k``.

    The env meets the env contract (:mod:`sb3_hddpg.envs.contract`): per-term sums and the normalised total
    are measured on any such env, touches, collisions and clearance where ``info`` reports them. The worker a
    hierarchy or a manager's wrapper chose is counted, also by the state it chose in: nearest obstacle within
    ``near_clearance``, or none within ``clear_clearance`` (see :func:`state_dependence`).

    :param policy: anything with SB3's ``predict``.
    :param env: a time-limited env (default, for a policy with ``make_env()`` such as a ``Hierarchy``: its
        own, closed afterwards); or a VecEnv of such envs, which runs ``num_envs`` episodes at a time with the
        same seeds, ``predict`` given the batch with its ``state`` and ``episode_start``.
    :param n_episodes: how many episodes, 1 to 10,000.
    :param seed: the first episode's seed.
    :param deterministic: passed to ``predict``.
    :param on_step: called after every step with the env and its ``info`` (for recording; of a VecEnv only
        a ``DummyVecEnv``).
    :param near_clearance: a choice counts as "near an obstacle" at a clearance <= this (default: half the
        ``sensor_range`` of the env's declared :class:`~sb3_hddpg.envs.contract.Proximity`; an env that
        declares none refuses a band).
    :param clear_clearance: a choice counts as "no obstacle in range" at a clearance >= this (default: the
        env's ``sensor_range``).
    :return: per-episode metrics.
    """
    check_count("episodes", n_episodes, "n_episodes")
    if env is None:
        make_env = getattr(policy, "make_env", None)
        if not callable(make_env):
            raise ValueError(
                f"evaluate() needs env= for a {type(policy).__name__}: only a policy with make_env() "
                "(a Hierarchy) knows its env"
            )
        own_env = make_env()
        try:
            return evaluate(
                policy, own_env, n_episodes, seed, deterministic, on_step, near_clearance, clear_clearance
            )
        finally:
            own_env.close()
    if isinstance(env, VecEnv):
        return _evaluate_vec_env(
            policy, env, n_episodes, seed, deterministic, on_step, near_clearance, clear_clearance
        )
    near_clearance, clear_clearance = clearance_bands(env, near_clearance, clear_clearance)
    normaliser = TermNormaliser(env_contract(env).reward_bounds)
    episodes = []
    worker_names = _worker_names(policy, env)
    for k in range(n_episodes):
        obs, info = env.reset(seed=seed + k)
        getattr(policy, "reset_episode", lambda: None)()
        tally = EpisodeTally(normaliser, worker_names, near_clearance, clear_clearance, info)
        done = False
        while not done:
            action, _ = policy.predict(obs, deterministic=deterministic)
            decision = getattr(policy, "last_manager_action", None)  # a hierarchy's manager decided
            tally.add_decision(np.asarray(action if decision is None else decision))
            obs, reward, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            tally.add_env_step(float(reward), info, getattr(policy, "last_selection", None))
            if on_step is not None:
                on_step(env, info)
        episodes.append(finite_episode(tally.metrics(seed + k)))
    return EvaluationResult(episodes, near_clearance, clear_clearance)


def _evaluate_vec_env(
    policy: Policy,
    vec_env: VecEnv,
    n_episodes: int,
    seed: int,
    deterministic: bool,
    on_step: Callable[[gym.Env, dict[str, Any]], None] | None,
    near_clearance: float | None,
    clear_clearance: float | None,
) -> EvaluationResult:
    """:func:`~sb3_hddpg.evaluation.evaluate` on a VecEnv: episode ``k`` with seed ``seed + k``."""
    inner = vec_env.unwrapped
    envs = list(inner.envs) if isinstance(inner, DummyVecEnv) else None  # None: envs in other processes
    if on_step is not None and envs is None:
        raise ValueError(
            f"evaluate(): `on_step` is given the env that stepped, which a {type(vec_env.unwrapped).__name__} runs in "
            "another process; use a DummyVecEnv to record"
        )
    normaliser, proximity, name = _declared_terms(vec_env)
    near_clearance, clear_clearance = _bands_of(proximity, name, near_clearance, clear_clearance)
    names = getattr(policy, "names", None)
    if names is None:  # a manager's env (a WorkerSelectionWrapper) names the workers it chooses among
        names = vec_env.get_attr("worker_names", [0])[0] if vec_env.has_attr("worker_names") else []
    n_envs = vec_env.num_envs
    episodes: list[EpisodeMetrics] = []
    state: Any = None
    for first in range(0, n_episodes, n_envs):
        vec_env.seed(seed + first)  # env i's next reset: seed + first + i
        # The env contract's observations are arrays (a Box); SB3 types a VecEnv's more widely.
        obs = cast(np.ndarray, vec_env.reset())
        tallies = [
            EpisodeTally(normaliser, list(names), near_clearance, clear_clearance, vec_env.reset_infos[i])
            for i in range(min(n_envs, n_episodes - first))
        ]
        # Envs past this round's last episode step along (a VecEnv steps all) but are not counted.
        running = np.arange(n_envs) < len(tallies)
        starts = np.ones(n_envs, dtype=bool)
        while running.any():
            action, state = policy.predict(
                obs, state=state, episode_start=starts, deterministic=deterministic
            )
            selections = getattr(policy, "last_selections", None) or [None] * n_envs
            decisions = getattr(policy, "last_manager_actions", None)
            step_obs, rewards, dones, infos = vec_env.step(action)
            obs = cast(np.ndarray, step_obs)
            for i in np.flatnonzero(running):
                tallies[i].add_decision(np.asarray(action[i] if decisions is None else decisions[i]))
                tallies[i].add_env_step(float(rewards[i]), infos[i], selections[i])
                if on_step is not None and envs is not None:
                    on_step(envs[i], infos[i])
            running &= ~dones
            starts = dones
        episodes += [finite_episode(t.metrics(seed + first + i)) for i, t in enumerate(tallies)]
    return EvaluationResult(episodes, near_clearance, clear_clearance)


def _declared_terms(vec_env: VecEnv) -> tuple[TermNormaliser, Proximity | None, str]:
    """
    The first env's reward terms' normaliser, proximity (``None``: none) and name, asked through ``get_attr``
    (which reaches envs in other processes); a one-line ``ValueError`` for envs that declare no terms.
    """
    spec = vec_env.get_attr("spec", [0])[0]
    name = repr(spec.id) if spec is not None else "the VecEnv's first env"
    if not (vec_env.has_attr("reward_bounds") and vec_env.has_attr("normalise_terms")):
        raise ValueError(
            f"Expected envs that declare their reward terms (`reward_bounds` and `normalise_terms`, see "
            f"sb3_hddpg.envs.contract), actually: {name}; wrap them with sb3_hddpg.envs.adapters"
        )
    proximity = vec_env.get_attr("proximity", [0])[0] if vec_env.has_attr("proximity") else None
    normaliser = TermNormaliser(vec_env.get_attr("reward_bounds", [0])[0])
    return normaliser, proximity if isinstance(proximity, Proximity) else None, name


def clearance_bands(
    env: gym.Env, near: float | None, clear: float | None
) -> tuple[float | None, float | None]:
    """
    The clearance bands of :func:`evaluate`, checked, defaulting to half and all the ``sensor_range`` of the
    env's declared :class:`~sb3_hddpg.envs.contract.Proximity`; both ``None`` for an env that declares none.

    :raises ValueError: a band that is negative or not finite, ``near > clear``, or a band given for an env
        without a proximity (it would count no choice at all, silently).
    """
    spec = env.unwrapped.spec
    return _bands_of(proximity_of(env), repr(spec.id) if spec else type(env.unwrapped).__name__, near, clear)


def _bands_of(
    proximity: Proximity | None, env_name: str, near: float | None, clear: float | None
) -> tuple[float | None, float | None]:
    """:func:`clearance_bands` of an env that declares ``proximity`` (``None``: none), named ``env_name``."""
    if proximity is None:
        given = next(
            (n for n, v in (("near_clearance", near), ("clear_clearance", clear)) if v is not None), None
        )
        if given is not None:
            raise ValueError(
                f"`{given}` is not available for this env: {env_name} declares no proximity (no "
                "`proximity` with a sensor range, no info['min_clearance']; see sb3_hddpg.envs.contract)"
            )
        return None, None
    near = 0.5 * proximity.sensor_range if near is None else near
    clear = proximity.sensor_range if clear is None else clear
    for name, value in (("near_clearance", near), ("clear_clearance", clear)):
        if not (math.isfinite(value) and value >= 0):
            raise ValueError(f"Expected `{name}` to be a finite number >= 0, actually: {value}")
    if near > clear:
        raise ValueError(f"Expected `near_clearance` <= `clear_clearance`, actually: {near} > {clear}")
    return near, clear


def state_dependence(summary: dict[str, Any], worker: str = DEPENDENCE_WORKER) -> dict[str, Any] | None:
    """
    Whether a hierarchy chooses by state: ``worker``'s share of the choices made near an obstacle against
    its share where none is in range, and their ratio (well above 1 for a manager that decides by state,
    about 1 for a fixed mix).

    :param summary: an :meth:`EvaluationResult.summary` (of a policy that reports its worker choices).
    :param worker: the worker whose share is compared.
    :return: ``near_share``, ``clear_share`` and ``ratio`` (each ``None`` where a band had no choices or the
        clear share is 0), the choices in each band, the bands and the worker; ``None`` without choices,
        without ``worker`` or without clearance bands.
    """
    near, clear = summary.get("selections_near"), summary.get("selections_clear")
    if near is None or clear is None or worker not in summary.get("selection_rate", {}):
        return None
    if summary.get("near_clearance") is None or summary.get("clear_clearance") is None:
        return None
    near_total, clear_total = sum(near.values()), sum(clear.values())
    near_share = near.get(worker, 0) / near_total if near_total else None
    clear_share = clear.get(worker, 0) / clear_total if clear_total else None
    ratio = near_share / clear_share if near_share is not None and clear_share else None
    return {
        "worker": worker,
        "near_share": near_share,
        "clear_share": clear_share,
        "ratio": ratio,
        "near_choices": near_total,
        "clear_choices": clear_total,
        "near_clearance": summary.get("near_clearance"),
        "clear_clearance": summary.get("clear_clearance"),
    }


def dependence_ratio_text(figure: dict[str, Any]) -> str:
    """
    A :func:`state_dependence` ratio as text. Where the ratio is ``None`` it says why: ``"inf"`` when the
    worker is chosen near obstacles but never with none in range (a rule such as HAM's that reads the
    distances), ``"never chosen"`` when it is chosen in neither band, ``"n/a"`` when a band had no choices.
    """
    near, clear, ratio = figure["near_share"], figure["clear_share"], figure["ratio"]
    if ratio is not None:
        return f"{ratio:.2f}"
    if near is None or clear is None:
        return "n/a"
    return "inf" if near > 0 else "never chosen"


def dependence_rows(figure: dict[str, Any], worker: str) -> list[tuple[str, str, str]]:
    """
    A :func:`state_dependence` figure as rows of quantity, value and unit: ``worker``'s share of the choices
    near an obstacle and with none in range (each with the number of choices it is out of), and their ratio.
    """
    rows = []
    for band, sign, note in (("near", "<=", ""), ("clear", ">=", " (none in range)")):
        share, choices = figure[f"{band}_share"], figure[f"{band}_choices"]
        rows.append(
            (
                f"{worker} share, clearance {sign} {figure[f'{band}_clearance']:.3g}{note}",
                f"{share:.1%} of {choices}" if share is not None else "- (0 choices)",
                "of choices",
            )
        )
    return [*rows, (f"{worker} share ratio near / none in range", dependence_ratio_text(figure), "ratio")]


@dataclass(frozen=True)
class SummariesTable:
    """
    Evaluation summaries as a table of text, one row per agent, each column in one unit (named in the
    caption, so that the table fits an 80-column terminal); the CLI draws it.

    :param title: the table's title.
    :param caption: the units of the columns.
    :param columns: the column headers after the agent's.
    :param rows: per agent, its name and one text per column.
    """

    title: str
    caption: str
    columns: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]


def summaries_table(
    title: str, summaries: Mapping[str, Mapping[str, Any]], reward: MetricLabel | None = None
) -> SummariesTable:
    """
    The table of evaluation summaries a training command prints: the reward with its spread, the normalised
    return where it differs, the snake's touch and collision rates (else every reward term) and the deciding
    network's saturation.

    :param title: the table's title.
    :param summaries: agent -> its evaluation summary.
    :param reward: what ``mean_reward`` is for these agents (default: the env's own reward).
    """
    # The closest approach to an obstacle is in the evaluation history (and `evaluate`): 80 columns hold no more.
    snake = ("goal_touch_rate", "collisions_per_episode", "success_rate")
    shown = [k for k in snake if any(k in row for row in summaries.values())] or [
        k
        for row in list(summaries.values())[:1]
        for k in row
        if k not in ("mean_reward", "mean_reach_reward") and k.startswith("mean_") and k.endswith("_reward")
    ]
    # The return of the normalised terms where it is not the reward itself (on the snake's reach env it is).
    same = all(same_returns(row) for row in summaries.values())
    normalised = [] if same else ["mean_reach_reward"]
    # Share of the deciding network's outputs pinned at +-1 (a saturated actor has stopped learning).
    keys = ("mean_reward", *normalised, *shown, "action_saturation")
    labels = {key: metric_label(key) for key in keys}
    labels["mean_reward"] = reward or labels["mean_reward"]
    if same:
        names = (labels["mean_reward"].short, metric_label("mean_reach_reward").short)
        labels["mean_reward"] = replace(labels["mean_reward"], short=" = ".join(dict.fromkeys(names)))
    rows = []
    for name, summary in summaries.items():
        cells = [name]
        for key in keys:
            label = labels[key]
            cell = label.format(summary[key]) if key in summary else "-"
            if key == "mean_reward" and "std_reward" in summary:
                cell += f" ± {label.format(summary['std_reward'])}"
            cells.append(cell)
        rows.append(tuple(cells))
    return SummariesTable(
        title,
        units_caption(list(labels.values())),
        tuple(labels[key].short or labels[key].label for key in keys),
        tuple(rows),
    )


def _worker_names(policy: object, env: gym.Env) -> list[str]:
    """The workers a hierarchy (``policy``) or a manager's env (a ``WorkerSelectionWrapper``) chooses among."""
    names = getattr(policy, "names", None)
    if names is not None:
        return list(names)
    try:
        return list(env.get_wrapper_attr("worker_names"))
    except AttributeError:
        return []
