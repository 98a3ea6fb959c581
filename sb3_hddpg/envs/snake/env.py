"""The snake arm env: gymnasium's API over the arm's physics, movers and reward terms."""

from __future__ import annotations

import atexit
import math
import struct
import weakref
from collections.abc import Mapping, Sequence
from dataclasses import fields
from typing import TYPE_CHECKING, Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_hddpg.envs.contract import Proximity, TermNormaliser
from sb3_hddpg.envs.layout import StateLayout, build_state_layout
from sb3_hddpg.envs.snake.movers import Movers
from sb3_hddpg.envs.snake.params import REWARD_TERMS, SnakeParams, check_choice
from sb3_hddpg.envs.snake.physics import ArmPhysics, body_angle
from sb3_hddpg.envs.snake.rewards import GoalTerm, avoid_term, reward_bounds
from sb3_hddpg.envs.snake.view import SnakeView

if TYPE_CHECKING:
    import pymunk

    from sb3_hddpg.envs.snake.rendering import SnakeRenderer


class SnakeArmEnv(gym.Env[np.ndarray, np.ndarray]):
    r"""
    ## Description

    A planar snake arm of ``n_joints`` revolute joints in a chain, fixed at a base in the middle of a disc
    shaped workspace, must touch a goal point that random-walks inside its reach while ``n_obstacles``
    discs random-walk through the workspace (Um, Nethala & Shin, *AI* 2022, Section 3 and Figure 2).
    Reaching and avoiding conflict: the straight way to the goal often crosses an obstacle.

    Lengths are in units of the arm's reach: every link is ``1 / n_joints`` long, so the stretched arm
    reaches exactly 1.

    The arm is simulated by pymunk: every link is a thin rod (each 0.6 times as heavy as its parent), joined
    to its parent by a ``PivotJoint`` and driven by a ``SimpleMotor`` at the commanded joint velocity. A soft
    limit slows every joint but the base so that it stops at ``±joint_limit`` radians, as a servo would.
    **Self-collision** is not simulated: the links pass through each other, and the joint limits keep the
    chain from folding back onto itself. **Obstacles** are kinematic discs: like the paper's robot with a
    sensitive skin, the arm is not pushed by an obstacle but *touches* it, which the avoid reward penalises.
    The goal and the obstacles move by a bounded random walk of their velocity (speed capped at
    ``goal_speed`` / ``obstacle_speed`` reach per second), reflected at the edge of their region.

    ## Action Space

    ``Box(-1, 1, (n_joints,), float32)``: joint velocity commands, scaled to ``max_joint_speed`` rad/s;
    positive turns counter-clockwise. Index ``i`` drives joint ``i`` (joint 0 is the base).

    ## Observation Space

    ``Box(low, high, (6 * n_joints + 3,), float32)``, the paper's shared state (Table 1). "Link ``i``" is the
    link that joint ``i`` drives; its *obstacle* is the obstacle whose disc is closest to the link segment.
    With ``n = n_joints``:

    | Index           | Name (``state_layout``)  | Meaning                                                        | Min | Max |
    |-----------------|--------------------------|----------------------------------------------------------------|-----|-----|
    | 0 .. 2n-1       | ``joint_positions``      | (x, y) of the far end of each link (joints 2..n, then the tip) | -1  | 1   |
    | 2n .. 2n+1      | ``ee_to_goal``           | (goal - tip) / 2                                               | -1  | 1   |
    | 2n+2 .. 4n+1    | ``joint_obstacle_vectors``| (obstacle centre - closest point of link i) / 2, per link     | -1  | 1   |
    | 4n+2 .. 5n+1    | ``joint_obstacle_distances``| clearance of link i to the disc surface / ``sensor_range``, clipped | 0 | 1 |
    | 5n+2            | ``goal_touched``         | 1 if the tip is within ``touch_radius`` of the goal            | 0   | 1   |
    | 5n+3 .. 6n+2    | ``obstacle_touched``     | 1 if link i touches its closest obstacle                       | 0   | 1   |

    The total length is therefore ``6 n + 3`` (39 for the default six joints); joint velocities are not
    observed, since the motors hold the commanded rates. ``env.unwrapped.state_layout`` maps every name above
    to its slice (the paper's design specification 4). With ``observe=[names...]`` the env returns only
    those components, in that order: ``state_layout`` still describes the full state, and
    ``observed_components`` lists what the observation holds.

    ## Rewards

    Both terms of Table 2 are computed every step and returned in ``info["reward_terms"]``:

    - ``goal = -d + 1[d <= touch_radius]`` with ``d`` the tip-to-goal distance;
    - ``avoid = r_bf * sum_i c_i - 1[any link touches an obstacle]`` with ``c_i`` the clearance of link ``i``
      to its closest obstacle surface, clipped to ``[0, sensor_range]`` (a skin sensor's range: beyond it,
      farther is not safer, so the avoid worker is not paid to curl up away from the task).

    ``env.unwrapped.reward_bounds`` gives each term's exact per-step ``(low, high)``:
    ``goal in [-(1 + goal_radius_max), 1]`` and ``avoid in [-1, r_bf * n_joints * sensor_range]``.
    The step reward is chosen by the ``reward`` argument: ``"goal"`` or ``"avoid"`` (one term, raw, as a
    worker learns it) or ``"reach"``: the sum of both terms, each min-max normalised to [0, 1] with
    ``reward_bounds`` (the single-DDPG baseline's task, and the manager's reward with preferences 1).

    ## Starting State

    The base joint angle is uniform in ``[-pi, pi)``, every other joint uniform in ``[-0.5, 0.5]`` rad, all
    at rest. The goal starts uniform in the goal annulus; obstacles start uniform in the obstacle annulus,
    at least ``spawn_margin`` from the arm's links and from the goal (re-drawn until so).

    ## Episode End

    The task is continuing: the episode never terminates (a collision is penalised, not fatal). It is
    truncated by the registered ``max_episode_steps`` (200). ``info`` at every step reports
    ``reward_terms``, ``goal_touched``, ``collision``, ``min_clearance``, ``distance_to_goal`` and
    ``is_success``: the goal was touched at least once and no link has touched an obstacle so far in the
    episode; read at the last step it is the episode's success.

    ## Arguments

    ``gym.make("hddpg/SnakeReach-v0", n_joints=6, n_obstacles=3, ...)``; every argument is also a keyword of
    this class. See :meth:`__init__`.

    ## Version History

    - v0: initial version.
    """

    # The parameters' values, set from :attr:`params` (``reward`` as ``reward_name``).
    reward_name: str
    n_joints: int
    n_obstacles: int
    obstacle_radius: float
    obstacle_speed: float
    goal_speed: float
    touch_radius: float
    r_bf: float
    sensor_range: float
    max_joint_speed: float
    joint_limit: float
    dt: float
    substeps: int
    goal_radius_min: float
    goal_radius_max: float
    obstacle_radius_min: float
    obstacle_radius_max: float
    spawn_margin: float

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"], "render_fps": 10}  # type: ignore[misc]

    def __init__(
        self,
        reward: str = "reach",
        n_joints: int = 6,
        n_obstacles: int = 3,
        obstacle_radius: float = 0.08,
        obstacle_speed: float = 0.15,
        goal_speed: float = 0.08,
        touch_radius: float = 0.1,
        r_bf: float = 0.2,
        sensor_range: float = 0.3,
        max_joint_speed: float = 1.5,
        joint_limit: float = 2.4,
        dt: float = 0.1,
        substeps: int = 2,
        goal_radius_min: float = 0.3,
        goal_radius_max: float = 0.9,
        obstacle_radius_min: float = 0.35,
        obstacle_radius_max: float = 1.0,
        spawn_margin: float = 0.1,
        observe: Sequence[str] | None = None,
        render_mode: str | None = None,
    ) -> None:
        """
        :param reward: the step reward: ``"goal"``, ``"avoid"`` or ``"reach"`` (see Rewards).
        :param n_joints: number of revolute joints (and links), 2 to 32.
        :param n_obstacles: number of moving obstacle discs, 1 to 32.
        :param obstacle_radius: radius of every obstacle disc, in reach units.
        :param obstacle_speed: the obstacles' top speed, reach units per second.
        :param goal_speed: the goal's top speed, reach units per second.
        :param touch_radius: the tip touches the goal within this distance.
        :param r_bf: the avoid reward's factor on the summed clearances (Table 2's ``r_bf``).
        :param sensor_range: clearances are clipped to this range in the reward and observation.
        :param max_joint_speed: joint speed, rad/s, commanded by an action of magnitude 1.
        :param joint_limit: every joint but the base turns at most this far (rad) either way.
        :param dt: seconds of simulated time per environment step.
        :param substeps: pymunk steps per environment step (each ``dt / substeps`` long), 1 to 100.
        :param goal_radius_min: the goal stays at least this far from the base.
        :param goal_radius_max: the goal stays at most this far from the base (below 1: reachable).
        :param obstacle_radius_min: obstacle centres stay at least this far from the base.
        :param obstacle_radius_max: obstacle centres stay at most this far from the base.
        :param spawn_margin: at reset, obstacles start at least this far from the arm and the goal.
        :param observe: the state components the observation holds, in this order (names of
            ``state_layout``; default: all of them).
        :param render_mode: ``None``, ``"rgb_array"`` or ``"human"``.
        """
        given = locals()  # the arguments, before any other local: the parameters are read from it
        params = SnakeParams(**{field.name: given[field.name] for field in fields(SnakeParams)})
        if render_mode is not None:
            check_choice("render_mode", render_mode, tuple(self.metadata["render_modes"]))
        #: The checked parameters; each is also an attribute of the env (``reward`` as ``reward_name``).
        self.params = params
        for field in fields(params):
            name = "reward_name" if field.name == "reward" else field.name
            setattr(self, name, getattr(params, field.name))
        self.render_mode = render_mode
        self.link_length = params.link_length
        self.state_layout: StateLayout = build_state_layout(params.n_joints)
        self.proximity = Proximity(self.sensor_range, self.touch_radius)
        self.observed_components: tuple[str, ...] | None = _check_components(observe, self.state_layout)
        # None (the whole state, no copy) or the indices that select the observed components.
        self._observe_index: np.ndarray | None = (
            None if self.observed_components is None else self.state_layout.indices(self.observed_components)
        )
        self._set_observation()
        self.action_space = spaces.Box(-1.0, 1.0, (params.n_joints,), dtype=np.float32)

        self._set_rewards(params)
        self._arm = ArmPhysics(params)
        self._link_slots = self._observation_slots()
        _LIVE_ENVS.add(self)
        self._movers = Movers(params)
        self._ever_touched = False
        self._ever_collided = False
        self._renderer: SnakeRenderer | None = None

    def _set_rewards(self, params: SnakeParams) -> None:
        """The reward terms' bounds and normaliser, and the step's reward choice."""
        self.reward_bounds: dict[str, tuple[float, float]] = reward_bounds(params)
        self.reward_terms = REWARD_TERMS
        self._normaliser = TermNormaliser(self.reward_bounds)
        # The reach reward: every term, normalised, weight 1.
        self._reach_weights = tuple((term, 1.0) for term in REWARD_TERMS)
        self._reach = params.reward == "reach"
        self._goal_term = GoalTerm(params.touch_radius, *self.reward_bounds["goal"])
        self._inv_sensor_range = 1.0 / params.sensor_range

    def _set_observation(self) -> None:
        """The observation space (of the observed components) and what the step needs to fill the full state."""
        size = self._obs_size = self.state_layout.size
        self._pack_obs = struct.Struct(f"={size}f").pack
        self._obs_offsets = (self.state_layout["ee_to_goal"].start, self.state_layout["goal_touched"].start)
        low = np.full(size, -1.0, dtype=np.float32)
        high = np.ones(size, dtype=np.float32)
        for name in ("joint_obstacle_distances", "goal_touched", "obstacle_touched"):
            low[self.state_layout[name]] = 0.0
        if self._observe_index is not None:
            low, high = low[self._observe_index], high[self._observe_index]
        self.observation_space = spaces.Box(low, high, dtype=np.float32)

    def _observation_slots(self) -> list[tuple[int, object, int, int, int, int]]:
        """
        Per link: its index, its body's Chipmunk pointer, and where its values go in the observation (end
        point x, obstacle vector x, obstacle distance, touch flag; y follows x). Rebuilt with the chain.
        """
        layout = self.state_layout
        return [
            (
                i,
                handle,
                layout["joint_positions"].start + 2 * i,
                layout["joint_obstacle_vectors"].start + 2 * i,
                layout["joint_obstacle_distances"].start + i,
                layout["obstacle_touched"].start + i,
            )
            for i, handle in enumerate(self._arm.link_handles)
        ]

    # ------------------------------------------------------------------ the arm and the movers
    @property
    def space(self) -> pymunk.Space | None:
        """The arm's pymunk space."""
        return self._arm.space

    def link_points(self) -> np.ndarray:
        """The ``(n_joints + 1, 2)`` chain points: the base, every joint, then the tip."""
        xs, ys = self._arm.chain_points()
        return np.array([xs, ys]).T

    def joint_gaps(self) -> np.ndarray:
        """How far each simulated pivot has come apart (reach units; small, not zero: pymunk iterates)."""
        ends = [(0.0, 0.0)] + [body.local_to_world((self.link_length, 0.0)) for body in self._arm.links[:-1]]
        return np.array([abs(body.position - end) for body, end in zip(self._arm.links, ends)])

    def joint_angles(self) -> np.ndarray:
        """Relative joint angles (rad); index 0 is the base joint's absolute angle."""
        return np.diff([body.angle for body in self._arm.links], prepend=0.0)

    @property
    def goal(self) -> np.ndarray:
        """The goal's position, shape ``(2,)``."""
        return np.array(self._movers.goal)

    @property
    def obstacles(self) -> np.ndarray:
        """The obstacle centres, shape ``(n_obstacles, 2)``."""
        return np.array(self._movers.obstacles).reshape(self.n_obstacles, 2)

    # ------------------------------------------------------------------ sensing
    def _step_result(self) -> tuple[np.ndarray, float, dict[str, Any]]:
        """
        Read the physics and compute the observation, the reward and the info in one pass; store the links'
        absolute angles in the arm's ``angles`` and update the episode's touched / collided flags.
        """
        # Forward kinematics from the link angles: the points are exactly one link length apart (the pivot
        # solver's slack never reaches the observation), so its bounds hold without clipping. Plain Python
        # on purpose: for a handful of points, scalar math is several times faster than numpy calls.
        length = self.link_length
        radius = self.obstacle_radius
        sensor_range = self.sensor_range
        inv_range = self._inv_sensor_range
        cos, sin, sqrt, inf = math.cos, math.sin, math.sqrt, math.inf
        angles = self._arm.angles
        obstacles = self._movers.obstacles
        obs = [0.0] * self._obs_size
        clipped_sum = 0.0
        min_clearance = inf
        collision = False
        ax = ay = 0.0
        for i, handle, j, vector, distance, touch_flag in self._link_slots:
            angle = angles[i] = body_angle(handle)
            bx = ax + length * cos(angle)
            by = ay + length * sin(angle)
            obs[j] = bx
            obs[j + 1] = by
            vx, vy, best = _closest_obstacle(ax, ay, bx - ax, by - ay, obstacles)
            obs[vector] = 0.5 * vx
            obs[vector + 1] = 0.5 * vy
            clearance = sqrt(best) - radius
            if clearance < min_clearance:
                min_clearance = clearance
            if clearance <= 0.0:  # touching: the distance stays 0
                obs[touch_flag] = 1.0
                collision = True
            else:
                clipped = sensor_range if clearance > sensor_range else clearance
                clipped_sum += clipped
                obs[distance] = clipped * inv_range
            ax = bx
            ay = by
        goal, goal_distance, goal_touched = self._sense_goal(ax, ay, obs)
        avoid = avoid_term(self.r_bf, clipped_sum, collision)

        ever_touched = self._ever_touched = self._ever_touched or goal_touched
        ever_collided = self._ever_collided = self._ever_collided or collision
        terms = {"goal": goal, "avoid": avoid}
        if self._reach:  # the sum of both terms, each normalised as by normalise_terms
            reward = self._normaliser.weighted_sum(terms, self._reach_weights)
        else:
            reward = goal if self.reward_name == "goal" else avoid
        info = {
            "reward_terms": terms,
            "goal_touched": goal_touched,
            "collision": collision,
            "min_clearance": min_clearance,
            "distance_to_goal": goal_distance,
            "is_success": ever_touched and not ever_collided,
        }
        # struct packs the Python floats to float32 in one C loop: cheaper than numpy converting a list.
        return np.frombuffer(self._pack_obs(*obs), np.float32).copy(), reward, info

    def _sense_goal(self, tip_x: float, tip_y: float, obs: list[float]) -> tuple[float, float, bool]:
        """The goal term, distance and touch for the tip at (``tip_x``, ``tip_y``), written into ``obs`` too."""
        to_goal, goal_flag = self._obs_offsets
        gx, gy = self._movers.goal
        dgx = gx - tip_x
        dgy = gy - tip_y
        obs[to_goal] = 0.5 * dgx
        obs[to_goal + 1] = 0.5 * dgy
        goal_distance = math.hypot(dgx, dgy)
        goal, goal_touched = self._goal_term(goal_distance)
        if goal_touched:
            obs[goal_flag] = 1.0
        return goal, goal_distance, goal_touched

    def _observed(self, state: np.ndarray) -> np.ndarray:
        """The observation: the full state, or the components chosen by ``observe``."""
        return state if self._observe_index is None else state[self._observe_index]

    def view(self) -> SnakeView:
        """What the arm senses now, read-only (it does not step the env nor change the episode's flags)."""
        obs, _, info = self._step_result()  # the episode flags it updates are unchanged by a second call
        return SnakeView(
            link_points=self.link_points(),
            goal=self.goal,
            obstacles=self.obstacles,
            obstacle_radius=self.obstacle_radius,
            touch_radius=self.touch_radius,
            goal_touched=bool(info["goal_touched"]),
            touching=tuple(bool(t) for t in obs[self.state_layout["obstacle_touched"]] == 1.0),
            collision=bool(info["collision"]),
            min_clearance=float(info["min_clearance"]),
            goal_distance=float(info["distance_to_goal"]),
        )

    def normalise_terms(self, terms: Mapping[str, float]) -> dict[str, float]:
        """Min-max normalise reward terms to [0, 1] with the fixed :attr:`reward_bounds`."""
        return self._normaliser(terms)

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, object] | None = None
    ) -> tuple[np.ndarray, dict[str, object]]:
        super().reset(seed=seed)
        n = self.n_joints
        angles = np.concatenate(
            ([self.np_random.uniform(-np.pi, np.pi)], self.np_random.uniform(-0.5, 0.5, n - 1))
        )
        # A fresh space: pymunk warm-starts its solver with impulses cached from earlier steps, so reusing
        # the old space would make the same seed and actions give a different trajectory.
        self._arm.build()
        self._link_slots = self._observation_slots()
        self._arm.place(angles)
        self._movers.spawn(self.np_random, self.link_points())
        self._ever_touched = False
        self._ever_collided = False
        obs, _, info = self._step_result()
        if self.render_mode == "human":
            self.render()
        return self._observed(obs), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        # A float array is the fast path; anything else (lists, integer or bool arrays such as a bang-bang
        # [1, -1, ...]) is converted, so that its values are checked rather than its dtype rejected.
        is_float_array = isinstance(action, np.ndarray) and action.dtype.kind == "f"
        commands = (action if is_float_array else np.asarray(action, float)).tolist()
        if (
            not isinstance(commands, list)
            or len(commands) != self.n_joints
            or not isinstance(commands[0], float)
        ):
            raise ValueError(f"Expected an action of shape ({self.n_joints},), actually: {np.shape(action)}")
        # One check for all: a NaN or an infinity makes the sum non-finite (the sum of finite values can
        # only overflow for absurdly large commands, so check them one by one then).
        if not -math.inf < sum(commands) < math.inf and not all(-math.inf < c < math.inf for c in commands):
            raise ValueError(f"Expected a finite action, actually: {commands}")
        self._arm.drive(commands)
        self._movers.walk(self.np_random)
        obs, reward, info = self._step_result()
        if self.render_mode == "human":
            self.render()
        return self._observed(obs), reward, False, False, info

    def __getstate__(self) -> dict[str, object]:
        # The arm pickles its motion state and rebuilds its chain; the env rebuilds what points into it.
        unpicklable = ("_renderer", "_link_slots", "_pack_obs")
        return {k: v for k, v in self.__dict__.items() if k not in unpicklable}

    def __setstate__(self, state: dict[str, object]) -> None:
        self.__dict__.update(state)
        self._renderer = None
        self._pack_obs = struct.Struct(f"={self._obs_size}f").pack
        self._link_slots = self._observation_slots()
        _LIVE_ENVS.add(self)

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn(
                "You are calling render method without specifying any render mode. "
                'Pass render_mode="rgb_array" or "human" to gym.make.'
            )
            return None
        # Lazily: Pillow loads only when drawing is asked for, not in every env subprocess.
        from sb3_hddpg.envs.snake.rendering import SnakeRenderer

        if self._renderer is None:
            self._renderer = SnakeRenderer(self.render_mode, fps=self.metadata["render_fps"])
        return self._renderer.draw(self.view())

    def _release_space(self) -> None:
        """Empty the arm's pymunk space before it is dropped (see ``ArmPhysics.release``)."""
        arm = self.__dict__.get("_arm")
        if arm is not None:
            arm.release()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self._release_space()

    def __del__(self) -> None:
        # An env dropped without close() still empties its space first (finalisers run before the collector
        # clears a cycle, PEP 442); at interpreter exit module globals may be None, hence a bare try.
        try:  # noqa: SIM105 - contextlib may already be None here
            self._release_space()
        except Exception:
            pass


#: Every SnakeArmEnv not yet garbage-collected (weakly held, so it keeps none alive).
_LIVE_ENVS: weakref.WeakSet[SnakeArmEnv] = weakref.WeakSet()


@atexit.register
def _release_live_spaces() -> None:
    """
    Free the pymunk spaces of envs still alive at interpreter exit, while pymunk can: later, its finaliser
    fails and prints a traceback for every space.
    """
    for env in list(_LIVE_ENVS):
        env._release_space()
        arm = env.__dict__.get("_arm")
        if arm is not None:
            arm.space = None  # the last reference: the space is freed now, not at teardown


def _closest_obstacle(
    ax: float, ay: float, sx: float, sy: float, obstacles: list[list[float]]
) -> tuple[float, float, float]:
    """
    The obstacle whose centre is closest to the segment from (``ax``, ``ay``) along (``sx``, ``sy``): the
    vector from the segment's closest point to its centre, and that vector's squared length.
    """
    inv_len2 = 1.0 / (sx * sx + sy * sy)
    best = math.inf  # the first obstacle always improves on it (there is at least one)
    best_vx = best_vy = 0.0
    for ox, oy in obstacles:
        vx = ox - ax
        vy = oy - ay
        dot = vx * sx + vy * sy
        if dot > 0.0:  # beyond the link's start (else the start is the closest point)
            t = dot * inv_len2
            if t < 1.0:
                vx -= t * sx
                vy -= t * sy
            else:
                vx -= sx
                vy -= sy
        d = vx * vx + vy * vy
        if d < best:
            best = d
            best_vx = vx
            best_vy = vy
    return best_vx, best_vy, best


def _check_components(observe: object, layout: StateLayout) -> tuple[str, ...] | None:
    """``observe`` as a tuple of known, distinct component names (``None``: the whole state)."""
    if observe is None:
        return None
    if not isinstance(observe, (list, tuple)) or not observe or not all(isinstance(n, str) for n in observe):
        raise ValueError(
            f"Expected `observe` to be a non-empty list of state components {list(layout)}, actually: "
            f"{observe!r:.200}"
        )
    try:
        layout.indices(observe)  # unknown or repeated names are refused there
    except ValueError as error:
        raise ValueError(f"`observe`: {error}") from None
    return tuple(observe)
