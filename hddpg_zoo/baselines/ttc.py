"""
The time-to-collision switch: the hand-written rule of a driving env (highway-env), beside the learned manager.

The obvious rule a driver would write over a fast worker and a safe worker: drive with the fast one, and hand
over to the safe one while the time to collision with the car ahead in the ego's lane is below a threshold.
Nothing is trained; like :class:`~sb3_hddpg.baselines.ham.HAMSwitch` for the snake arm it is a policy (SB3's
``predict``) that ``evaluate`` and the benchmark run, and its threshold is tuned on the learning-curve episodes
(:data:`~sb3_hddpg.episode_sets.CURVE`), never on test episodes.

The time to collision is read from highway-env's ``Kinematics`` observation (its default): one row per vehicle,
the ego first, with features ``presence, x, y, vx, vy``; the other rows are relative to the ego and every
feature is min-max scaled to ``[-1, 1]`` by the observation's ``features_range``. :class:`KinematicsScales`
holds what the rule needs to undo that scaling, read from the env itself (:meth:`KinematicsScales.from_env`).
:class:`DecisionStates` counts a hierarchy's choices by the same quantity: the "decides by state" measure
(the safe worker's share of decisions with a car close ahead against its share with the road clear).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import gymnasium as gym
import numpy as np

from hddpg_zoo.records.results_leaves import TtcShares
from sb3_hddpg.policy import Policy

#: The default threshold, in seconds: about two seconds is the usual following-distance rule for drivers.
DEFAULT_TTC_THRESHOLD = 2.0
#: The thresholds the benchmark tries when it tunes the switch (seconds).
TTC_GRID = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 8.0)
#: The benchmark's "car close ahead" band for counting decisions: under this time to collision (seconds).
CLOSE_SECONDS = 3.0
#: The features the rule reads; highway-env's default ``Kinematics`` features include them.
REQUIRED_FEATURES = ("presence", "x", "y", "vx")


@dataclass(frozen=True)
class KinematicsScales:
    """
    How to read metres and metres per second back from a normalised ``Kinematics`` observation.

    :param features: the observation's features, in column order.
    :param x_range: the ``[low, high]`` of ``x`` (metres) that the observation maps to ``[-1, 1]``.
    :param y_range: the same for ``y``.
    :param vx_range: the same for ``vx`` (metres per second).
    :param lane_width: metres; a vehicle whose lateral offset is under half of it is in the ego's lane.
    :param vehicle_length: metres between the centres of two touching cars, one behind the other.
    :param normalized: whether the observation is scaled (``False``: already in metres).
    """

    features: tuple[str, ...]
    x_range: tuple[float, float]
    y_range: tuple[float, float]
    vx_range: tuple[float, float]
    lane_width: float = 4.0
    vehicle_length: float = 5.0
    normalized: bool = True

    def __post_init__(self) -> None:
        missing = [f for f in REQUIRED_FEATURES if f not in self.features]
        if missing:
            raise ValueError(
                f"The time-to-collision rule reads the Kinematics features {list(REQUIRED_FEATURES)}; "
                f"the observation lacks {missing}"
            )
        for name in ("x_range", "y_range", "vx_range"):
            low, high = getattr(self, name)
            if not (math.isfinite(low) and math.isfinite(high) and low < high):
                raise ValueError(
                    f"Expected `{name}` as finite (low, high) with low < high, actually: {(low, high)}"
                )

    @classmethod
    def from_env(cls, env: gym.Env) -> KinematicsScales:
        """
        The scales of a highway-env env's ``Kinematics`` observation, through any wrappers and adapters
        (an adapter keeps the env it adapts as ``inner``). The env must have been reset once: highway-env
        fills in the default ranges then.

        :raises ValueError: the env is not a highway-env env observing ``Kinematics``.
        """
        observation = _observation_type(env)
        if observation is None or type(observation).__name__ != "KinematicObservation":
            raise ValueError(
                "The time-to-collision rule needs highway-env's Kinematics observation; "
                f"{env.spec.id if env.spec else env!r} has none"
            )
        ranges = observation.features_range or {}
        if observation.normalize and not {"x", "y", "vx"} <= set(ranges):
            raise ValueError(
                "Reset the env before reading its Kinematics scales (highway-env sets them then)"
            )
        if getattr(observation, "absolute", False):
            raise ValueError("The time-to-collision rule reads relative Kinematics (absolute=False)")
        unwrapped = observation.env
        lane_width = 4.0
        ego = getattr(unwrapped, "vehicle", None)
        if ego is not None and getattr(ego, "lane", None) is not None:
            lane_width = float(ego.lane.width_at(ego.lane.local_coordinates(ego.position)[0]))
        return cls(
            features=tuple(observation.features),
            x_range=_pair(ranges.get("x", (-1.0, 1.0))),
            y_range=_pair(ranges.get("y", (-1.0, 1.0))),
            vx_range=_pair(ranges.get("vx", (-1.0, 1.0))),
            lane_width=lane_width,
            vehicle_length=float(getattr(ego, "LENGTH", 5.0)),
            normalized=bool(observation.normalize),
        )

    def _unscale(self, values: np.ndarray, span: tuple[float, float]) -> np.ndarray:
        if not self.normalized:
            return values
        low, high = span
        return low + (values + 1.0) * (high - low) / 2.0

    def relative(self, values: np.ndarray, span: tuple[float, float]) -> np.ndarray:
        """A relative feature in its own units: the scaling of a difference drops the range's offset."""
        if not self.normalized:
            return values
        return values * (span[1] - span[0]) / 2.0


def _pair(value: Sequence[float]) -> tuple[float, float]:
    low, high = value
    return float(low), float(high)


class KinematicObservation(Protocol):
    """What this module reads of highway-env's ``KinematicObservation`` (highway-env is optional)."""

    features: Sequence[str]
    features_range: Mapping[str, Sequence[float]] | None
    normalize: bool
    env: object


def _observation_type(env: object) -> KinematicObservation | None:
    """highway-env's observation object of ``env``, looking through wrappers and adapters' ``inner``."""
    seen = 0
    while env is not None and seen < 32:
        seen += 1
        observation: KinematicObservation | None = getattr(env, "observation_type", None)
        if observation is not None:
            return observation
        unwrapped = getattr(env, "unwrapped", env)
        if unwrapped is not env:
            env = unwrapped
            continue
        env = getattr(env, "inner", None)
    return None


def _vehicle_rows(observation: np.ndarray, n_features: int) -> tuple[np.ndarray, bool]:
    """
    Observations as ``(batch, vehicles, features)``, and whether they were a batch: one observation is
    ``(vehicles, features)`` or flat ``(vehicles * features,)``; a batch adds a leading axis to either.
    """
    obs = np.asarray(observation, dtype=np.float64)
    if obs.ndim == 1 and obs.size % n_features == 0:
        return obs.reshape(1, -1, n_features), False
    if obs.ndim == 2 and obs.shape[-1] == n_features:
        return obs[None], False
    if obs.ndim == 2 and obs.shape[-1] % n_features == 0:
        return obs.reshape(obs.shape[0], -1, n_features), True
    if obs.ndim == 3 and obs.shape[-1] == n_features:
        return obs, True
    raise ValueError(
        f"Expected Kinematics observations of {n_features} features per vehicle, actually shape {obs.shape}"
    )


def time_to_collision(observation: np.ndarray, scales: KinematicsScales) -> np.ndarray:
    """
    Seconds until the ego reaches the nearest car ahead in its lane at today's speeds (``inf``: no car ahead
    in the lane, or none closing in; ``0``: already touching).

    :param observation: one Kinematics observation ``(vehicles, features)``, flat or not, or a batch of them.
    :param scales: the observation's scales.
    :return: shape ``(batch,)`` (``(1,)`` for a single observation).
    """
    rows, _ = _vehicle_rows(observation, len(scales.features))
    column = {name: i for i, name in enumerate(scales.features)}
    others = rows[:, 1:, :]
    present = others[..., column["presence"]] > 0.5
    dx = scales.relative(others[..., column["x"]], scales.x_range)
    dy = scales.relative(others[..., column["y"]], scales.y_range)
    dvx = scales.relative(others[..., column["vx"]], scales.vx_range)
    ahead = present & (dx > 0) & (np.abs(dy) < scales.lane_width / 2)
    gap = np.maximum(dx - scales.vehicle_length, 0.0)
    closing = -dvx  # the other car's speed relative to the ego: negative when the ego gains on it
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(ahead & (closing > 0), gap / np.where(closing > 0, closing, 1.0), np.inf)
    return ttc.min(axis=1)


class TTCSwitch:
    """
    Run the fast worker, and the safe worker while the time to collision with the car ahead is below
    ``threshold`` seconds (with ``hysteresis`` it stays with the safe worker until it is at least
    ``threshold + hysteresis``).

    :param fast_worker: the policy that drives fast.
    :param safe_worker: the policy that avoids collisions.
    :param scales: the env's Kinematics scales (:meth:`KinematicsScales.from_env`).
    :param threshold: seconds, > 0.
    :param hysteresis: seconds, >= 0.
    :param names: the display names of the two workers, as ``(fast, safe)``: what ``last_selection`` reports.
    """

    def __init__(
        self,
        fast_worker: Policy,
        safe_worker: Policy,
        scales: KinematicsScales,
        threshold: float = DEFAULT_TTC_THRESHOLD,
        hysteresis: float = 0.0,
        names: tuple[str, str] = ("fast", "safe"),
    ) -> None:
        if len(names) != 2 or names[0] == names[1]:
            raise ValueError(f"Expected two distinct worker names (fast, safe), actually: {names}")
        if not math.isfinite(hysteresis) or hysteresis < 0:
            raise ValueError(f"Expected `hysteresis` to be a finite number >= 0, actually: {hysteresis}")
        self.threshold = threshold  # checked by the setter
        self.hysteresis = float(hysteresis)
        self.scales = scales
        self.names = list(names)
        self.workers: dict[str, Policy] = {names[0]: fast_worker, names[1]: safe_worker}
        for attribute in ("observation_space", "action_space"):
            if hasattr(fast_worker, attribute):
                setattr(self, attribute, getattr(fast_worker, attribute))
        self._safe = np.zeros(1, dtype=bool)
        self.last_selection: str | None = None

    @property
    def threshold(self) -> float:
        return self._threshold

    @threshold.setter
    def threshold(self, value: float) -> None:
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise ValueError(
                f"Expected `threshold` to be a finite number of seconds > 0, actually: {value!r}"
            )
        self._threshold = float(value)

    def select(self, observation: np.ndarray) -> np.ndarray:
        """Which worker acts on each observation (``True``: the safe one), updating the hysteresis memory."""
        ttc = time_to_collision(observation, self.scales)
        if self._safe.shape != ttc.shape:
            self._safe = np.zeros(ttc.shape, dtype=bool)
        self._safe = (ttc < self.threshold) | (self._safe & (ttc < self.threshold + self.hysteresis))
        return self._safe.copy()

    def reset_episode(self) -> None:
        """Forget the hysteresis memory (at an episode start)."""
        self._safe = np.zeros(1, dtype=bool)
        self.last_selection = None

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """The acting worker's action, like SB3's ``predict`` (one observation or a batch)."""
        if episode_start is not None:
            starts = np.asarray(episode_start, dtype=bool).reshape(-1)
            if starts.shape == self._safe.shape:
                self._safe[starts] = False
        _, batched = _vehicle_rows(observation, len(self.scales.features))
        safe = self.select(observation)
        fast_action, _ = self.workers[self.names[0]].predict(observation, deterministic=deterministic)
        safe_action, _ = self.workers[self.names[1]].predict(observation, deterministic=deterministic)
        fast, careful = np.asarray(fast_action), np.asarray(safe_action)
        if batched:
            mask = safe.reshape(-1, *([1] * (fast.ndim - 1)))
            action = np.where(mask, careful, fast)
        else:
            action = careful if safe[0] else fast
        self.last_selection = self.names[int(safe[-1])]
        return action, None


class DecisionStates:
    """
    Count a hierarchy's (or a switch's) choices by the state they were made in: with a car close ahead
    (time to collision below ``close``) or the road clear (no car ahead closing in within ``clear``).

    It wraps the policy: ``evaluate`` runs it like the policy itself (every attribute is the policy's), and
    each new decision is counted: a manager holding its choice for several steps decides once, which a new
    ``last_manager_action`` reveals; a policy without one decides every step.

    :param policy: a policy reporting ``last_selection`` (a :class:`~sb3_hddpg.hierarchy.hierarchy.Hierarchy`,
        :class:`TTCSwitch`).
    :param scales: the env's Kinematics scales.
    :param close: seconds: a decision with a smaller time to collision is made with a car close ahead.
    :param clear: seconds: one with at least this is made with the road clear (``None``: only one with no car
        ahead in the lane closing in, an infinite time to collision).
    """

    def __init__(
        self,
        policy: Policy,
        scales: KinematicsScales,
        close: float = CLOSE_SECONDS,
        clear: float | None = None,
    ) -> None:
        if not (0 < close <= (math.inf if clear is None else clear)):
            raise ValueError(f"Expected 0 < close <= clear (seconds), actually: close={close}, clear={clear}")
        self.policy = policy
        self.scales = scales
        self.close_seconds = float(close)
        self.clear_seconds = None if clear is None else float(clear)
        self.close: Counter[str] = Counter()
        self.clear: Counter[str] = Counter()
        self._last_decision: object = None

    def __getattr__(self, name: str) -> object:
        return getattr(self.__dict__["policy"], name)

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """The policy's action; counts its choice if it made a new one."""
        action, state = self.policy.predict(observation, deterministic=deterministic)
        decision = getattr(self.policy, "last_manager_action", None)
        new = decision is None or decision is not self._last_decision
        self._last_decision = decision
        selected = getattr(self.policy, "last_selection", None)
        if new and selected is not None:
            ttc = float(time_to_collision(observation, self.scales)[0])
            if ttc < self.close_seconds:
                self.close[selected] += 1
            elif ttc >= (math.inf if self.clear_seconds is None else self.clear_seconds):
                self.clear[selected] += 1
        return action, state

    def shares(self, worker: str) -> TtcShares:
        """
        ``worker``'s share of the decisions made close and clear, their ratio (``None`` where a band had no
        decision or the clear share is 0) and the decisions counted in each band.
        """
        close_total, clear_total = sum(self.close.values()), sum(self.clear.values())
        close_share = self.close[worker] / close_total if close_total else None
        clear_share = self.clear[worker] / clear_total if clear_total else None
        ratio = close_share / clear_share if close_share is not None and clear_share else None
        return {
            "worker": worker,
            "close_share": close_share,
            "clear_share": clear_share,
            "ratio": ratio,
            "close_decisions": close_total,
            "clear_decisions": clear_total,
            "close_seconds": self.close_seconds,
            "clear_seconds": self.clear_seconds,
        }
