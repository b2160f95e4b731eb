"""ORCA as the robot's planner: the robot sees the humans, the humans do not see it."""

from __future__ import annotations

import numpy as np

from crowdplan.config import OrcaConfig
from crowdplan.policy import PolicyOutput
from crowdplan.sim.orca import orca_velocities, preferred_velocities


class OrcaPlanner:
    """Continuous ORCA velocity commands for a holonomic robot.

    Args:
        dt: simulation step (the ORCA collision case uses 1/dt).
        orca: ORCA parameters (neighbor distance, horizon, radius pad).
        safety_space: extra radius added to every agent (CrowdNav's ORCA safety space; the
            imitation-learning demonstrations use 0.15).
    """

    name = "orca"
    kinematics = "holonomic"

    def __init__(self, dt: float = 0.25, orca: OrcaConfig | None = None, safety_space: float = 0.0):
        self.dt = dt
        self.orca = orca or OrcaConfig()
        self.safety_space = safety_space

    def act(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray) -> PolicyOutput:
        e, n = mask.shape
        pos = np.concatenate([robot[:, None, 0:2], humans[..., 0:2]], axis=1)
        vel = np.concatenate([robot[:, None, 2:4], humans[..., 2:4]], axis=1)
        radii = np.concatenate([robot[:, None, 4], humans[..., 4]], axis=1)
        radii = radii + self.orca.radius_pad + self.safety_space
        v_pref = robot[:, 7]
        pref = np.zeros((e, n + 1, 2))
        pref[:, 0] = preferred_velocities(robot[:, 0:2], robot[:, 5:7], v_pref)
        max_speed = np.concatenate([v_pref[:, None], np.ones((e, n))], axis=1)
        active = np.concatenate([np.ones((e, 1), dtype=bool), mask.astype(bool)], axis=1)
        solve = np.zeros((e, n + 1), dtype=bool)
        solve[:, 0] = True
        new = orca_velocities(
            pos,
            vel,
            radii,
            pref,
            max_speed,
            active,
            solve,
            self.dt,
            self.orca.neighbor_dist,
            self.orca.max_neighbors,
            self.orca.time_horizon,
        )
        return PolicyOutput(new[:, 0])
