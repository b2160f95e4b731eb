"""The scenario protocol's value: the initial state of one episode, and the kinds of humans.

Scenario generators (``sim/scenarios.py``, ``sim/replay.py``, ``sim/scenario_file.py``) return an
``InitialState``; the world plays it (``World.reset_states``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

PLACEMENT_MARGIN = 0.2

# Kinds of humans (codes of ``InitialState.human_kind``).
ORCA, SOCIAL_FORCE, STATIC, WAITING, REPLAY = 0, 1, 2, 3, 4
HUMAN_KINDS = ("orca", "social_force", "static", "waiting", "replay")


class PlacementError(ValueError):
    """The crowd could not be placed within the allowed number of rejection-sampling tries."""


@dataclass
class InitialState:
    """Initial state of one episode (the scenario protocol's value).

    ``N`` may be smaller than ``WorldConfig.humans``: the world pads with absent humans. The
    generator is kept for later draws (respawn on arrival).

    Attributes:
        robot_pos, robot_goal: (2,) robot start and goal.
        human_pos, human_goal: (N, 2) human starts and goals (a standing human's goal is its
            start).
        human_radius, human_v_pref: (N,) radii and preferred speeds.
        rng: the episode's generator.
        robot_theta: initial heading; None = towards the goal.
        human_kind: (N,) codes of ``HUMAN_KINDS``; None = all ORCA.
        human_wait: (N, 2) [start, end) in seconds of a waiting human's stop; None = never.
        human_vel: (N, 2) initial velocities; None = standing.
        track: (N, T + 1, 2) recorded positions of replayed humans at every step (T = max_steps);
            track_present: (N, T + 1) whether each is in the scene at that step.
        rotation: angle (rad) the scene was rotated by about the origin (respawn uses it).
    """

    robot_pos: np.ndarray
    robot_goal: np.ndarray
    human_pos: np.ndarray
    human_goal: np.ndarray
    human_radius: np.ndarray
    human_v_pref: np.ndarray
    rng: np.random.Generator = field(default_factory=lambda: np.random.default_rng(0))
    robot_theta: float | None = None
    human_kind: np.ndarray | None = None
    human_wait: np.ndarray | None = None
    human_vel: np.ndarray | None = None
    track: np.ndarray | None = None
    track_present: np.ndarray | None = None
    rotation: float = 0.0

    @property
    def humans(self) -> int:
        """Number of humans N of this scene."""
        return len(self.human_pos)

    def kinds(self) -> np.ndarray:
        """(N,) kind codes, ORCA where unset."""
        if self.human_kind is None:
            return np.full(self.humans, ORCA, dtype=np.int64)
        return np.asarray(self.human_kind, dtype=np.int64)

    def waits(self) -> np.ndarray:
        """(N, 2) stop windows in seconds, [inf, inf] where unset."""
        if self.human_wait is None:
            return np.full((self.humans, 2), np.inf)
        return np.asarray(self.human_wait, dtype=np.float64)

    def heading(self) -> float:
        """Initial robot heading: ``robot_theta`` or the direction to the goal."""
        if self.robot_theta is not None:
            return float(self.robot_theta)
        dx, dy = self.robot_goal - self.robot_pos
        return float(np.arctan2(dy, dx))
