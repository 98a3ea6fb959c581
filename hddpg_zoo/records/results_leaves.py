"""
The JSON shapes of the leaves of a benchmark's ``results.json`` (:mod:`.results`): a summary over seeds, a
paired difference, an interval, rliable's aggregates, the transfer and front figures. Each stays the JSON
object it is written as, typed by its :class:`~typing.TypedDict`.
"""

from __future__ import annotations

from typing import NotRequired, TypedDict


class Summary(TypedDict):
    """Values over seeds: mean, sample standard deviation, count, bootstrap CI of the mean, IQM."""

    mean: float
    std: float
    n: int
    ci_low: float
    ci_high: float
    iqm: float


class Interval(TypedDict):
    """A point estimate with its interval (rliable's aggregates, probabilities of improvement)."""

    value: float
    ci_low: float
    ci_high: float


class PairedDifference(TypedDict, total=False):
    """
    One metric of a paired comparison over seeds: the mean difference with its Student t interval and
    p-value, and once the table is adjusted (Holm p-value, the interval at its Holm-consistent level), the seeds
    where A scored higher and the equivalence margin of "level"; files written before a
    field existed lack it.
    """

    difference: float
    ci_low: float
    ci_high: float
    p_value: float
    standard_error: float
    relative_gain: float | None
    probability_of_improvement: float
    p_holm: float
    ci_low_adjusted: float
    ci_high_adjusted: float
    confidence_adjusted: float
    seeds_higher: int
    equivalence_margin: float


class ComparisonFamily(TypedDict):
    """One challenger's table of comparisons: their number per metric and how the table is adjusted."""

    comparisons: dict[str, int]
    adjustment: str


class Aggregates(TypedDict):
    """
    rliable's aggregates of the score over seeds (``unit``: the runs of the matrix; ``tasks``: its columns): per
    method IQM and mean, per compared pair P(A > B); and per method the episodes' spread within a seed.
    """

    metric: str
    unit: str
    tasks: int
    intervals: dict[str, dict[str, Interval]]
    probability_of_improvement: dict[str, Interval]
    episode_spread: NotRequired[dict[str, float]]


class TransferSeed(TypedDict):
    """One seed of a transfer comparison: own steps to 90 % of the final score, their ratio, the scores."""

    manager_steps: int | None
    flat_steps: int | None
    ratio: float | None
    flat_steps_to_manager_final: int | None
    manager_final_score: float
    flat_final_score: float
    random_score: float
    worker_timesteps: int
    target_score: NotRequired[float | None]
    manager_steps_to_target: NotRequired[int | None]
    flat_steps_to_target: NotRequired[int | None]
    ratio_to_target: NotRequired[float | None]
    censored: NotRequired[str]


class TransferComparison(TypedDict):
    """A hierarchy against a flat method under one preference, per seed and over seeds."""

    manager: str
    flat: str
    per_seed: dict[str, TransferSeed]
    ratio: Summary | None
    seeds_with_ratio: int
    seeds_flat_reaches_manager: int


class TransferResults(TypedDict):
    """The transfer scenario's figure: per preference, per comparison key, the steps' ratios."""

    fraction: float
    definition: str
    eval_freq: int
    preferences: dict[str, dict[str, TransferComparison]]


class DependenceFigure(TypedDict):
    """
    Whether a hierarchy chooses by state (:func:`~sb3_hddpg.evaluation.state_dependence`): a worker's share
    of the choices near an obstacle and with none in range, their ratio and the choices in each band.
    """

    worker: str
    near_share: float | None
    clear_share: float | None
    ratio: float | None
    near_choices: int
    clear_choices: int
    near_clearance: float
    clear_clearance: float


class TtcShares(TypedDict):
    """
    On highway-env, a worker's share of the decisions made with a car close ahead and with the road clear,
    their ratio and the decisions in each band (:meth:`~hddpg_zoo.baselines.ttc.DecisionStates.shares`).
    """

    worker: str
    close_share: float | None
    clear_share: float | None
    ratio: float | None
    close_decisions: int
    clear_decisions: int
    close_seconds: float
    clear_seconds: float | None


class FrontDifference(TypedDict):
    """A paired difference of two members' hypervolumes in one plane over seeds."""

    difference: float
    ci_low: float
    ci_high: float
    p_value: float
    wins: int
    probability_of_improvement: float
    standard_error: NotRequired[float]
    equivalence_margin: NotRequired[float]
    p_holm: NotRequired[float]
    confidence_adjusted: NotRequired[float]
    ci_low_adjusted: NotRequired[float]
    ci_high_adjusted: NotRequired[float]


class FrontComparison(TypedDict):
    """Two members of the front compared in each plane over their seeds."""

    seeds: list[int]
    #: plane -> the difference there (``outcomes`` and ``terms`` on the snake arm; ``terms`` and ``returns``
    #: on another env)
    planes: dict[str, FrontDifference]


class DecisionFigure(TypedDict):
    """
    Whether the conditioned manager decides by state, per decision: the worker's share near an obstacle and
    with none in range, their ratio with a bootstrap interval over episodes, and the decisions counted.
    """

    worker: str
    near_share: float | None
    clear_share: float | None
    near_decisions: int
    clear_decisions: int
    ratio: float | None
    ratio_ci: list[float] | None
    near_clearance: float
    clear_clearance: float
    unit: str


class FrontManager(TypedDict):
    """The front's managers: their algorithm, each one's budget in env steps and the backend that trained them."""

    algo: str
    env_steps: int | None
    #: the backend that trained them (absent from a front recorded before it was kept)
    backend: NotRequired[str | None]
    #: the preferences they were trained over and measured at (absent before it could change: ratio-sweep)
    sweep: NotRequired[str]
    #: their motion scale (absent before they could see motion: 0)
    motion: NotRequired[float]
    #: whether a manager per preference was trained beside the conditioned one (absent before optional: yes)
    per_preference: NotRequired[bool]
    #: env steps per decision, each option's length (absent from a front recorded before it was kept)
    option_steps: NotRequired[int]
    #: their discount per decision (absent from a front recorded before it was kept)
    gamma: NotRequired[float]
    #: how the conditioned manager started (``gpi``; absent: from its random initialisation)
    start: NotRequired[str | None]
    #: the support method's workers, per-term and weighted (absent from the front over per-term workers)
    workers: NotRequired[list[str]]


class SafeTouch(TypedDict):
    """Per member and seed, the most goal touch among its front's points with at most ``contacts`` contacts."""

    contacts: float
    #: member -> seed -> the touch rate (``None``: no point of that seed's front is that safe)
    per_seed: dict[str, dict[str, float | None]]
    #: member -> seed -> the safe point of highest reach reward, ``{"reach", "touch"}`` (absent before kept)
    best_reach: NotRequired[dict[str, dict[str, dict[str, float] | None]]]


class MorlResults(TypedDict):
    """
    A MORL library's learner beside the conditioned manager over seeds: each front scored by the library's own
    indicators, and the wall-clock each took to train.
    """

    algorithm: str
    #: the learner's training env steps per seed (the hierarchy's workers and conditioned manager together)
    env_steps: list[int]
    ref_point: list[float]
    #: member -> indicator (``hypervolume``, ``expected_utility``) -> its values over seeds
    scores: dict[str, dict[str, Summary]]
    #: member -> seconds of training over seeds (the hierarchy: its workers' task and the conditioned manager)
    train_seconds: dict[str, Summary]
    versions: dict[str, str | None]


class FrontResults(TypedDict):
    """
    The front scenario's figures over seeds: per member and plane the hypervolumes (per seed and their
    summary), the paired comparisons, the decides-by-state figures and every seed's points.
    """

    members: list[str]
    references: dict[str, list[float]]
    #: plane -> its objectives, each ``[key, larger is better]``
    planes: dict[str, list[list[object]]]
    hypervolume_per_seed: dict[str, dict[str, dict[str, float]]]
    hypervolume: dict[str, dict[str, Summary]]
    comparisons: dict[str, FrontComparison]
    decides_by_state: dict[str, dict[str, DecisionFigure | None]]
    points: dict[str, dict[str, list[dict[str, float | str]]]]
    #: absent from a front measured before its managers' algorithm was a setting (DDPG, the manager's budget)
    manager: NotRequired[FrontManager]
    #: absent from a front measured before the safe end was summarised (its points give it)
    safe_touch: NotRequired[SafeTouch]
    #: a MORL library's learner beside the hierarchy (``benchmark --morl-python``)
    morl: NotRequired[MorlResults]
    #: flat method -> seed -> its reach reward and env steps: flat runs of the workers' benchmark on the same
    #: test episodes, beside the equal-weighting point
    flat: NotRequired[dict[str, dict[str, dict[str, float]]]]
