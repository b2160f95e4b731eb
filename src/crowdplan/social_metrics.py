"""Social-navigation metrics of one episode, from its trajectory (docs/metrics.md).

Pure functions of arrays, used by ``crowdplan.evaluation.episode_record`` (the one place that
turns an episode into its record) and by the analyses that read recorded trajectories.

Conventions: states 0..T (positions after each of the T steps; state 0 is the start); the robot's
velocity of step t (``robot_vel[t - 1]``) is the one that brought it to state t; a human's
velocity at state t is the one it had during the step that ended there. Gaps are edge-to-edge:
centre distance minus both radii. Absent humans (``present`` False) are left out.
"""

from __future__ import annotations

import math

import numpy as np

PERSONAL_SPACE = 0.45  # metres from a human's edge (docs/metrics.md)
_STILL = 1e-6  # m/s: slower than this the robot has no heading


def gaps(
    robot_pos: np.ndarray,
    human_pos: np.ndarray,
    robot_radius: float,
    human_radius: np.ndarray,
    present: np.ndarray | None = None,
) -> np.ndarray:
    """Edge-to-edge distance (S, N) between the robot (S, 2) and each human (S, N, 2); inf for
    absent humans."""
    centre = np.linalg.norm(human_pos - robot_pos[:, None, :], axis=-1)
    gap = centre - robot_radius - np.asarray(human_radius, dtype=float)
    return gap if present is None else np.where(present, gap, np.inf)


def nearest_gap(gap: np.ndarray) -> np.ndarray:
    """Gap to the nearest human at each state (S,); inf without humans."""
    return gap.min(axis=1) if gap.shape[1] else np.full(len(gap), np.inf)


def personal_space_intrusion(gap: np.ndarray, space: float = PERSONAL_SPACE) -> float:
    """Share of states in which some human's edge is closer than ``space`` to the robot's edge."""
    if not len(gap):
        return 0.0
    return float(np.mean(nearest_gap(gap) < space))


def mean_human_distance(gap: np.ndarray) -> float:
    """Mean over states of the gap to the nearest human (nan without humans)."""
    nearest = nearest_gap(gap)
    nearest = nearest[np.isfinite(nearest)]
    return float(nearest.mean()) if nearest.size else math.nan


def time_to_collision(
    rel_pos: np.ndarray, rel_vel: np.ndarray, radius: np.ndarray | float
) -> np.ndarray:
    """Time until two discs moving at constant velocity touch: 0 if they already overlap, inf if
    they never do. ``rel_pos``/``rel_vel`` (..., 2) are the other's position and velocity
    relative to the robot; ``radius`` the sum of both radii."""
    radius = np.asarray(radius, dtype=float)
    c = np.einsum("...i,...i", rel_pos, rel_pos) - radius**2
    b = np.einsum("...i,...i", rel_pos, rel_vel)
    a = np.einsum("...i,...i", rel_vel, rel_vel)
    disc = b * b - a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        tau = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
    ttc = np.where((b < 0) & (disc >= 0) & (a > 0), tau, np.inf)
    return np.where(c <= 0, 0.0, ttc)


def ttc_matrix(
    robot_pos: np.ndarray,
    robot_vel: np.ndarray,
    human_pos: np.ndarray,
    human_vel: np.ndarray,
    robot_radius: float,
    human_radius: np.ndarray,
    present: np.ndarray | None = None,
) -> np.ndarray:
    """Constant-velocity time to collision (S, N) of the robot with each human at each state."""
    ttc = time_to_collision(
        human_pos - robot_pos[:, None, :],
        human_vel - robot_vel[:, None, :],
        robot_radius + np.asarray(human_radius, dtype=float),
    )
    return ttc if present is None else np.where(present, ttc, np.inf)


def path_irregularity(robot_pos: np.ndarray, robot_vel: np.ndarray, goal: np.ndarray) -> float:
    """Mean angle (rad) between the robot's velocity and the direction to its goal, over the
    steps in which it moves (0 when it never moves)."""
    moving = np.hypot(*robot_vel.T) > _STILL
    if not moving.any():
        return 0.0
    to_goal = goal - robot_pos[:-1][moving]
    vel = robot_vel[moving]
    cross = to_goal[:, 0] * vel[:, 1] - to_goal[:, 1] * vel[:, 0]
    return float(np.abs(np.arctan2(cross, np.einsum("ij,ij->i", to_goal, vel))).mean())


def linear_jerk(robot_vel: np.ndarray, dt: float) -> float:
    """Mean |change of acceleration| / dt (m/s^3); acceleration from consecutive velocities,
    starting from rest; 0 for episodes under three steps."""
    if len(robot_vel) < 3:
        return 0.0
    accel = np.diff(np.vstack([np.zeros(2), robot_vel]), axis=0) / dt
    return float(np.hypot(*np.diff(accel, axis=0).T).mean() / dt)


def headings(robot_vel: np.ndarray) -> np.ndarray:
    """Direction of motion (rad) per step, unwrapped; a still step keeps the previous heading
    (the first moving heading before the robot first moves; 0 if it never does)."""
    moving = np.hypot(*robot_vel.T) > _STILL
    if not moving.any():
        return np.zeros(len(robot_vel))
    angle = np.arctan2(robot_vel[:, 1], robot_vel[:, 0])
    idx = np.where(moving, np.arange(len(angle)), -1)
    idx = np.maximum.accumulate(idx)
    idx[idx < 0] = np.argmax(moving)
    return np.unwrap(angle[idx])


def angular_jerk(robot_vel: np.ndarray, dt: float) -> float:
    """Mean |third difference of the heading| / dt^3 (rad/s^3); 0 for episodes under 4 steps."""
    if len(robot_vel) < 4:
        return 0.0
    return float(np.abs(np.diff(headings(robot_vel), n=3)).mean() / dt**3)


def episode_metrics(trace) -> dict[str, float]:
    """The social metrics of one ``evaluation.Trace`` (that has human velocities)."""
    present = None if trace.human_present is None else trace.human_present[1:]
    gap = gaps(
        trace.robot_pos[1:], trace.human_pos[1:], trace.robot_radius, trace.human_radius, present
    )
    ttc = ttc_matrix(
        trace.robot_pos[1:],
        trace.robot_vel,
        trace.human_pos[1:],
        trace.human_vel[1:],
        trace.robot_radius,
        trace.human_radius,
        present,
    )
    return {
        "path_irregularity": path_irregularity(trace.robot_pos, trace.robot_vel, trace.robot_goal),
        "angular_jerk": angular_jerk(trace.robot_vel, trace.dt),
        "personal_space_intrusion": personal_space_intrusion(gap),
        "min_ttc": float(ttc.min()) if ttc.size else math.inf,
        "mean_human_distance": mean_human_distance(gap),
    }
