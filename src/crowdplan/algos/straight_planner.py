"""The blind baseline: drive straight at the goal at full speed, ignoring everyone."""

from __future__ import annotations

import numpy as np

from crowdplan.policy import PolicyOutput


class StraightPlanner:
    """Velocity ``v_pref`` along the robot->goal direction, whoever is in the way.

    What any planner must beat: its collisions are the ones a crowd causes when the robot does
    not react at all.
    """

    name = "straight"
    kinematics = "holonomic"

    def act(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray) -> PolicyOutput:
        to_goal = robot[:, 5:7] - robot[:, 0:2]
        distance = np.maximum(np.linalg.norm(to_goal, axis=1, keepdims=True), 1e-12)
        return PolicyOutput(to_goal / distance * robot[:, 7:8])
