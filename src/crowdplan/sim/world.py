"""Batched crowd world: E environments x N humans stepped together (SPEC.md sections 1-2).

One environment is E = 1. Humans are driven by one shared ORCA solve per environment and step.
The robot is commanded either by discrete action indices (the 81-action table) or by continuous
velocity commands (planners such as ORCA).

The hot path of ``World.step`` (robot velocity, preferred velocities, the ORCA solve of all humans,
the swept collision test, integration, outcome and reward) runs in one Numba kernel that loops
over environments; Python only validates arguments, respawns humans that arrived (an option) and
builds the ``StepResult``. ``point_to_segment_distance`` and ``compute_reward`` are the numpy
definitions of the collision distance and of the reward; the kernel inlines the same arithmetic
(``tests/test_world_kernel.py`` checks it against a numpy reference step).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from crowdplan.config import WorldConfig
from crowdplan.sim import orca, scenarios
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
    # The same operations, in the same order, as the step kernel's inlined version.
    sx, sy = start[..., 0], start[..., 1]
    seg = end - start
    gx, gy = seg[..., 0], seg[..., 1]
    seg_len_sq = gx * gx + gy * gy
    with np.errstate(invalid="ignore", divide="ignore"):
        u = np.where(seg_len_sq > 0, -(sx * gx + sy * gy) / seg_len_sq, 0.0)
    u = np.clip(u, 0.0, 1.0)
    x, y = sx + u * gx, sy + u * gy
    return np.sqrt(x * x + y * y)


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


# Layout of the parameter vectors handed to the step kernel (built once per World).
_F_DT, _F_ROBOT_RADIUS, _F_ROBOT_V_PREF, _F_DISCOMFORT, _F_RADIUS_PAD = 0, 1, 2, 3, 4
_F_NEIGHBOR_DIST, _F_TIME_HORIZON = 5, 6
_I_MAX_NEIGHBORS, _I_MAX_STEPS, _I_UNICYCLE, _I_VISIBLE, _I_RESPAWN = 0, 1, 2, 3, 4


def _make_step_kernel(orca_version: int):
    """Compile (or load from Numba's cache) the step kernel for this version of ``orca.py``.

    The kernel calls ``orca._orca_kernel``, but Numba keys its cache only on the file of the cached
    function itself, so a changed ``orca.py`` would leave a stale ORCA solve inside a cached step
    kernel. The hash of ``orca.py`` is therefore a closure variable of the kernel, and closure
    variables are part of the cache key. ``error_model="numpy"``: float division by zero gives
    inf / nan (as in numpy) instead of raising.
    """

    @numba.njit(cache=True, error_model="numpy")
    def step_kernel(
        discrete: bool,
        action_idx: np.ndarray,
        commands: np.ndarray,
        table: np.ndarray,
        table_vel: np.ndarray,
        active: np.ndarray,
        robot_pos: np.ndarray,
        robot_vel: np.ndarray,
        robot_theta: np.ndarray,
        robot_goal: np.ndarray,
        start_dist: np.ndarray,
        steps: np.ndarray,
        human_pos: np.ndarray,
        human_vel: np.ndarray,
        human_goal: np.ndarray,
        human_radius: np.ndarray,
        human_v_pref: np.ndarray,
        fparams: np.ndarray,
        iparams: np.ndarray,
        out_robot_pos: np.ndarray,
        out_robot_vel: np.ndarray,
        out_robot_theta: np.ndarray,
        out_human_pos: np.ndarray,
        out_human_vel: np.ndarray,
        out_steps: np.ndarray,
        reward: np.ndarray,
        outcome: np.ndarray,
        d_min: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
        arrived: np.ndarray,
    ) -> int:
        """One step of every environment; the new state goes to the ``out_*`` arrays.

        ``action_idx`` (E,) or (1,) holds action indices into ``table`` when ``discrete``, otherwise
        ``commands`` (E, 2) holds velocity commands. Returns -1 (and writes nothing) when an action
        index is out of range, else the number of humans flagged in ``arrived`` (E, N) (only with
        respawn_on_arrival). The arithmetic follows the numpy definitions of this module
        (``preferred_velocities``, ``point_to_segment_distance``, ``compute_reward``) operation by
        operation, so that both give the same floats.
        """
        _ = orca_version  # a closure variable: part of the cache key (see _make_step_kernel)
        n_env, n_hum = human_pos.shape[0], human_pos.shape[1]
        dt = fparams[_F_DT]
        robot_radius = fparams[_F_ROBOT_RADIUS]
        robot_v_pref = fparams[_F_ROBOT_V_PREF]
        discomfort_dist = fparams[_F_DISCOMFORT]
        radius_pad = fparams[_F_RADIUS_PAD]
        max_steps = iparams[_I_MAX_STEPS]
        unicycle = iparams[_I_UNICYCLE] != 0
        visible = iparams[_I_VISIBLE] != 0
        respawn = iparams[_I_RESPAWN] != 0

        if discrete:
            for k in range(action_idx.shape[0]):
                if action_idx[k] < 0 or action_idx[k] >= table.shape[0]:
                    return -1
        broadcast_action = action_idx.shape[0] == 1

        # ORCA inputs of all agents; with visible_robot the robot is agent 0 of its environment (a
        # neighbour with its current velocity, never solved).
        off = 1 if visible else 0
        n_agents = n_hum + off
        pos = np.empty((n_env, n_agents, 2))
        vel = np.empty((n_env, n_agents, 2))
        pref = np.zeros((n_env, n_agents, 2))
        rad = np.empty((n_env, n_agents))
        vmax = np.empty((n_env, n_agents))
        seen = np.ones((n_env, n_agents), dtype=np.bool_)
        solve = np.empty((n_env, n_agents), dtype=np.bool_)
        new_vel = np.empty((n_env, n_agents, 2))
        for e in range(n_env):
            if visible:
                pos[e, 0, 0] = robot_pos[e, 0]
                pos[e, 0, 1] = robot_pos[e, 1]
                vel[e, 0, 0] = robot_vel[e, 0]
                vel[e, 0, 1] = robot_vel[e, 1]
                pref[e, 0, 0] = robot_vel[e, 0]
                pref[e, 0, 1] = robot_vel[e, 1]
                rad[e, 0] = robot_radius + radius_pad
                vmax[e, 0] = robot_v_pref
                solve[e, 0] = False
            for h in range(n_hum):
                a = h + off
                px = human_pos[e, h, 0]
                py = human_pos[e, h, 1]
                pos[e, a, 0] = px
                pos[e, a, 1] = py
                vel[e, a, 0] = human_vel[e, h, 0]
                vel[e, a, 1] = human_vel[e, h, 1]
                rad[e, a] = human_radius[e, h] + radius_pad
                speed = human_v_pref[e, h]
                vmax[e, a] = speed
                solve[e, a] = active[e]
                if active[e]:
                    # preferred_velocities: goal - position, shortened to speed if longer.
                    gx = human_goal[e, h, 0] - px
                    gy = human_goal[e, h, 1] - py
                    norm = np.sqrt(gx * gx + gy * gy)
                    scale = 1.0
                    if norm > speed:
                        scale = speed / (norm if norm > 0.0 else 1.0)
                    pref[e, a, 0] = gx * scale
                    pref[e, a, 1] = gy * scale
        orca._orca_kernel(
            pos,
            vel,
            rad,
            pref,
            vmax,
            seen,
            solve,
            dt,
            fparams[_F_NEIGHBOR_DIST],
            iparams[_I_MAX_NEIGHBORS],
            fparams[_F_TIME_HORIZON],
            new_vel,
        )

        n_arrived = 0
        for e in range(n_env):
            # Robot velocity (World.robot_velocity), computed for inactive environments too: their
            # d_min is reported with it.
            k = 0
            if discrete:
                k = action_idx[0 if broadcast_action else e]
                speed = table[k, 0]
                angle = table[k, 1]
            elif unicycle:
                speed = commands[e, 0]
                angle = commands[e, 1]
            else:
                speed = np.hypot(commands[e, 0], commands[e, 1])
                if speed > robot_v_pref:
                    speed = robot_v_pref
                angle = np.arctan2(commands[e, 1], commands[e, 0])
            if unicycle:
                theta = robot_theta[e] + angle
                heading = theta
            else:
                theta = robot_theta[e]
                heading = angle
            if discrete and not unicycle:
                rvx = table_vel[k, 0]  # speed * cos(angle) of the action, precomputed
                rvy = table_vel[k, 1]
            else:
                rvx = speed * np.cos(heading)
                rvy = speed * np.sin(heading)
            rpx = robot_pos[e, 0]
            rpy = robot_pos[e, 1]

            # Swept collision test (point_to_segment_distance of the human's motion relative to the
            # robot during dt, minus both radii); min over humans, inf without humans.
            dmin = np.inf
            nan_gap = False
            for h in range(n_hum):
                sx = human_pos[e, h, 0] - rpx
                sy = human_pos[e, h, 1] - rpy
                ex = sx + (new_vel[e, h + off, 0] - rvx) * dt
                ey = sy + (new_vel[e, h + off, 1] - rvy) * dt
                segx = ex - sx
                segy = ey - sy
                seg_len_sq = segx * segx + segy * segy
                u = -(sx * segx + sy * segy) / seg_len_sq
                u = u if seg_len_sq > 0 else 0.0
                # Branch-free clip to [0, 1] and running minimum (data-dependent branches here were
                # mispredicted often); min/max keep a NaN first operand, as np.clip does.
                u = min(max(u, 0.0), 1.0)
                cx = sx + u * segx
                cy = sy + u * segy
                gap = np.sqrt(cx * cx + cy * cy) - human_radius[e, h] - robot_radius
                dmin = min(dmin, gap)
                nan_gap |= gap != gap
            d_min[e] = np.nan if nan_gap else dmin  # np.min propagates NaN

            if active[e]:
                rpx = rpx + rvx * dt
                rpy = rpy + rvy * dt
                out_robot_vel[e, 0] = rvx
                out_robot_vel[e, 1] = rvy
                out_robot_theta[e] = theta
                for h in range(n_hum):
                    hvx = new_vel[e, h + off, 0]
                    hvy = new_vel[e, h + off, 1]
                    out_human_pos[e, h, 0] = human_pos[e, h, 0] + hvx * dt
                    out_human_pos[e, h, 1] = human_pos[e, h, 1] + hvy * dt
                    out_human_vel[e, h, 0] = hvx
                    out_human_vel[e, h, 1] = hvy
                out_steps[e] = steps[e] + 1
            else:
                out_robot_vel[e, 0] = robot_vel[e, 0]
                out_robot_vel[e, 1] = robot_vel[e, 1]
                out_robot_theta[e] = robot_theta[e]
                for h in range(n_hum):
                    out_human_pos[e, h, 0] = human_pos[e, h, 0]
                    out_human_pos[e, h, 1] = human_pos[e, h, 1]
                    out_human_vel[e, h, 0] = human_vel[e, h, 0]
                    out_human_vel[e, h, 1] = human_vel[e, h, 1]
                out_steps[e] = steps[e]
            out_robot_pos[e, 0] = rpx
            out_robot_pos[e, 1] = rpy

            # Outcome (collision > goal > timeout) and reward (compute_reward), zero when inactive.
            code = RUNNING
            r = 0.0
            if active[e]:
                gdx = robot_goal[e, 0] - rpx
                gdy = robot_goal[e, 1] - rpy
                goal_dist = np.sqrt(gdx * gdx + gdy * gdy)
                if dmin < 0:
                    code = COLLISION
                    r = REWARD_COLLISION
                elif goal_dist < robot_radius:
                    code = GOAL
                    r = REWARD_GOAL
                elif out_steps[e] >= max_steps:
                    code = TIMEOUT
                    r = TIMEOUT_REWARD_SCALE * (start_dist[e] - goal_dist) / start_dist[e]
                elif dmin > 0 and dmin < discomfort_dist:
                    r = (dmin - discomfort_dist) * DISCOMFORT_SCALE
            outcome[e] = code
            reward[e] = r
            terminated[e] = code in (GOAL, COLLISION)
            truncated[e] = code == TIMEOUT

            if respawn:
                for h in range(n_hum):
                    flag = False
                    if active[e]:
                        gdx = human_goal[e, h, 0] - out_human_pos[e, h, 0]
                        gdy = human_goal[e, h, 1] - out_human_pos[e, h, 1]
                        flag = np.sqrt(gdx * gdx + gdy * gdy) < human_radius[e, h]
                    arrived[e, h] = flag
                    n_arrived += flag
        return n_arrived

    return step_kernel


_step_kernel = _make_step_kernel(
    int.from_bytes(hashlib.sha256(Path(orca.__file__).read_bytes()).digest()[:7], "little")
)


@numba.njit(cache=True)
def _observe_kernel(
    robot_pos: np.ndarray,
    robot_vel: np.ndarray,
    robot_goal: np.ndarray,
    robot_theta: np.ndarray,
    human_pos: np.ndarray,
    human_vel: np.ndarray,
    human_radius: np.ndarray,
    robot_radius: float,
    robot_v_pref: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fresh observation arrays: robot (E, 9), humans (E, N, 5), mask (E, N)."""
    n_env, n_hum = human_pos.shape[0], human_pos.shape[1]
    robot = np.empty((n_env, 9))
    humans = np.empty((n_env, n_hum, 5))
    for e in range(n_env):
        robot[e, 0] = robot_pos[e, 0]
        robot[e, 1] = robot_pos[e, 1]
        robot[e, 2] = robot_vel[e, 0]
        robot[e, 3] = robot_vel[e, 1]
        robot[e, 4] = robot_radius
        robot[e, 5] = robot_goal[e, 0]
        robot[e, 6] = robot_goal[e, 1]
        robot[e, 7] = robot_v_pref
        robot[e, 8] = robot_theta[e]
        for h in range(n_hum):
            humans[e, h, 0] = human_pos[e, h, 0]
            humans[e, h, 1] = human_pos[e, h, 1]
            humans[e, h, 2] = human_vel[e, h, 0]
            humans[e, h, 3] = human_vel[e, h, 1]
            humans[e, h, 4] = human_radius[e, h]
    return robot, humans, np.ones((n_env, n_hum), dtype=np.bool_)


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
        # Kernel parameters (the config is frozen) and buffers.
        fparams = np.empty(7)
        fparams[_F_DT] = config.dt
        fparams[_F_ROBOT_RADIUS] = config.robot_radius
        fparams[_F_ROBOT_V_PREF] = config.robot_v_pref
        fparams[_F_DISCOMFORT] = config.discomfort_dist
        fparams[_F_RADIUS_PAD] = config.orca.radius_pad
        fparams[_F_NEIGHBOR_DIST] = config.orca.neighbor_dist
        fparams[_F_TIME_HORIZON] = config.orca.time_horizon
        iparams = np.empty(5, dtype=np.int64)
        iparams[_I_MAX_NEIGHBORS] = config.orca.max_neighbors
        iparams[_I_MAX_STEPS] = config.max_steps
        iparams[_I_UNICYCLE] = config.kinematics == "unicycle"
        iparams[_I_VISIBLE] = config.visible_robot
        iparams[_I_RESPAWN] = config.respawn_on_arrival and n > 0
        self._fparams, self._iparams = fparams, iparams
        # Holonomic world-frame velocity of each action (unicycle actions depend on the heading).
        speed, angle = self.actions[:, 0], self.actions[:, 1]
        self._action_vel = np.stack([speed * np.cos(angle), speed * np.sin(angle)], axis=1)
        self._all_active = np.ones(e, dtype=bool)
        self._no_actions = np.zeros(0, dtype=np.int64)
        self._no_commands = np.zeros((0, 2))
        self._arrived = np.zeros((e, n), dtype=bool)

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
        """Raw observation: robot (E, 9), humans (E, N, 5), mask (E, N) (all humans are real).

        Robot rows are (px, py, vx, vy, radius, gx, gy, v_pref, theta), human rows
        (px, py, vx, vy, radius); the arrays are new on every call.
        """
        return _observe_kernel(
            self.robot_pos,
            self.robot_vel,
            self.robot_goal,
            self.robot_theta,
            self.human_pos,
            self.human_vel,
            self.human_radius,
            self.config.robot_radius,
            self.config.robot_v_pref,
        )

    # ------------------------------------------------------------------ step
    def robot_velocity(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-frame robot velocity and new heading for discrete actions (E,) or commands (E, 2).

        Commands are world-frame (vx, vy) for holonomic robots (clipped to v_pref) and
        (speed, rotation) for unicycle robots. (The numpy statement of what ``step`` does inside
        its kernel.)
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
        """New human velocities from one shared ORCA solve per environment.

        (The numpy statement of what ``step`` does inside its kernel.)
        """
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
            actions: (E,) integer action indices in 0..80, or (E, 2) float velocity commands
                (see ``robot_velocity``).
            active: (E,) bool, default all.

        The state arrays are replaced by new ones (arrays obtained before the step keep the old
        state).
        """
        e, n = self.num_envs, self.config.humans
        if active is None:
            active = self._all_active
        else:
            active = np.asarray(active, dtype=bool)
            if active.shape != (e,) or not active.flags.c_contiguous:
                active = np.ascontiguousarray(np.broadcast_to(active, (e,)))
        actions = np.asarray(actions)
        if actions.dtype.kind in "iu" or actions.ndim == 1:
            if actions.dtype.kind not in "iu":
                check_actions(actions)  # raises: not integers
            if actions.ndim != 1 or actions.shape[0] not in (e, 1):
                raise ValueError(f"action indices must have shape ({e},), got {actions.shape}")
            discrete, action_idx, commands = True, actions, self._no_commands
            if actions.dtype != np.int64 or not actions.flags.c_contiguous:
                action_idx = actions.astype(np.int64)
        else:
            if actions.shape != (e, 2):
                raise ValueError(f"velocity commands must have shape ({e}, 2), got {actions.shape}")
            discrete, action_idx = False, self._no_actions
            commands = np.ascontiguousarray(actions, dtype=np.float64)

        robot_pos, robot_vel, robot_theta = np.empty((e, 2)), np.empty((e, 2)), np.empty(e)
        human_pos, human_vel = np.empty((e, n, 2)), np.empty((e, n, 2))
        steps = np.empty(e, dtype=np.int64)
        reward, outcome, d_min = np.empty(e), np.empty(e, dtype=np.int64), np.empty(e)
        terminated, truncated = np.empty(e, dtype=bool), np.empty(e, dtype=bool)
        n_arrived = _step_kernel(
            discrete,
            action_idx,
            commands,
            self.actions,
            self._action_vel,
            active,
            self.robot_pos,
            self.robot_vel,
            self.robot_theta,
            self.robot_goal,
            self.start_dist,
            self.steps,
            self.human_pos,
            self.human_vel,
            self.human_goal,
            self.human_radius,
            self.human_v_pref,
            self._fparams,
            self._iparams,
            robot_pos,
            robot_vel,
            robot_theta,
            human_pos,
            human_vel,
            steps,
            reward,
            outcome,
            d_min,
            terminated,
            truncated,
            self._arrived,
        )
        if n_arrived < 0:  # an action index out of range; nothing was written
            check_actions(actions)  # raises, naming the index
            raise ValueError("action index outside the valid range")
        self.robot_pos, self.robot_vel, self.robot_theta = robot_pos, robot_vel, robot_theta
        self.human_pos, self.human_vel, self.steps = human_pos, human_vel, steps
        if n_arrived:
            self._respawn_arrived()
        return StepResult(
            reward=reward, terminated=terminated, truncated=truncated, outcome=outcome, d_min=d_min
        )

    def _respawn_arrived(self) -> None:
        """New goals for the humans that the step kernel flagged as arrived (active envs only)."""
        for env, human in zip(*np.nonzero(self._arrived), strict=True):
            self.human_goal[env, human] = scenarios.respawn_goal(
                self.config,
                self._rngs[env],
                self.human_pos[env, human],
                self.human_v_pref[env, human],
            )
