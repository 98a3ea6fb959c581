"""
The snake arm's hand-written controllers, reading only the observation: two reachers blind to obstacles and
a potential-field avoider blind to the goal; baselines for the learned workers, and priors
(:class:`~sb3_hddpg.callbacks.ControllerPrior`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sb3_hddpg.envs.layout import StateLayout

#: The env's default joint speed at an action of 1 (rad/s), which :class:`IKReacher` scales its rates by.
DEFAULT_MAX_JOINT_SPEED = 1.5


class _ObservationController:
    """A controller that reads only the observation (one or a batch) and keeps no state."""

    def predict(
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, None]:
        """The command(s) for ``observation`` (one or a batch), like SB3's ``predict``: no state."""
        obs = np.atleast_2d(observation).astype(np.float64)
        action = np.clip(self._command(obs), -1.0, 1.0).astype(np.float32)
        return (action if np.ndim(observation) > 1 else action[0]), None

    def _command(self, obs: np.ndarray) -> np.ndarray:
        """The commands for a batch of observations ``(batch, obs_dim)``, before clipping to [-1, 1]."""
        raise NotImplementedError


@dataclass(eq=False)
class JacobianReacher(_ObservationController):
    """
    Moves the tip toward the goal by Jacobian-transpose control: joint ``i`` turns by the 2-D cross product
    of ``tip - p_i`` with the tip-to-goal vector. It ignores obstacles.

    :param layout: the env's ``state_layout``.
    :param gain: command per unit of the Jacobian-transpose signal (clipped to [-1, 1]).
    """

    layout: StateLayout
    gain: float = 8.0

    def _command(self, obs: np.ndarray) -> np.ndarray:
        lever, error = _levers_and_error(self.layout, obs)
        return self.gain * (lever[..., 0] * error[:, None, 1] - lever[..., 1] * error[:, None, 0])


@dataclass(eq=False)
class IKReacher(_ObservationController):
    """
    Moves the tip toward the goal by damped-least-squares inverse kinematics: joint rates
    ``J^T (J J^T + damping^2 I)^-1 (gain * error)``, scaled to the action range by ``max_joint_speed``.
    Blind to obstacles, but proportional, so it holds a moving goal: the ceiling of reaching alone; with
    ``bang_bang=True`` it shows what a saturated actor costs (docs/WORKERS.md).

    :param layout: the env's ``state_layout``.
    :param gain: the error fraction closed per second.
    :param damping: the damping of the least-squares solve (in reach units), for poses near a singularity.
    :param max_joint_speed: the env's joint speed at an action of 1 (rad/s).
    :param bang_bang: replace every command by its sign.
    """

    layout: StateLayout
    gain: float = 3.0
    damping: float = 0.1
    max_joint_speed: float = DEFAULT_MAX_JOINT_SPEED
    bang_bang: bool = False

    def _command(self, obs: np.ndarray) -> np.ndarray:
        lever, error = _levers_and_error(self.layout, obs)  # (batch, joints, 2), (batch, 2)
        jacobian = np.stack((-lever[..., 1], lever[..., 0]), axis=1)  # (batch, 2, joints)
        damped = jacobian @ jacobian.transpose(0, 2, 1) + self.damping**2 * np.eye(2)
        task = np.linalg.solve(damped, self.gain * error[..., None])  # (batch, 2, 1)
        rates = (jacobian.transpose(0, 2, 1) @ task)[..., 0] / self.max_joint_speed
        return np.sign(rates) if self.bang_bang else rates


@dataclass(eq=False)
class FieldAvoider(_ObservationController):
    """
    Moves every link away from its obstacle by a repulsive potential field: a link whose clearance ``c`` (a
    fraction of the sensor range) is below ``margin`` is pushed at its midpoint with strength
    ``(margin - c) ** power``, mapped to joint rates by the Jacobian transpose. Blind to the goal: the avoid
    worker's reference (docs/WORKERS.md).

    :param layout: the env's ``state_layout``.
    :param gain: command per unit of the Jacobian-transpose signal (clipped to [-1, 1]).
    :param margin: the clearance, as a fraction of the sensor range, below which a link is pushed.
    :param power: the push's growth as the clearance shrinks (2: quadratic, gentle at the range's edge).
    """

    layout: StateLayout
    gain: float = 4.0
    margin: float = 1.0
    power: float = 2.0

    def _command(self, obs: np.ndarray) -> np.ndarray:
        ends, pivots = _ends_and_pivots(self.layout, obs)
        towards = obs[:, self.layout["joint_obstacle_vectors"]].reshape(ends.shape)
        clearance = obs[:, self.layout["joint_obstacle_distances"]]
        strength = np.clip(self.margin - clearance, 0.0, None) ** self.power
        norm = np.linalg.norm(towards, axis=-1)
        # A link with its obstacle at zero distance has no direction to flee in: no push.
        scale = np.divide(strength, norm, out=np.zeros_like(norm), where=norm > 1e-9)
        push = -towards * scale[..., None]  # (batch, links, 2)
        middles = 0.5 * (pivots + ends)
        # lever[b, i, j] = middle of link i - pivot of joint j, counted only where joint j moves link i (j <= i).
        lever = middles[:, :, None, :] - pivots[:, None, :, :]
        moves = np.tril(np.ones((ends.shape[1], ends.shape[1])))[None, :, :]
        torque = lever[..., 0] * push[:, :, None, 1] - lever[..., 1] * push[:, :, None, 0]
        return self.gain * (moves * torque).sum(axis=1)


def _ends_and_pivots(layout: StateLayout, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each link's far end and its pivot (the base pivot at the origin), ``(batch, links, 2)`` each."""
    ends = obs[:, layout["joint_positions"]].reshape(len(obs), -1, 2)
    pivots = np.concatenate((np.zeros((len(obs), 1, 2)), ends[:, :-1]), axis=1)
    return ends, pivots


def _levers_and_error(layout: StateLayout, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """From a batch of observations: each joint's lever ``tip - p_i`` and the tip-to-goal vector."""
    ends, pivots = _ends_and_pivots(layout, obs)
    error = 2.0 * obs[:, layout["ee_to_goal"]]  # the observation halves it
    return ends[:, -1:, :] - pivots, error


Controller = IKReacher | JacobianReacher | FieldAvoider

#: The controllers by the names configs and commands use.
CONTROLLERS: dict[str, type[Controller]] = {
    "ik": IKReacher,
    "jacobian": JacobianReacher,
    "field": FieldAvoider,
}
#: The observation components each controller reads.
CONTROLLER_INPUTS: dict[str, tuple[str, ...]] = {
    "ik": ("joint_positions", "ee_to_goal"),
    "jacobian": ("joint_positions", "ee_to_goal"),
    "field": ("joint_positions", "joint_obstacle_vectors", "joint_obstacle_distances"),
}


def make_controller(
    name: str, layout: StateLayout, max_joint_speed: float = DEFAULT_MAX_JOINT_SPEED
) -> Controller:
    """
    The controller ``name`` (:data:`CONTROLLERS`) for observations of ``layout``.

    :param name: ``ik``, ``jacobian`` or ``field``.
    :param layout: the observation's layout (an ``observe`` view's own, :meth:`StateLayout.view`).
    :param max_joint_speed: the env's joint speed at an action of 1 (the IK reacher scales by it).
    :raises ValueError: an unknown name, or a layout without a component the controller reads
        (:data:`CONTROLLER_INPUTS`).
    """
    if name not in CONTROLLERS:
        raise ValueError(f"Unknown controller {name!r:.100}; choose from {sorted(CONTROLLERS)}")
    missing = [c for c in CONTROLLER_INPUTS[name] if c not in layout]
    if missing:
        raise ValueError(
            f"The {name} controller reads {missing} from the observation, which holds {list(layout)}"
        )
    if name == "ik":
        return IKReacher(layout, max_joint_speed=max_joint_speed)
    return CONTROLLERS[name](layout)
