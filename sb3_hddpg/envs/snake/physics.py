"""
The snake arm's body: a pymunk chain of velocity-controlled links. The step calls Chipmunk's C functions
through pymunk's cffi module with the raw pointers pymunk keeps on its objects, without pymunk's Python
layers, which cost several times more (docs/PERFORMANCE.md).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pymunk
from pymunk._chipmunk_cffi import lib as _chipmunk

from sb3_hddpg.envs.snake.params import SnakeParams

#: Chipmunk's C functions the step calls (see the module's note).
body_angle = _chipmunk.cpBodyGetAngle
_set_motor_rate = _chipmunk.cpSimpleMotorSetRate
_space_step = _chipmunk.cpSpaceStep


class ArmPhysics:
    """
    The pymunk chain of one snake arm (see :class:`~sb3_hddpg.envs.snake.SnakeArmEnv`). :meth:`build` makes
    a fresh space (``reset`` needs one: pymunk carries solver state between steps).

    :param params: the arm's parameters.
    """

    def __init__(self, params: SnakeParams) -> None:
        self.n_joints = params.n_joints
        self.link_length = params.link_length
        self.substeps = params.substeps
        self.top_speed = params.max_joint_speed
        self.joint_limit = params.joint_limit
        self.substep_dt = params.dt / params.substeps
        self.inv_dt = 1.0 / params.dt
        # Joints with |relative angle| below this cannot reach their limit within a step, whatever the
        # command (with a margin far above rounding errors); negative if any joint can.
        reach_per_step = params.max_joint_speed * params.dt
        self.free_joint_range = (
            params.joint_limit - reach_per_step - 1e-9 * (params.joint_limit + reach_per_step)
        )
        # The links' absolute angles as last read from the physics (the soft joint limits need them).
        self.angles = [0.0] * self.n_joints
        self.space: pymunk.Space | None = None
        self.build()

    def build(self) -> None:
        """Build a fresh chain, at rest along the x axis, emptying the previous space first."""
        self.release()
        space = self.space = pymunk.Space()
        space.gravity = (0.0, 0.0)  # a planar arm on a table: gravity is normal to the plane
        space.iterations = 10
        # Lighter toward the tip: pymunk's solver tracks a chain of equal masses badly, a 0.6 ratio per link
        # tracks the commanded rates within ~3 %.
        masses = [0.6**i for i in range(self.n_joints)]
        self.links: list[pymunk.Body] = []
        self.motors: list[pymunk.SimpleMotor] = []
        parent: pymunk.Body = space.static_body
        for i in range(self.n_joints):
            moment = pymunk.moment_for_segment(masses[i], (0, 0), (self.link_length, 0), 0.01)
            body = pymunk.Body(masses[i], moment)
            # The base pivot sits at the static body's origin; the others at the parent link's far end.
            anchor = (0.0, 0.0) if i == 0 else (self.link_length, 0.0)
            pivot = pymunk.PivotJoint(parent, body, anchor, (0.0, 0.0))
            motor = pymunk.SimpleMotor(parent, body, 0.0)
            # Strong enough to hold the commanded rate against the chain's inertia within a substep.
            motor.max_force = 50.0
            space.add(body, pivot, motor)
            self.links.append(body)
            self.motors.append(motor)
            parent = body
        # Raw Chipmunk pointers for the step; the pymunk objects own them and keep them alive.
        self._space_handle: object = space._space
        self.link_handles = [body._body for body in self.links]
        self._motor_handles = [motor._constraint for motor in self.motors]

    def place(self, joint_angles: np.ndarray) -> None:
        """Put the chain at the given relative joint angles, at rest."""
        absolute = np.cumsum(joint_angles)
        start = np.zeros(2)
        for body, angle in zip(self.links, absolute):
            body.angle = float(angle)
            body.position = (float(start[0]), float(start[1]))
            body.velocity = (0.0, 0.0)
            body.angular_velocity = 0.0
            start = start + self.link_length * np.array([math.cos(angle), math.sin(angle)])

    def drive(self, commands: list[float]) -> None:
        """
        Set every motor to its command (clipped to [-1, 1], times the top speed; counter-clockwise positive),
        slowed where a joint would pass its limit within the step (reading :attr:`angles`), and advance the
        physics one env step.
        """
        top = self.top_speed
        limit = self.joint_limit
        inv_dt = self.inv_dt
        free = self.free_joint_range
        set_motor_rate = _set_motor_rate
        previous = 0.0
        first = True
        for handle, command, absolute in zip(self._motor_handles, commands, self.angles):
            rate = top * (-1.0 if command < -1.0 else (1.0 if command > 1.0 else command))
            if first:
                first = False
            else:
                # Soft joint limit: stop at the limit within this step instead of pushing into it (a
                # RotaryLimitJoint fighting the motor made the chain unstable).
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
        space, h = self._space_handle, self.substep_dt
        for _ in range(self.substeps):
            _space_step(space, h)

    def chain_points(self) -> tuple[list[float], list[float]]:
        """
        The chain's x and y from the base to the tip, by forward kinematics from the link angles (also stored
        in :attr:`angles`), so exactly one link length apart.
        """
        length = self.link_length
        x = y = 0.0
        xs = [0.0]
        ys = [0.0]
        angles = self.angles
        for i, body in enumerate(self.links):
            angle = angles[i] = body.angle
            x += length * math.cos(angle)
            y += length * math.sin(angle)
            xs.append(x)
            ys.append(y)
        return xs, ys

    def __getstate__(self) -> dict[str, object]:
        # pymunk pickles a space with copies of its bodies, outside the simulation: keep the motion, rebuild.
        kept = {k: v for k, v in self.__dict__.items() if k not in _UNPICKLABLE}
        kept["_links"] = [
            ((b.position.x, b.position.y), b.angle, (b.velocity.x, b.velocity.y), b.angular_velocity)
            for b in self.links
        ]
        kept["_motor_rates"] = [m.rate for m in self.motors]
        return kept

    def __setstate__(self, state: dict[str, Any]) -> None:
        links, rates = state.pop("_links"), state.pop("_motor_rates")
        self.__dict__.update(state)
        self.space = None
        self.build()
        for body, (position, angle, velocity, spin) in zip(self.links, links):
            body.position, body.angle, body.velocity, body.angular_velocity = position, angle, velocity, spin
        for motor, rate in zip(self.motors, rates):
            motor.rate = rate

    def release(self) -> None:
        """
        Empty the current pymunk space before it is dropped: the garbage collector frees a space and its
        joints in no fixed order, and pymunk 7 aborts the process when a joint goes before its space.
        """
        space = getattr(self, "space", None)
        if space is not None:
            space.remove(*space.constraints, *space.shapes, *space.bodies)
            self._space_handle = None


_UNPICKLABLE = ("space", "links", "motors", "_space_handle", "link_handles", "_motor_handles")
