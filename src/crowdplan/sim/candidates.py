"""Candidate next states of the one-step lookahead, numpy only (no torch).

For E environments, all 81 actions and all N humans at once (no Python loop over either):

- the robot's next state for every action, from the one action table
  (:func:`crowdplan.sim.actions.action_velocities`);
- the humans' next states: constant-velocity propagation (``constant_velocity``, the default) or
  the simulator's true next states (``oracle``, what CrowdNav did), read from one step of a copy
  of the world. The humans' next states do not depend on the robot's action: invisible robots
  are not seen, and a visible robot enters the humans' solve with its *current* velocity, so one
  step of the copy serves all 81 candidates;
- the reward of every candidate from the world's own definitions
  (:func:`crowdplan.sim.world.point_to_segment_distance` for the swept distance,
  :func:`crowdplan.sim.world.compute_reward`), with collision > goal > (timeout) > discomfort;
- the robot-centric features of every next state (:func:`crowdplan.features.robot_centric`).

:func:`candidate_values` scores each candidate ``r + gamma_step * V(s')`` from the values of the
next states, without the bootstrap term where the candidate ends the episode (collision or goal).
Training evaluates V with torch (:mod:`crowdplan.sim.lookahead`), the deployment runtime with
onnxruntime (:mod:`crowdplan.deploy.value_lookahead`); both build the candidates here.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from crowdplan.config import WorldConfig
from crowdplan.features import Features, robot_centric
from crowdplan.sim.actions import N_ACTIONS, every_action_velocity
from crowdplan.sim.world import (
    COLLISION,
    GOAL,
    RUNNING,
    TIMEOUT,
    compute_reward,
    point_to_segment_distance,
)

if TYPE_CHECKING:
    from crowdplan.sim.world import World

LOOKAHEAD_MODES = ("constant_velocity", "oracle")


@dataclass
class Candidates:
    """The 81 one-step candidates of E environments.

    Attributes:
        robot: (E, A, 9) raw next robot states.
        humans: (E, N, 5) raw next human states (the same for every action).
        mask: (E, N) humans present in the next state.
        rewards: (E, A) reward of each action.
        outcome: (E, A) outcome codes of :mod:`crowdplan.sim.world` (RUNNING, GOAL, ...).
        features: robot-centric features of the E * A next states, flattened env-major
            (row ``e * A + a``).
    """

    robot: np.ndarray
    humans: np.ndarray
    mask: np.ndarray
    rewards: np.ndarray
    outcome: np.ndarray
    features: Features

    @property
    def terminal(self) -> np.ndarray:
        """(E, A) candidates that end the episode (collision or goal)."""
        return (self.outcome == COLLISION) | (self.outcome == GOAL)


@dataclass
class Timing:
    """Episode clocks for the timeout reward: steps taken (E,), start-goal distance (E,) and the
    step limit. Without it no candidate times out (a state value carries no clock)."""

    steps: np.ndarray
    start_dist: np.ndarray
    max_steps: int


def check_mode(mode: str) -> str:
    """``mode`` if it is a lookahead mode, else a ValueError naming the valid ones."""
    if mode not in LOOKAHEAD_MODES:
        raise ValueError(f"unknown lookahead {mode!r}; valid modes: {', '.join(LOOKAHEAD_MODES)}")
    return mode


def next_humans(
    humans: np.ndarray,
    mask: np.ndarray,
    dt: float,
    mode: str = "constant_velocity",
    world: World | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Next human states (E, N, 5), their velocities during the step (E, N, 2) and next mask.

    ``oracle`` steps a deep copy of ``world`` (whose observation must be ``humans``, ``mask``);
    the world itself is not changed.
    """
    check_mode(mode)
    if mode == "constant_velocity":
        vel = humans[..., 2:4]
        moved = humans.copy()
        moved[..., 0:2] = humans[..., 0:2] + vel * dt
        return moved, vel, mask
    if world is None:
        raise ValueError(
            "the oracle lookahead queries the simulator: it needs the world being played "
            "(evaluation hands it over; other callers use lookahead 'constant_velocity')"
        )
    shadow = copy.deepcopy(world)
    shadow.step(np.zeros(shadow.num_envs, dtype=np.int64))
    k = shadow.config.humans  # observations may pad humans beyond the world's N
    moved = humans.copy()
    moved[:, :k, 0:2] = shadow.human_pos
    moved[:, :k, 2:4] = shadow.human_vel
    next_mask = np.zeros_like(mask)
    next_mask[:, :k] = shadow.human_present
    return moved, moved[..., 2:4], next_mask


def one_step(
    robot: np.ndarray,
    humans: np.ndarray,
    mask: np.ndarray,
    config: WorldConfig,
    mode: str = "constant_velocity",
    world: World | None = None,
    timing: Timing | None = None,
) -> Candidates:
    """Every action's next state, reward and features for raw observations of E environments.

    Args:
        robot: (E, 9) raw robot states; humans: (E, N, 5); mask: (E, N) present humans.
        config: the world's configuration (dt, kinematics, action frame, speeds, discomfort).
        mode: ``constant_velocity`` or ``oracle`` (needs ``world``).
        world: the world the observation came from (oracle mode only).
        timing: episode clocks, for the timeout reward (see :class:`Timing`).
    """
    robot = np.asarray(robot, dtype=np.float64)
    humans = np.asarray(humans, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    e, n = mask.shape
    a = N_ACTIONS
    dt = config.dt
    vel, theta = every_action_velocity(
        robot, config.kinematics, config.action_frame, config.speed_sampling
    )
    next_robot = np.repeat(robot[:, None], a, axis=1)
    next_robot[..., 0:2] = robot[:, None, 0:2] + vel * dt
    next_robot[..., 2:4] = vel
    next_robot[..., 8] = theta
    moved, human_vel, next_mask = next_humans(humans, mask, dt, mode, world)

    # swept distance of each human's motion relative to the robot during dt, minus both radii
    start = (humans[..., 0:2] - robot[:, None, 0:2])[:, None]  # (E, 1, N, 2)
    end = start + (human_vel[:, None] - vel[:, :, None]) * dt  # (E, A, N, 2)
    gap = point_to_segment_distance(start, end) - humans[:, None, :, 4] - robot[:, None, None, 4]
    d_min = np.where(mask[:, None], gap, np.inf).min(axis=2, initial=np.inf)  # (E, A)

    to_goal = robot[:, None, 5:7] - next_robot[..., 0:2]
    goal_dist = np.sqrt(to_goal[..., 0] * to_goal[..., 0] + to_goal[..., 1] * to_goal[..., 1])
    outcome = np.full((e, a), RUNNING)
    start_dist = np.ones((e, 1))
    if timing is not None:
        start_dist = np.asarray(timing.start_dist, dtype=np.float64)[:, None]
        late = (np.asarray(timing.steps) + 1 >= timing.max_steps)[:, None]
        outcome = np.where(late, TIMEOUT, outcome)
    outcome = np.where(goal_dist < robot[:, None, 4], GOAL, outcome)
    outcome = np.where(d_min < 0, COLLISION, outcome)
    rewards = compute_reward(outcome, d_min, start_dist, goal_dist, config.discomfort_dist)

    features = robot_centric(
        next_robot.reshape(e * a, 9),
        np.repeat(moved, a, axis=0),  # (E * A, N, 5): each env's humans once per action
        np.repeat(next_mask, a, axis=0),
        config.kinematics == "unicycle",
    )
    return Candidates(next_robot, moved, next_mask, rewards, outcome, features)


def step_discount(gamma_per_second: float, config: WorldConfig) -> float:
    """Discount of one step: ``gamma ** (dt * v_pref)`` (gamma per second of travel at v_pref)."""
    return gamma_per_second ** (config.dt * config.robot_v_pref)


def candidate_values(candidates: Candidates, values: np.ndarray, gamma_step: float) -> np.ndarray:
    """(E, A) ``r + gamma_step * V(s')`` of every candidate from the values ``values`` (E * A,)
    of the flattened next states; terminal candidates score ``r``."""
    e, a = candidates.rewards.shape
    alive = ~candidates.terminal
    return candidates.rewards + gamma_step * alive * np.asarray(values).reshape(e, a)
