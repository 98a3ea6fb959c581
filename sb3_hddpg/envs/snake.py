"""A planar snake arm among moving obstacles, simulated with pymunk (the paper's Figure 2 task)."""

from __future__ import annotations

import atexit
import math
import struct
import weakref
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import pymunk
from gymnasium import spaces
from pymunk._chipmunk_cffi import lib as _chipmunk

from sb3_hddpg.envs.contract import Proximity, TermNormaliser
from sb3_hddpg.envs.layout import StateLayout, build_state_layout

#: The reward choices of :class:`SnakeArmEnv`: one per paper worker plus their normalised sum.
REWARD_CHOICES = ("goal", "avoid", "reach")
#: Upper limits of the counts (the work per step and the observation grow with them). Env kwargs can
#: come from a shared file; far above any sensible arm, they keep such a file from stalling a step.
MAX_JOINTS = 32
MAX_OBSTACLES = 32
MAX_SUBSTEPS = 100
#: The reward terms computed every step (Table 2 of the paper).
REWARD_TERMS = ("goal", "avoid")

# The step calls Chipmunk through pymunk's cffi module directly, with the raw pointers pymunk keeps on
# its objects (``Body._body``, ``SimpleMotor._constraint``, ``Space._space``): the same C functions that
# pymunk's properties and ``Space.step`` call, without their Python wrapper layers (setting a motor rate
# through the property costs ~5 times more than the C call). See docs/PERFORMANCE.md.
_body_angle = _chipmunk.cpBodyGetAngle
_set_motor_rate = _chipmunk.cpSimpleMotorSetRate
_space_step = _chipmunk.cpSpaceStep


class SnakeArmEnv(gym.Env[np.ndarray, np.ndarray]):
    r"""
    ## Description

    A planar snake arm of ``n_joints`` revolute joints in a chain, fixed at a base in the middle of a disc
    shaped workspace, must touch a goal point that random-walks inside its reach while ``n_obstacles``
    discs random-walk through the workspace (Um, Nethala & Shin, *AI* 2022, Section 3 and Figure 2).
    Reaching and avoiding conflict: the straight way to the goal often crosses an obstacle.

    Lengths are in units of the arm's reach: every link is ``1 / n_joints`` long, so the stretched arm
    reaches exactly 1.

    The arm is simulated by pymunk: every link is a dynamic body with the mass and moment of a thin rod
    (each 0.6 times as heavy as its parent), joined to its
    parent (the static base for link 0) by a ``PivotJoint`` and driven by a ``SimpleMotor`` whose rate is the
    commanded joint velocity. A soft limit keeps every joint but the base within
    ``±joint_limit`` radians: the commanded rate is reduced so that the joint stops at its limit within
    the step, as a servo controller would (a pymunk ``RotaryLimitJoint`` fighting a motor made the chain
    unstable). **Self-collision** is not simulated: the links have no pymunk collision shapes (nothing in
    the space could collide with them, and pymunk's collision detection would cost a quarter of the
    physics time), so they pass through each other, and the joint limits keep the chain from folding back
    onto itself. **Obstacles** are kinematic discs, not pymunk bodies: like the paper's robot with a
    sensitive skin, the arm is not pushed by an obstacle but *touches* it, which the avoid reward penalises.
    The goal and the obstacles move by a bounded random walk of their velocity (speed capped at
    ``goal_speed`` / ``obstacle_speed`` reach per second), reflected at the edge of their region.

    ## Action Space

    ``Box(-1, 1, (n_joints,), float32)``: joint velocity commands, scaled to ``max_joint_speed`` rad/s;
    positive turns counter-clockwise. Index ``i`` drives joint ``i`` (joint 0 is the base).

    ## Observation Space

    ``Box(low, high, (5 * n_joints + 3,), float32)``, the paper's shared state (Table 1). "Link ``i``" is the
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

    The total length is therefore ``6 n + 3`` (39 for the default six joints). Joint angles and velocities
    are not observed: the link end points determine the angles, and with velocity-commanded motors the arm
    has no momentum worth observing (the motor holds each commanded rate within a substep).
    ``env.unwrapped.state_layout`` maps every name above to its slice, so an agent can be fed a chosen
    subset of the state (the paper's design specification 4). With ``observe=[names...]`` the env itself
    returns only those components, in that order (e.g. the goal worker's ``["joint_positions",
    "ee_to_goal", "goal_touched"]``, 15 values): ``state_layout`` still describes the full state, and
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
            ``state_layout``; default: all of them). A worker that needs only part of the shared state
            (the paper's design specification 4: the goal worker needs no obstacle values) learns on less
            noise; ``WorkerSelectionWrapper`` then feeds it the same components of the full state.
        :param render_mode: ``None``, ``"rgb_array"`` or ``"human"``.
        """
        _check_choice("reward", reward, REWARD_CHOICES)
        _check_count("n_joints", n_joints, minimum=2, maximum=MAX_JOINTS)
        _check_count("n_obstacles", n_obstacles, minimum=1, maximum=MAX_OBSTACLES)
        _check_count("substeps", substeps, minimum=1, maximum=MAX_SUBSTEPS)
        for name, value in (
            ("obstacle_radius", obstacle_radius),
            ("touch_radius", touch_radius),
            ("r_bf", r_bf),
            ("sensor_range", sensor_range),
            ("max_joint_speed", max_joint_speed),
            ("joint_limit", joint_limit),
            ("dt", dt),
            ("goal_radius_max", goal_radius_max),
            ("obstacle_radius_max", obstacle_radius_max),
        ):
            _check_positive(name, value)
        for name, value in (
            ("obstacle_speed", obstacle_speed),
            ("goal_speed", goal_speed),
            ("goal_radius_min", goal_radius_min),
            ("obstacle_radius_min", obstacle_radius_min),
            ("spawn_margin", spawn_margin),
        ):
            _check_non_negative(name, value)
        if not goal_radius_min < goal_radius_max <= 1.0:
            raise ValueError(
                "Expected 0 <= goal_radius_min < goal_radius_max <= 1 (the goal must be reachable), "
                f"actually: goal_radius_min={goal_radius_min}, goal_radius_max={goal_radius_max}"
            )
        if not obstacle_radius_min < obstacle_radius_max:
            raise ValueError(
                "Expected obstacle_radius_min < obstacle_radius_max, actually: "
                f"obstacle_radius_min={obstacle_radius_min}, obstacle_radius_max={obstacle_radius_max}"
            )
        if render_mode is not None:
            _check_choice("render_mode", render_mode, tuple(self.metadata["render_modes"]))

        self.reward_name = reward
        self.n_joints = int(n_joints)
        self.n_obstacles = int(n_obstacles)
        self.obstacle_radius = float(obstacle_radius)
        self.obstacle_speed = float(obstacle_speed)
        self.goal_speed = float(goal_speed)
        self.touch_radius = float(touch_radius)
        self.r_bf = float(r_bf)
        self.sensor_range = float(sensor_range)
        self.max_joint_speed = float(max_joint_speed)
        self.joint_limit = float(joint_limit)
        self.dt = float(dt)
        self.substeps = int(substeps)
        self.goal_radius_min = float(goal_radius_min)
        self.goal_radius_max = float(goal_radius_max)
        self.obstacle_radius_min = float(obstacle_radius_min)
        self.obstacle_radius_max = float(obstacle_radius_max)
        self.spawn_margin = float(spawn_margin)
        self.render_mode = render_mode
        self.link_length = 1.0 / self.n_joints

        n = self.n_joints
        self.state_layout: StateLayout = build_state_layout(n)
        # The optional proximity capability of the env contract: info reports min_clearance (read by the
        # skin sensors up to sensor_range) and distance_to_goal (touched within touch_radius).
        self.proximity = Proximity(self.sensor_range, self.touch_radius)
        obs_size = self.state_layout.size
        low = np.full(obs_size, -1.0, dtype=np.float32)
        high = np.ones(obs_size, dtype=np.float32)
        for name in ("joint_obstacle_distances", "goal_touched", "obstacle_touched"):
            low[self.state_layout[name]] = 0.0
        self.observed_components: tuple[str, ...] | None = _check_components(observe, self.state_layout)
        # None (the whole state, no copy) or the indices that select the observed components.
        self._observe_index: np.ndarray | None = (
            None if self.observed_components is None else self.state_layout.indices(self.observed_components)
        )
        if self._observe_index is not None:
            low, high = low[self._observe_index], high[self._observe_index]
        self.observation_space = spaces.Box(low, high, dtype=np.float32)
        self.action_space = spaces.Box(-1.0, 1.0, (n,), dtype=np.float32)

        self.reward_bounds: dict[str, tuple[float, float]] = {
            "goal": (-(1.0 + self.goal_radius_max), 1.0),
            "avoid": (-1.0, self.r_bf * n * self.sensor_range),
        }
        self.reward_terms = REWARD_TERMS
        self._normaliser = TermNormaliser(self.reward_bounds)
        # The reach reward: every term, normalised, weight 1.
        self._reach_weights = tuple((term, 1.0) for term in REWARD_TERMS)

        # (top speed, min radius, max radius) of the goal's walk, then of each obstacle's.
        self._walk_limits = [(self.goal_speed, self.goal_radius_min, self.goal_radius_max)] + [
            (self.obstacle_speed, self.obstacle_radius_min, self.obstacle_radius_max)
        ] * self.n_obstacles
        # Constants of the step, precomputed once.
        self._substep_dt = self.dt / self.substeps
        self._inv_dt = 1.0 / self.dt
        # Joints with |relative angle| below this cannot reach their limit within a step, whatever the
        # command (with a margin far above rounding errors); negative if any joint can.
        reach_per_step = self.max_joint_speed * self.dt
        self._free_joint_range = (
            self.joint_limit - reach_per_step - 1e-9 * (self.joint_limit + reach_per_step)
        )
        self._inv_sensor_range = 1.0 / self.sensor_range
        self._reach = reward == "reach"
        self._obs_size = obs_size
        self._pack_obs = struct.Struct(f"={obs_size}f").pack
        self._obs_offsets = (self.state_layout["ee_to_goal"].start, self.state_layout["goal_touched"].start)
        self._goal_bounds = self.reward_bounds["goal"]
        self._build_space()
        _LIVE_ENVS.add(self)
        # The links' absolute angles as last read from the physics (the soft joint limits need them).
        self._angles = [0.0] * self.n_joints
        # Positions and velocities of the goal (index 0) and the obstacles, as plain lists (see _walk_movers).
        self._movers: list[list[float]] = [[0.0, 0.0] for _ in range(1 + self.n_obstacles)]
        self._velocities: list[list[float]] = [[0.0, 0.0] for _ in range(1 + self.n_obstacles)]
        self._link_walkers()
        self._noise: list[Any] = []
        self._noise_index = 0
        self._ever_touched = False
        self._ever_collided = False
        self._renderer: Any = None

    # ------------------------------------------------------------------ physics
    def _build_space(self) -> None:
        """Build the pymunk chain; ``reset`` rebuilds it, since pymunk carries solver state between steps."""
        self._release_space()
        self.space = pymunk.Space()
        self.space.gravity = (0.0, 0.0)  # a planar arm on a table: gravity is normal to the plane
        self.space.iterations = 10
        # Links get lighter toward the tip, as in a real arm. It also matters numerically: pymunk's
        # iterative solver tracks a chain of equal-mass motor-driven links badly (the base overshoots
        # and the tip lags), while a 0.6 mass ratio per link tracks the commanded rates within ~3 %.
        masses = [0.6**i for i in range(self.n_joints)]
        self.links: list[pymunk.Body] = []
        self.motors: list[pymunk.SimpleMotor] = []
        parent: pymunk.Body = self.space.static_body
        for i in range(self.n_joints):
            moment = pymunk.moment_for_segment(masses[i], (0, 0), (self.link_length, 0), 0.01)
            body = pymunk.Body(masses[i], moment)
            # The base pivot sits at the static body's origin; the others at the parent link's far end.
            anchor = (0.0, 0.0) if i == 0 else (self.link_length, 0.0)
            pivot = pymunk.PivotJoint(parent, body, anchor, (0.0, 0.0))
            motor = pymunk.SimpleMotor(parent, body, 0.0)
            # Strong enough to hold the commanded rate against the chain's inertia within a substep.
            motor.max_force = 50.0
            self.space.add(body, pivot, motor)
            self.links.append(body)
            self.motors.append(motor)
            parent = body
        # Raw Chipmunk pointers for the step (see the module's note above _body_angle); the pymunk objects
        # in space, links and motors own them and keep them alive.
        self._space_handle = self.space._space
        self._link_handles = [body._body for body in self.links]
        self._motor_handles = [motor._constraint for motor in self.motors]
        # Per link: its index, body pointer, and where its values go in the observation (end point x,
        # obstacle vector x, obstacle distance, touch flag; y follows x).
        layout = self.state_layout
        self._link_slots = [
            (
                i,
                handle,
                layout["joint_positions"].start + 2 * i,
                layout["joint_obstacle_vectors"].start + 2 * i,
                layout["joint_obstacle_distances"].start + i,
                layout["obstacle_touched"].start + i,
            )
            for i, handle in enumerate(self._link_handles)
        ]

    def _place_arm(self, joint_angles: np.ndarray) -> None:
        """Put the chain at the given relative joint angles, at rest."""
        absolute = np.cumsum(joint_angles)
        start = np.zeros(2)
        for body, angle in zip(self.links, absolute):
            body.angle = float(angle)
            body.position = (float(start[0]), float(start[1]))
            body.velocity = (0.0, 0.0)
            body.angular_velocity = 0.0
            start = start + self.link_length * np.array([math.cos(angle), math.sin(angle)])

    def link_points(self) -> np.ndarray:
        """The ``(n_joints + 1, 2)`` chain points: the base, every joint, then the tip."""
        xs, ys = self._chain_points()
        return np.array([xs, ys]).T

    def _chain_points(self) -> tuple[list[float], list[float]]:
        # The chain from the simulated link angles by forward kinematics: the points are exactly one link
        # length apart (the pivot solver's slack, see joint_gaps, never reaches the observation), so the
        # observation bounds hold without clipping. Plain Python on purpose: for a handful of points it
        # is several times faster than numpy calls, and pymunk's angle is its cheapest accessor.
        length = self.link_length
        x = y = 0.0
        xs = [0.0]
        ys = [0.0]
        angles = self._angles
        for i, body in enumerate(self.links):
            angle = angles[i] = body.angle
            x += length * math.cos(angle)
            y += length * math.sin(angle)
            xs.append(x)
            ys.append(y)
        return xs, ys

    def joint_gaps(self) -> np.ndarray:
        """
        How far each simulated pivot has come apart (reach units): the distance between a link's start and
        its parent's far end (the base for link 0). pymunk solves joints iteratively, so these are small but
        not zero; they show that the physics keeps the arm connected.
        """
        gaps = []
        parent_end = pymunk.Vec2d(0.0, 0.0)
        for body in self.links:
            gaps.append(abs(body.position - parent_end))
            parent_end = body.local_to_world((self.link_length, 0.0))
        return np.array(gaps)

    def joint_angles(self) -> np.ndarray:
        """Relative joint angles (rad); index 0 is the base joint's absolute angle."""
        absolute = np.array([b.angle for b in self.links])
        return np.diff(absolute, prepend=0.0)

    @property
    def goal(self) -> np.ndarray:
        """The goal's position, shape ``(2,)``."""
        return np.array(self._movers[0])

    @property
    def obstacles(self) -> np.ndarray:
        """The obstacle centres, shape ``(n_obstacles, 2)``."""
        return np.array(self._movers[1:]).reshape(self.n_obstacles, 2)

    # ------------------------------------------------------------------ random walks
    def _sample_annulus(self, r_min: float, r_max: float) -> list[float]:
        # Uniform over the annulus area: radius from the square-root law.
        radius = math.sqrt(self.np_random.uniform(r_min**2, r_max**2))
        angle = self.np_random.uniform(-math.pi, math.pi)
        return [radius * math.cos(angle), radius * math.sin(angle)]

    def _link_walkers(self) -> None:
        """
        Gather, for the random walks, the position, velocity, limits and noise offset of every mover that
        moves; call whenever ``_movers`` or ``_velocities`` are replaced.
        """
        self._walkers = [
            (pos, vel, top, r_min, r_max, 2 * k)
            for k, (pos, vel, (top, r_min, r_max)) in enumerate(
                zip(self._movers, self._velocities, self._walk_limits)
            )
            if top != 0.0
        ]

    def _walk_movers(self) -> None:
        """
        Advance the goal's and the obstacles' bounded random walks: jitter the velocity, cap the speed,
        move, and reflect the velocity's radial part at the edge of the mover's annulus.
        """
        noise = self._noise
        k = self._noise_index
        per_step = 2 * len(self._movers)  # noise values per step: (x, y) per mover, moving or not
        if k >= len(noise):
            # Normal noise drawn in blocks of 256 steps, (x, y) per mover per step, as one flat list: one
            # generator call and one (cheap, flat) tolist per block instead of a generator call per step.
            noise = self._noise = self.np_random.normal(0.0, 0.3, size=256 * per_step).tolist()
            k = 0
        self._noise_index = k + per_step
        dt = self.dt
        hypot = math.hypot
        for pos, vel, top, r_min, r_max, offset in self._walkers:
            i = k + offset
            vx = vel[0] + noise[i] * top
            vy = vel[1] + noise[i + 1] * top
            speed = hypot(vx, vy)
            if speed > top:
                vx, vy = vx * top / speed, vy * top / speed
            x = pos[0] + vx * dt
            y = pos[1] + vy * dt
            radius = hypot(x, y)
            if radius > r_max or radius < r_min:
                ux, uy = x / max(radius, 1e-12), y / max(radius, 1e-12)
                radial = vx * ux + vy * uy
                vx, vy = vx - 2.0 * radial * ux, vy - 2.0 * radial * uy
                radius = min(max(radius, r_min), r_max)
                x, y = ux * radius, uy * radius
            pos[0] = x
            pos[1] = y
            vel[0] = vx
            vel[1] = vy

    # ------------------------------------------------------------------ geometry
    def _step_result(self) -> tuple[np.ndarray, float, dict[str, Any]]:
        """
        Read the physics and compute the observation, the reward and the info in one pass. Also stores
        the links' absolute angles in ``_angles`` and updates the episode's touched / collided flags.
        """
        # The chain by forward kinematics from the simulated link angles: the points are exactly one link
        # length apart (the pivot solver's slack, see joint_gaps, never reaches the observation), so the
        # observation bounds hold without clipping. Plain Python on purpose: for a handful of points and
        # obstacles, scalar math is several times faster than numpy's per-call overhead.
        length = self.link_length
        radius = self.obstacle_radius
        sensor_range = self.sensor_range
        inv_range = self._inv_sensor_range
        cos, sin, sqrt, inf = math.cos, math.sin, math.sqrt, math.inf
        angles = self._angles
        obstacles = self._movers[1:]
        # The observation, filled in place; see the class docstring for the layout.
        obs = [0.0] * self._obs_size
        clipped_sum = 0.0
        min_clearance = inf
        collision = False
        ax = ay = 0.0
        for i, handle, j, vector, distance, touch_flag in self._link_slots:
            angle = angles[i] = _body_angle(handle)
            bx = ax + length * cos(angle)
            by = ay + length * sin(angle)
            obs[j] = bx
            obs[j + 1] = by
            # The obstacle whose centre is closest to the link segment from (ax, ay) to (bx, by).
            sx = bx - ax
            sy = by - ay
            inv_len2 = 1.0 / (sx * sx + sy * sy)
            best = inf  # the first obstacle always improves on it (there is at least one)
            for ox, oy in obstacles:
                # (vx, vy): from the segment's closest point to the obstacle centre.
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
            obs[vector] = 0.5 * best_vx
            obs[vector + 1] = 0.5 * best_vy
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
        goal, goal_distance, goal_touched = self._goal_term(ax, ay, obs)
        avoid = self.r_bf * clipped_sum
        if collision:
            avoid -= 1.0

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

    def _goal_term(self, tip_x: float, tip_y: float, obs: list[float]) -> tuple[float, float, bool]:
        """
        The goal term for the tip at (``tip_x``, ``tip_y``), its distance to the goal and whether it touches
        it; writes the tip-to-goal vector and the touch flag into ``obs``.
        """
        to_goal, goal_flag = self._obs_offsets
        gx, gy = self._movers[0]
        dgx = gx - tip_x
        dgy = gy - tip_y
        obs[to_goal] = 0.5 * dgx
        obs[to_goal + 1] = 0.5 * dgy
        goal_distance = math.hypot(dgx, dgy)
        goal_touched = goal_distance <= self.touch_radius
        if goal_touched:
            obs[goal_flag] = 1.0
            goal = 1.0 - goal_distance
        else:
            goal = -goal_distance
        # Clip to the documented bounds: physics slack can put the tip a hair beyond reach.
        goal_low, goal_high = self._goal_bounds
        if goal < goal_low:
            goal = goal_low
        elif goal > goal_high:
            goal = goal_high
        return goal, goal_distance, goal_touched

    def _observed(self, state: np.ndarray) -> np.ndarray:
        """The observation: the full state, or the components chosen by ``observe``."""
        return state if self._observe_index is None else state[self._observe_index]

    def _measure(self) -> dict[str, Any]:
        """The current state's touch flags and distances (for rendering and inspection, not the step)."""
        obs, _, info = self._step_result()  # the episode flags it updates are unchanged by a second call
        return {
            "goal_touched": info["goal_touched"],
            "touching": (obs[self.state_layout["obstacle_touched"]] == 1.0).tolist(),
            "collision": info["collision"],
            "min_clearance": info["min_clearance"],
            "goal_distance": info["distance_to_goal"],
        }

    def normalise_terms(self, terms: Mapping[str, float]) -> dict[str, float]:
        """Min-max normalise reward terms to [0, 1] with the fixed :attr:`reward_bounds`."""
        return self._normaliser(terms)

    # ------------------------------------------------------------------ gymnasium API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        n = self.n_joints
        angles = np.concatenate(
            ([self.np_random.uniform(-np.pi, np.pi)], self.np_random.uniform(-0.5, 0.5, n - 1))
        )
        # A fresh space: pymunk warm-starts its solver with impulses cached from earlier steps, so reusing
        # the old space would make the same seed and actions give a different trajectory.
        self._build_space()
        self._place_arm(angles)
        goal = self._sample_annulus(self.goal_radius_min, self.goal_radius_max)
        self._movers = [goal]
        points = self.link_points()
        for _ in range(self.n_obstacles):
            for _ in range(1000):
                candidate = self._sample_annulus(self.obstacle_radius_min, self.obstacle_radius_max)
                if self._clear_of(np.array(candidate), points, np.array(goal)):
                    break
            self._movers.append(candidate)
        self._velocities = [[0.0, 0.0] for _ in self._movers]
        self._link_walkers()
        self._noise = []
        self._noise_index = 0
        self._ever_touched = False
        self._ever_collided = False
        obs, _, info = self._step_result()
        if self.render_mode == "human":
            self.render()
        return self._observed(obs), info

    def _clear_of(self, centre: np.ndarray, points: np.ndarray, goal: np.ndarray) -> bool:
        """Whether an obstacle at ``centre`` starts clear of the arm's links and the goal."""
        starts, seg = points[:-1], points[1:] - points[:-1]
        t = np.clip(np.sum((centre - starts) * seg, axis=1) / np.sum(seg * seg, axis=1), 0.0, 1.0)
        to_links = np.linalg.norm(starts + t[:, None] * seg - centre, axis=1).min()
        to_goal = np.linalg.norm(goal - centre)
        need = self.obstacle_radius + self.spawn_margin
        return bool(to_links > need and to_goal > need + self.touch_radius)

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
        top = self.max_joint_speed
        limit = self.joint_limit
        inv_dt = self._inv_dt
        free = self._free_joint_range
        # One check for all: a NaN or an infinity makes the sum non-finite (the sum of finite values can
        # only overflow for absurdly large commands, so check them one by one then).
        if not -math.inf < sum(commands) < math.inf and not all(-math.inf < c < math.inf for c in commands):
            raise ValueError(f"Expected a finite action, actually: {commands}")
        set_motor_rate = _set_motor_rate
        previous = 0.0
        first = True
        # _angles holds the links' absolute angles as read at the end of the previous step (or reset).
        for handle, command, absolute in zip(self._motor_handles, commands, self._angles):
            rate = top * (-1.0 if command < -1.0 else (1.0 if command > 1.0 else command))
            if first:
                first = False
            else:
                # Soft joint limit, as a servo controller would do it: slow the joint so that it stops at
                # the limit within this step instead of pushing into it. Only a joint within one step at
                # top speed of its limit can need it.
                relative = absolute - previous
                if not -free < relative < free:
                    low = (-limit - relative) * inv_dt
                    if rate < low:
                        rate = low
                    high = (limit - relative) * inv_dt
                    if rate > high:
                        rate = high
            previous = absolute
            # pymunk's motor rate is clockwise-positive, our commands counter-clockwise.
            set_motor_rate(handle, -rate)
        space, h = self._space_handle, self._substep_dt
        for _ in range(self.substeps):
            _space_step(space, h)
        self._walk_movers()
        obs, reward, info = self._step_result()
        if self.render_mode == "human":
            self.render()
        return self._observed(obs), reward, False, False, info

    def __getstate__(self) -> dict[str, Any]:
        # pymunk pickles a space with copies of its bodies, which would leave ``links`` and ``motors``
        # pointing at bodies outside the simulation: pickle the links' motion state and rebuild instead.
        unpicklable = (
            "space",
            "links",
            "motors",
            "_renderer",
            "_space_handle",
            "_link_handles",
            "_motor_handles",
            "_link_slots",
            "_pack_obs",
            "_walkers",
        )
        state = {k: v for k, v in self.__dict__.items() if k not in unpicklable}
        state["_link_states"] = [
            (tuple(b.position), b.angle, tuple(b.velocity), b.angular_velocity) for b in self.links
        ]
        state["_motor_rates"] = [m.rate for m in self.motors]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        link_states = state.pop("_link_states")
        motor_rates = state.pop("_motor_rates")
        self.__dict__.update(state)
        self._renderer = None
        self._pack_obs = struct.Struct(f"={self._obs_size}f").pack
        self._link_walkers()
        self._build_space()
        for body, (position, angle, velocity, spin) in zip(self.links, link_states):
            body.position, body.angle, body.velocity, body.angular_velocity = position, angle, velocity, spin
        for motor, rate in zip(self.motors, motor_rates):
            motor.rate = rate

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn(
                "You are calling render method without specifying any render mode. "
                'Pass render_mode="rgb_array" or "human" to gym.make.'
            )
            return None
        # Lazily: Pillow (+25 ms) loads only when drawing is asked for, not in every env subprocess.
        from sb3_hddpg.envs.rendering import SnakeRenderer

        if self._renderer is None:
            self._renderer = SnakeRenderer(self.render_mode, fps=self.metadata["render_fps"])
        return self._renderer.draw(self)

    def _release_space(self) -> None:
        """
        Empty the current pymunk space before it is dropped.

        A space, its bodies and its joints reference each other, so the cyclic garbage collector frees them,
        in no fixed order; pymunk 7 aborts the whole process ("Cannot remove a constraint that was not
        added to the space") when a joint is freed before its space. An empty space frees safely in any
        order, so every space this env lets go of is emptied first.
        """
        space = getattr(self, "space", None)
        if space is not None:
            space.remove(*space.constraints, *space.shapes, *space.bodies)
            self._space_handle = None

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self._release_space()

    def __del__(self) -> None:
        # An env dropped without close() (or left in a reference cycle) still empties its space first:
        # finalisers run before the collector clears the objects of a cycle (PEP 442). Envs still alive at
        # interpreter exit were released by _release_live_spaces while the modules existed; a finaliser run
        # later may find module globals set to None, hence a bare try (no contextlib lookup).
        try:  # noqa: SIM105 - contextlib may already be None here
            self._release_space()
        except Exception:
            pass


#: Every SnakeArmEnv not yet garbage-collected (weakly held, so it keeps none alive).
_LIVE_ENVS: weakref.WeakSet[SnakeArmEnv] = weakref.WeakSet()


@atexit.register
def _release_live_spaces() -> None:
    """
    Free the pymunk spaces of envs still alive at interpreter exit, while pymunk can still free them.

    Objects left at exit (an env held by a model in a script's globals, say) are freed after the modules'
    globals are torn down, when pymunk's own finaliser fails and prints a traceback for every space.
    """
    for env in list(_LIVE_ENVS):
        env._release_space()
        if hasattr(env, "space"):
            del env.space  # the last reference: the space is freed now, not at teardown


def _check_components(observe: Any, layout: StateLayout) -> tuple[str, ...] | None:
    """``observe`` as a tuple of known, distinct component names (``None``: the whole state)."""
    if observe is None:
        return None
    if isinstance(observe, str) or not isinstance(observe, (list, tuple)) or not observe:
        raise ValueError(
            f"Expected `observe` to be a non-empty list of state components {list(layout)}, actually: "
            f"{observe!r:.200}"
        )
    names = tuple(observe)
    unknown = [n for n in names if not isinstance(n, str) or n not in layout]
    if unknown:
        raise ValueError(f"Unknown state components in `observe`: {unknown!r:.200}; known: {list(layout)}")
    if len(set(names)) != len(names):
        raise ValueError(f"Expected `observe` to name each state component once, actually: {list(names)}")
    return names


def _check_choice(name: str, value: Any, choices: tuple[str, ...]) -> None:
    if value not in choices:
        raise ValueError(f"Expected `{name}` to be one of {list(choices)}, actually: {value!r}")


def _check_count(name: str, value: Any, minimum: int, maximum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not minimum <= value <= maximum:
        raise ValueError(f"Expected `{name}` to be an integer in [{minimum}, {maximum}], actually: {value!r}")


def _check_positive(name: str, value: Any) -> None:
    if not isinstance(value, (int, float, np.number)) or not math.isfinite(value) or value <= 0:
        raise ValueError(f"Expected `{name}` to be a finite number > 0, actually: {value!r}")


def _check_non_negative(name: str, value: Any) -> None:
    if not isinstance(value, (int, float, np.number)) or not math.isfinite(value) or value < 0:
        raise ValueError(f"Expected `{name}` to be a finite number >= 0, actually: {value!r}")
