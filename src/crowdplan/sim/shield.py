"""A safety shield over the 81 discrete actions (numpy only, shared with the deployment runtime).

A learned policy ranks the actions; the shield removes the ones that would hit a human within
``horizon`` seconds if the robot held the action's velocity and every human kept its observed
velocity, then takes the best-ranked action that is left. Where every action would hit someone,
it takes the action that keeps the largest clearance over the horizon. The clearance of an action
is the smallest distance between the robot's and each human's edge along the two straight paths
(the swept distance of :func:`crowdplan.sim.world.point_to_segment_distance`), so a human that
crosses the robot's path between two control steps counts too.

The prediction is the observation only (positions and velocities): nothing is read from the
simulator, so a robot runs the same shield (:class:`crowdplan.deploy.onnx_policy.OnnxPolicy`).
docs/generalization.md measures it; its horizon was chosen on cases that no test world uses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from crowdplan.sim.actions import every_action_velocity
from crowdplan.sim.world import point_to_segment_distance


class ActionSpace(Protocol):
    """How action indices become velocities: a :class:`~crowdplan.config.WorldConfig` or an
    export's :class:`~crowdplan.deploy.manifest.Manifest` both say it."""

    kinematics: str
    action_frame: str
    speed_sampling: str


@dataclass(frozen=True)
class Shield:
    """Remove the actions predicted to collide within ``horizon`` seconds.

    Attributes:
        horizon: look-ahead time in seconds (> 0).
        margin: extra distance in metres an action must keep from every human to count as safe.
    """

    horizon: float
    margin: float = 0.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.horizon) or self.horizon <= 0:
            raise ValueError(
                f"shield horizon {self.horizon!r} s must be a positive number of seconds "
                "(0 turns the shield off where a command takes --shield)"
            )
        if not np.isfinite(self.margin) or self.margin < 0:
            raise ValueError(f"shield margin {self.margin!r} m must be >= 0")

    def clearance(
        self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray, space: ActionSpace
    ) -> np.ndarray:
        """(E, 81) smallest edge-to-edge distance to any present human over the horizon for
        each action (inf without humans; negative: a predicted collision).

        Args:
            robot: (E, 9) raw robot states; humans: (E, N, 5) raw human states; mask: (E, N).
            space: how action indices become velocities (the world the policy drives).
        """
        robot = np.asarray(robot, dtype=np.float64)
        humans = np.asarray(humans, dtype=np.float64)
        mask = np.asarray(mask, dtype=bool)
        vel, _ = every_action_velocity(
            robot, space.kinematics, space.action_frame, space.speed_sampling
        )
        vel = vel[:, :, None]  # (E, A, 1, 2)
        start = (humans[..., 0:2] - robot[:, None, 0:2])[:, None]  # (E, 1, N, 2)
        end = start + (humans[:, None, :, 2:4] - vel) * self.horizon  # (E, A, N, 2)
        gap = point_to_segment_distance(start, end) - humans[:, None, :, 4]
        gap = gap - robot[:, None, None, 4]
        return np.where(mask[:, None], gap, np.inf).min(axis=2, initial=np.inf)

    def act(
        self,
        scores: np.ndarray,
        robot: np.ndarray,
        humans: np.ndarray,
        mask: np.ndarray,
        space: ActionSpace,
    ) -> np.ndarray:
        """(E,) the shielded greedy actions for action ``scores`` (E, 81) of raw observations:
        :meth:`choose` over :meth:`clearance` (same arguments)."""
        return self.choose(scores, self.clearance(robot, humans, mask, space))

    def choose(self, scores: np.ndarray, clearance: np.ndarray) -> np.ndarray:
        """(E,) the highest-scoring safe action of each environment, or the action with the
        largest clearance where none is safe. ``scores``: (E, 81), higher is better."""
        safe = clearance >= self.margin
        best_safe = np.where(safe, scores, -np.inf).argmax(axis=1)
        return np.where(safe.any(axis=1), best_safe, clearance.argmax(axis=1))
