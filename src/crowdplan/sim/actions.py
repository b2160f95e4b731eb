"""The one discrete action table (SPEC.md section 2): stop + 16 directions x 5 speeds.

Action frames (``WorldConfig.action_frame``) of holonomic robots: in the "goal" frame the 16
headings k*pi/8 are measured from the robot->goal direction (the x-axis of
``crowdplan.features.robot_centric``), so a policy over robot-centric features is equivariant to
rotations and translations of the whole scene; in the "world" frame they are the paper's absolute
compass headings. Unicycle actions always rotate the robot's own heading.
:func:`action_velocities` is the one statement of how an index becomes a world velocity (numpy
only: the world and a deployment runtime both use it).
"""

from __future__ import annotations

import numpy as np

N_DIRECTIONS = 16
N_SPEEDS = 5
N_ACTIONS = 1 + N_DIRECTIONS * N_SPEEDS
STOP = 0  # the index of the stop action; the moves follow it
ACTION_FRAMES = ("goal", "world")


def speed_levels(v_pref: float, sampling: str = "linear") -> np.ndarray:
    """The five speeds: {0.2, ..., 1.0} * v_pref, or CrowdNav's (e^(i/5) - 1) / (e - 1) * v_pref."""
    i = np.arange(1, N_SPEEDS + 1, dtype=np.float64)
    if sampling == "linear":
        return i / N_SPEEDS * v_pref
    if sampling == "exponential":
        return (np.exp(i / N_SPEEDS) - 1.0) / (np.e - 1.0) * v_pref
    raise ValueError(f"speed_sampling must be 'linear' or 'exponential', got {sampling!r}")


def direction_levels(kinematics: str = "holonomic") -> np.ndarray:
    """The 16 directions.

    Holonomic: headings k*pi/8, k = 0..15 (from the goal direction or the world's x-axis, see
    :func:`action_velocities`).
    Unicycle: rotations of the current heading, evenly spaced in [-pi/4, pi/4] (CrowdNav).
    """
    if kinematics == "holonomic":
        return np.arange(N_DIRECTIONS, dtype=np.float64) * (2 * np.pi / N_DIRECTIONS)
    if kinematics == "unicycle":
        return np.linspace(-np.pi / 4, np.pi / 4, N_DIRECTIONS)
    raise ValueError(f"kinematics must be 'holonomic' or 'unicycle', got {kinematics!r}")


def action_table(
    v_pref: float = 1.0, kinematics: str = "holonomic", sampling: str = "linear"
) -> np.ndarray:
    """(81, 2) array of (speed, angle); row 0 is stop, row 1 + d*5 + s is direction d, speed s."""
    speeds = speed_levels(v_pref, sampling)
    angles = direction_levels(kinematics)
    table = np.zeros((N_ACTIONS, 2))
    table[1:, 0] = np.tile(speeds, N_DIRECTIONS)
    table[1:, 1] = np.repeat(angles, N_SPEEDS)
    return table


def check_actions(actions: np.ndarray) -> np.ndarray:
    """Validate integer action indices, returning them as int64."""
    actions = np.asarray(actions)
    if actions.dtype.kind not in "iu":
        raise ValueError(
            f"actions must be integers in 0..{N_ACTIONS - 1}, got dtype {actions.dtype}"
        )
    if actions.size and (actions.min() < 0 or actions.max() >= N_ACTIONS):
        bad = actions[(actions < 0) | (actions >= N_ACTIONS)][0]
        raise ValueError(f"action {int(bad)} is outside the valid range 0..{N_ACTIONS - 1}")
    return actions.astype(np.int64)


def action_velocities(
    actions: np.ndarray,
    robot: np.ndarray,
    kinematics: str = "holonomic",
    action_frame: str = "goal",
    sampling: str = "linear",
) -> tuple[np.ndarray, np.ndarray]:
    """World-frame velocities and new headings of discrete actions.

    Args:
        actions: (E,) action indices in 0..80.
        robot: (E, 9) raw robot states px, py, vx, vy, r, gx, gy, v_pref, theta.
        kinematics: "holonomic" or "unicycle" (heading theta + rotation, then move along it).
        action_frame: "goal" (holonomic headings relative to the robot->goal direction) or
            "world" (absolute headings); ignored for unicycle robots.
        sampling: speed levels, "linear" or "exponential".

    Returns:
        (E, 2) velocities (vx, vy) and (E,) headings after the action.
    """
    if action_frame not in ACTION_FRAMES:
        raise ValueError(f"action_frame must be one of {ACTION_FRAMES}, got {action_frame!r}")
    actions = check_actions(actions)
    robot = np.asarray(robot, dtype=np.float64)
    if robot.ndim != 2 or robot.shape[1] != 9 or robot.shape[0] != actions.shape[0]:
        raise ValueError(f"robot states must have shape ({actions.shape[0]}, 9), got {robot.shape}")
    rows = np.arange(actions.shape[0])
    speeds = speed_levels(robot[:, 7:8], sampling)  # (E, 5), the same arithmetic as the table
    speed = np.where(actions == 0, 0.0, speeds[rows, (actions - 1) % N_SPEEDS])
    angle = direction_levels(kinematics)[(actions - 1) // N_SPEEDS]
    angle = np.where(actions == 0, 0.0, angle)
    theta = robot[:, 8]
    if kinematics == "unicycle":
        theta = theta + angle
        heading = theta
    elif action_frame == "goal":
        heading = angle + np.arctan2(robot[:, 6] - robot[:, 1], robot[:, 5] - robot[:, 0])
    else:
        heading = angle
    return np.stack([speed * np.cos(heading), speed * np.sin(heading)], axis=1), theta


def every_action_velocity(
    robot: np.ndarray,
    kinematics: str = "holonomic",
    action_frame: str = "goal",
    sampling: str = "linear",
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`action_velocities` of all 81 actions for each of E robots: (E, 81, 2) velocities
    and (E, 81) headings (the candidates of a lookahead or a shield)."""
    robot = np.asarray(robot, dtype=np.float64)
    e = len(robot)
    vel, theta = action_velocities(
        np.tile(np.arange(N_ACTIONS), e),
        np.repeat(robot, N_ACTIONS, axis=0),
        kinematics,
        action_frame,
        sampling,
    )
    return vel.reshape(e, N_ACTIONS, 2), theta.reshape(e, N_ACTIONS)
