"""Batched crowd world: E environments x N humans stepped together (SPEC.md sections 1-2).

One environment is E = 1. Humans are driven by one shared ORCA solve per environment and step.
The robot is commanded either by discrete action indices (the 81-action table) or by continuous
velocity commands (planners such as ORCA).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crowdplan.config import WorldConfig
from crowdplan.sim import scenarios
from crowdplan.sim.actions import action_table, check_actions
from crowdplan.sim.orca import orca_velocities, preferred_velocities

# Outcome codes, reported per environment and step.
RUNNING, GOAL, COLLISION, TIMEOUT = 0, 1, 2, 3
OUTCOME_NAMES = {RUNNING: "running", GOAL: "goal", COLLISION: "collision", TIMEOUT: "timeout"}

REWARD_GOAL = 1.0
REWARD_COLLISION = -0.25
TIMEOUT_REWARD_SCALE = 0.5
DISCOMFORT_SCALE = 0.5


@dataclass
class StepResult:
    """Per-environment outcome of one step; arrays of shape (E,)."""

    reward: np.ndarray
    terminated: np.ndarray  # goal or collision
    truncated: np.ndarray  # timeout
    outcome: np.ndarray  # RUNNING / GOAL / COLLISION / TIMEOUT
    d_min: np.ndarray  # swept minimum distance between robot and humans (inf with no humans)


def point_to_segment_distance(
    start: np.ndarray, end: np.ndarray, point: np.ndarray | None = None
) -> np.ndarray:
    """Distance from ``point`` (default: origin) to the segments start->end; shapes (..., 2)."""
    if point is not None:
        start, end = start - point, end - point
    seg = end - start
    seg_len_sq = np.einsum("...i,...i->...", seg, seg)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(seg_len_sq > 0, -np.einsum("...i,...i->...", start, seg) / seg_len_sq, 0.0)
    u = np.clip(u, 0.0, 1.0)
    closest = start + u[..., None] * seg
    return np.hypot(closest[..., 0], closest[..., 1])


def compute_reward(
    outcome: np.ndarray,
    d_min: np.ndarray,
    start_dist: np.ndarray,
    goal_dist: np.ndarray,
    discomfort_dist: float,
) -> np.ndarray:
    """Paper eq. 8 with the priority collision > goal > timeout > discomfort."""
    discomfort = (d_min > 0) & (d_min < discomfort_dist)
    timeout_reward = TIMEOUT_REWARD_SCALE * (start_dist - goal_dist) / start_dist
    return np.select(
        [outcome == COLLISION, outcome == GOAL, outcome == TIMEOUT, discomfort],
        [
            REWARD_COLLISION,
            REWARD_GOAL,
            timeout_reward,
            (d_min - discomfort_dist) * DISCOMFORT_SCALE,
        ],
        0.0,
    )


class World:
    """State of E environments with N humans each, stepped in one call.

    Arrays (public, read-only for callers): ``robot_pos`` (E, 2), ``robot_vel`` (E, 2),
    ``robot_theta`` (E,), ``robot_goal`` (E, 2), ``human_pos`` / ``human_vel`` / ``human_goal``
    (E, N, 2), ``human_radius`` / ``human_v_pref`` (E, N), ``steps`` (E,), ``seeds`` (E,).
    """

    def __init__(self, config: WorldConfig, num_envs: int = 1) -> None:
        if not isinstance(num_envs, int) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        self.config = config
        self.num_envs = num_envs
        self.actions = action_table(config.robot_v_pref, config.kinematics, config.speed_sampling)
        e, n = num_envs, config.humans
        self.robot_pos = np.zeros((e, 2))
        self.robot_vel = np.zeros((e, 2))
        self.robot_theta = np.full(e, np.pi / 2)
        self.robot_goal = np.zeros((e, 2))
        self.start_dist = np.ones(e)
        self.human_pos = np.zeros((e, n, 2))
        self.human_vel = np.zeros((e, n, 2))
        self.human_goal = np.zeros((e, n, 2))
        self.human_radius = np.full((e, n), config.human_radius)
        self.human_v_pref = np.full((e, n), config.human_v_pref)
        self.steps = np.zeros(e, dtype=np.int64)
        self.seeds = np.full(e, -1, dtype=np.int64)
        self._rngs: list[np.random.Generator | None] = [None] * e

    # ------------------------------------------------------------------ reset / observe
    def reset(self, seeds, env_ids=None) -> None:
        """Start new episodes: environment ``env_ids[k]`` (default: all) gets seed ``seeds[k]``."""
        seeds = [scenarios.check_seed(s) for s in np.atleast_1d(np.asarray(seeds, dtype=object))]
        env_ids = range(self.num_envs) if env_ids is None else [int(i) for i in env_ids]
        if len(seeds) != len(env_ids):
            raise ValueError(f"got {len(seeds)} seeds for {len(env_ids)} environments")
        for env, seed in zip(env_ids, seeds, strict=True):
            init = scenarios.generate(self.config, seed)
            self.robot_pos[env] = init.robot_pos
            self.robot_goal[env] = init.robot_goal
            self.robot_vel[env] = 0.0
            self.robot_theta[env] = np.pi / 2
            self.start_dist[env] = np.linalg.norm(init.robot_goal - init.robot_pos)
            self.human_pos[env] = init.human_pos
            self.human_goal[env] = init.human_goal
            self.human_vel[env] = 0.0
            self.human_radius[env] = init.human_radius
            self.human_v_pref[env] = init.human_v_pref
            self.steps[env] = 0
            self.seeds[env] = seed
            self._rngs[env] = init.rng

    def observe(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Raw observation: robot (E, 9), humans (E, N, 5), mask (E, N) (all humans are real)."""
        cfg = self.config
        e, n = self.num_envs, cfg.humans
        robot = np.empty((e, 9))
        robot[:, 0:2] = self.robot_pos
        robot[:, 2:4] = self.robot_vel
        robot[:, 4] = cfg.robot_radius
        robot[:, 5:7] = self.robot_goal
        robot[:, 7] = cfg.robot_v_pref
        robot[:, 8] = self.robot_theta
        humans = np.empty((e, n, 5))
        humans[..., 0:2] = self.human_pos
        humans[..., 2:4] = self.human_vel
        humans[..., 4] = self.human_radius
        return robot, humans, np.ones((e, n), dtype=bool)

    # ------------------------------------------------------------------ step
    def robot_velocity(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-frame robot velocity and new heading for discrete actions (E,) or commands (E, 2).

        Commands are world-frame (vx, vy) for holonomic robots (clipped to v_pref) and
        (speed, rotation) for unicycle robots.
        """
        actions = np.asarray(actions)
        if actions.dtype.kind in "iu" or actions.ndim == 1:
            speed_angle = self.actions[check_actions(actions)]
        else:
            if actions.shape != (self.num_envs, 2):
                raise ValueError(
                    f"velocity commands must have shape ({self.num_envs}, 2), got {actions.shape}"
                )
            if self.config.kinematics == "holonomic":
                speed = np.minimum(np.hypot(actions[:, 0], actions[:, 1]), self.config.robot_v_pref)
                angle = np.arctan2(actions[:, 1], actions[:, 0])
                speed_angle = np.stack([speed, angle], axis=1)
            else:
                speed_angle = actions
        speed, angle = speed_angle[:, 0], speed_angle[:, 1]
        theta = (
            self.robot_theta + angle if self.config.kinematics == "unicycle" else self.robot_theta
        )
        heading = theta if self.config.kinematics == "unicycle" else angle
        vel = np.stack([speed * np.cos(heading), speed * np.sin(heading)], axis=1)
        return vel, theta

    def human_velocities(self, active: np.ndarray) -> np.ndarray:
        """New human velocities from one shared ORCA solve per environment."""
        cfg = self.config
        e, n = self.num_envs, cfg.humans
        pref = preferred_velocities(self.human_pos, self.human_goal, self.human_v_pref)
        solve = np.broadcast_to(active[:, None], (e, n))
        if not cfg.visible_robot:
            return orca_velocities(
                self.human_pos,
                self.human_vel,
                self.human_radius + cfg.orca.radius_pad,
                pref,
                self.human_v_pref,
                np.ones((e, n), dtype=bool),
                np.ascontiguousarray(solve),
                cfg.dt,
                cfg.orca.neighbor_dist,
                cfg.orca.max_neighbors,
                cfg.orca.time_horizon,
            )
        # The robot joins the solve as a neighbour with its current velocity; it is never solved.
        pos = np.concatenate([self.robot_pos[:, None], self.human_pos], axis=1)
        vel = np.concatenate([self.robot_vel[:, None], self.human_vel], axis=1)
        radii = (
            np.concatenate([np.full((e, 1), cfg.robot_radius), self.human_radius], axis=1)
            + cfg.orca.radius_pad
        )
        pref_all = np.concatenate([self.robot_vel[:, None], pref], axis=1)
        speeds = np.concatenate([np.full((e, 1), cfg.robot_v_pref), self.human_v_pref], axis=1)
        solve_all = np.concatenate([np.zeros((e, 1), dtype=bool), solve], axis=1)
        new = orca_velocities(
            pos,
            vel,
            radii,
            pref_all,
            speeds,
            np.ones((e, n + 1), dtype=bool),
            solve_all,
            cfg.dt,
            cfg.orca.neighbor_dist,
            cfg.orca.max_neighbors,
            cfg.orca.time_horizon,
        )
        return new[:, 1:]

    def step(self, actions: np.ndarray, active: np.ndarray | None = None) -> StepResult:
        """Advance every active environment by dt; inactive ones are left untouched.

        Args:
            actions: (E,) integer action indices in 0..80, or (E, 2) float velocity commands.
            active: (E,) bool, default all.
        """
        cfg = self.config
        active = np.ones(self.num_envs, dtype=bool) if active is None else np.asarray(active, bool)
        robot_vel, robot_theta = self.robot_velocity(actions)
        human_vel = self.human_velocities(active)

        # Swept collision test: the human's motion relative to the robot during dt.
        rel_start = self.human_pos - self.robot_pos[:, None]
        rel_end = rel_start + (human_vel - robot_vel[:, None]) * cfg.dt
        gaps = point_to_segment_distance(rel_start, rel_end) - self.human_radius - cfg.robot_radius
        d_min = gaps.min(axis=1) if cfg.humans else np.full(self.num_envs, np.inf)

        a = active[:, None]
        self.robot_pos = np.where(a, self.robot_pos + robot_vel * cfg.dt, self.robot_pos)
        self.robot_vel = np.where(a, robot_vel, self.robot_vel)
        self.robot_theta = np.where(active, robot_theta, self.robot_theta)
        a3 = active[:, None, None]
        self.human_pos = np.where(a3, self.human_pos + human_vel * cfg.dt, self.human_pos)
        self.human_vel = np.where(a3, human_vel, self.human_vel)
        self.steps = self.steps + active

        goal_dist = np.linalg.norm(self.robot_goal - self.robot_pos, axis=1)
        outcome = np.select(
            [d_min < 0, goal_dist < cfg.robot_radius, self.steps >= cfg.max_steps],
            [COLLISION, GOAL, TIMEOUT],
            RUNNING,
        )
        outcome = np.where(active, outcome, RUNNING)
        reward = compute_reward(outcome, d_min, self.start_dist, goal_dist, cfg.discomfort_dist)
        reward = np.where(active, reward, 0.0)
        if cfg.respawn_on_arrival and cfg.humans:
            self._respawn_arrived(active)
        return StepResult(
            reward=reward,
            terminated=(outcome == GOAL) | (outcome == COLLISION),
            truncated=outcome == TIMEOUT,
            outcome=outcome,
            d_min=d_min,
        )

    def _respawn_arrived(self, active: np.ndarray) -> None:
        arrived = np.linalg.norm(self.human_goal - self.human_pos, axis=2) < self.human_radius
        arrived &= active[:, None]
        for env, human in zip(*np.nonzero(arrived), strict=True):
            self.human_goal[env, human] = scenarios.respawn_goal(
                self.config,
                self._rngs[env],
                self.human_pos[env, human],
                self.human_v_pref[env, human],
            )
