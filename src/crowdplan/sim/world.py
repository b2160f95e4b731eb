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
from crowdplan.sim import initial_state, orca, scenarios, socialforce
from crowdplan.sim.actions import action_table, action_velocities, check_actions

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
_F_SF_TAU, _F_SF_A, _F_SF_B, _F_SF_LAM, _F_SF_SPEED_FACTOR = 7, 8, 9, 10, 11
_I_MAX_NEIGHBORS, _I_MAX_STEPS, _I_UNICYCLE, _I_VISIBLE, _I_RESPAWN, _I_GOAL_FRAME = range(6)
# Kind codes (initial_state.HUMAN_KINDS) as module constants, for the kernel.
_SOCIAL_FORCE, _STATIC, _WAITING, _REPLAY = (
    initial_state.SOCIAL_FORCE,
    initial_state.STATIC,
    initial_state.WAITING,
    initial_state.REPLAY,
)


def _make_step_kernel(orca_version: int, social_force_version: int):
    """Compile (or load from Numba's cache) the step kernel for these versions of the solvers.

    The kernel calls ``orca._orca_kernel`` and ``socialforce._social_force_kernel``, but Numba
    keys its cache only on the file of the cached function itself, so a changed ``orca.py`` or
    ``socialforce.py`` would leave a stale solve inside a cached step kernel. The hashes of both
    files are therefore closure variables of the kernel, and closure variables are part of the
    cache key. ``error_model="numpy"``: float division by zero gives inf / nan (as in numpy)
    instead of raising.
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
        human_kind: np.ndarray,
        human_present: np.ndarray,
        human_wait: np.ndarray,
        track: np.ndarray,
        track_present: np.ndarray,
        fparams: np.ndarray,
        iparams: np.ndarray,
        out_robot_pos: np.ndarray,
        out_robot_vel: np.ndarray,
        out_robot_theta: np.ndarray,
        out_human_pos: np.ndarray,
        out_human_vel: np.ndarray,
        out_human_present: np.ndarray,
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
        (``action_velocities``, ``preferred_velocities``, ``point_to_segment_distance``,
        ``compute_reward``) operation by operation, so that both give the same floats. Absent
        humans (``human_present`` False) are neither seen, moved nor collided with.
        """
        _ = orca_version + social_force_version  # closure variables: part of the cache key
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
        goal_frame = iparams[_I_GOAL_FRAME] != 0
        last_frame = max(track.shape[2] - 1, 0)

        if discrete:
            for k in range(action_idx.shape[0]):
                if action_idx[k] < 0 or action_idx[k] >= table.shape[0]:
                    return -1
        broadcast_action = action_idx.shape[0] == 1

        # Inputs of the solvers for all agents; with visible_robot the robot is agent 0 of its
        # environment (a neighbour with its current velocity, never solved).
        off = 1 if visible else 0
        n_agents = n_hum + off
        pos = np.empty((n_env, n_agents, 2))
        vel = np.empty((n_env, n_agents, 2))
        pref = np.zeros((n_env, n_agents, 2))
        rad = np.empty((n_env, n_agents))
        body = np.empty((n_env, n_agents))
        vmax = np.empty((n_env, n_agents))
        sf_vmax = np.empty((n_env, n_agents))
        seen = np.ones((n_env, n_agents), dtype=np.bool_)
        solve = np.zeros((n_env, n_agents), dtype=np.bool_)
        sf_solve = np.zeros((n_env, n_agents), dtype=np.bool_)
        any_sf = False
        new_vel = np.zeros((n_env, n_agents, 2))
        for e in range(n_env):
            now = steps[e] * dt
            if visible:
                pos[e, 0, 0] = robot_pos[e, 0]
                pos[e, 0, 1] = robot_pos[e, 1]
                vel[e, 0, 0] = robot_vel[e, 0]
                vel[e, 0, 1] = robot_vel[e, 1]
                pref[e, 0, 0] = robot_vel[e, 0]
                pref[e, 0, 1] = robot_vel[e, 1]
                rad[e, 0] = robot_radius + radius_pad
                body[e, 0] = robot_radius
                vmax[e, 0] = robot_v_pref
                sf_vmax[e, 0] = robot_v_pref
            for h in range(n_hum):
                a = h + off
                px = human_pos[e, h, 0]
                py = human_pos[e, h, 1]
                pos[e, a, 0] = px
                pos[e, a, 1] = py
                vel[e, a, 0] = human_vel[e, h, 0]
                vel[e, a, 1] = human_vel[e, h, 1]
                rad[e, a] = human_radius[e, h] + radius_pad
                body[e, a] = human_radius[e, h]
                speed = human_v_pref[e, h]
                vmax[e, a] = speed
                sf_vmax[e, a] = speed * fparams[_F_SF_SPEED_FACTOR]
                kind = human_kind[e, h]
                present = human_present[e, h]
                seen[e, a] = present
                moving = active[e] and present and kind != _STATIC and kind != _REPLAY
                solve[e, a] = moving and kind != _SOCIAL_FORCE
                sf_solve[e, a] = moving and kind == _SOCIAL_FORCE
                any_sf |= sf_solve[e, a]
                waiting = kind == _WAITING and human_wait[e, h, 0] <= now < human_wait[e, h, 1]
                if moving and not waiting:
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
        if any_sf:
            socialforce._social_force_kernel(
                pos,
                vel,
                pref,
                body,
                sf_vmax,
                seen,
                sf_solve,
                dt,
                fparams[_F_SF_TAU],
                fparams[_F_SF_A],
                fparams[_F_SF_B],
                fparams[_F_SF_LAM],
                new_vel,
            )
        # Replayed humans of active environments move along their tracks (zero velocity where
        # they enter or leave); unsolved humans keep their velocity (0 for static and absent ones).
        for e in range(n_env):
            if not active[e]:
                continue
            next_k = min(steps[e] + 1, last_frame)
            for h in range(n_hum):
                if human_kind[e, h] == _REPLAY:
                    a = h + off
                    both = human_present[e, h] and track_present[e, h, next_k]
                    new_vel[e, a, 0] = (track[e, h, next_k, 0] - human_pos[e, h, 0]) / dt * both
                    new_vel[e, a, 1] = (track[e, h, next_k, 1] - human_pos[e, h, 1]) / dt * both

        n_arrived = 0
        for e in range(n_env):
            # Robot velocity (actions.action_velocities), computed for inactive environments too:
            # their d_min is reported with it.
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
            if discrete and not unicycle and not goal_frame:
                rvx = table_vel[k, 0]  # speed * cos(angle) of the action, precomputed
                rvy = table_vel[k, 1]
            else:
                if discrete and not unicycle:  # goal frame: headings from the goal direction
                    heading = angle + np.arctan2(
                        robot_goal[e, 1] - robot_pos[e, 1], robot_goal[e, 0] - robot_pos[e, 0]
                    )
                rvx = speed * np.cos(heading)
                rvy = speed * np.sin(heading)
            rpx = robot_pos[e, 0]
            rpy = robot_pos[e, 1]

            # Swept collision test (point_to_segment_distance of the human's motion relative to the
            # robot during dt, minus both radii); min over present humans, inf without any.
            dmin = np.inf
            nan_gap = False
            for h in range(n_hum):
                if not human_present[e, h]:
                    continue
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
                next_k = min(steps[e] + 1, last_frame)
                for h in range(n_hum):
                    hvx = new_vel[e, h + off, 0]
                    hvy = new_vel[e, h + off, 1]
                    out_human_vel[e, h, 0] = hvx
                    out_human_vel[e, h, 1] = hvy
                    out_human_present[e, h] = human_present[e, h]
                    if human_kind[e, h] == _REPLAY:
                        out_human_pos[e, h, 0] = track[e, h, next_k, 0]
                        out_human_pos[e, h, 1] = track[e, h, next_k, 1]
                        out_human_present[e, h] = track_present[e, h, next_k]
                    else:
                        out_human_pos[e, h, 0] = human_pos[e, h, 0] + hvx * dt
                        out_human_pos[e, h, 1] = human_pos[e, h, 1] + hvy * dt
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
                    out_human_present[e, h] = human_present[e, h]
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
                    kind = human_kind[e, h]
                    walks = kind != _STATIC and kind != _REPLAY and human_present[e, h]
                    if active[e] and walks:
                        gdx = human_goal[e, h, 0] - out_human_pos[e, h, 0]
                        gdy = human_goal[e, h, 1] - out_human_pos[e, h, 1]
                        flag = np.sqrt(gdx * gdx + gdy * gdy) < human_radius[e, h]
                    arrived[e, h] = flag
                    n_arrived += flag
        return n_arrived

    return step_kernel


def _file_version(path: str) -> int:
    return int.from_bytes(hashlib.sha256(Path(path).read_bytes()).digest()[:7], "little")


_step_kernel = _make_step_kernel(_file_version(orca.__file__), _file_version(socialforce.__file__))


@numba.njit(cache=True)
def _observe_kernel(
    robot_pos: np.ndarray,
    robot_vel: np.ndarray,
    robot_goal: np.ndarray,
    robot_theta: np.ndarray,
    human_pos: np.ndarray,
    human_vel: np.ndarray,
    human_radius: np.ndarray,
    human_present: np.ndarray,
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
    return robot, humans, human_present.copy()


class World:
    """State of E environments with N humans each, stepped in one call.

    Arrays (public, read-only for callers): ``robot_pos`` (E, 2), ``robot_vel`` (E, 2),
    ``robot_theta`` (E,), ``robot_goal`` (E, 2), ``human_pos`` / ``human_vel`` / ``human_goal``
    (E, N, 2), ``human_radius`` / ``human_v_pref`` (E, N), ``human_kind`` (E, N) (codes of
    ``initial_state.HUMAN_KINDS``), ``human_present`` (E, N) (absent humans are masked out of the
    observation and never collide), ``steps`` (E,), ``seeds`` (E,) (-1 for a scene given by
    ``reset_states``).
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
        self.human_kind = np.zeros((e, n), dtype=np.int64)
        self.human_present = np.ones((e, n), dtype=bool)
        self.human_wait = np.full((e, n, 2), np.inf)
        replays = config.scenario == "replay" or config.replay_fraction > 0
        frames = config.max_steps + 1 if replays else 1
        self.track = np.zeros((e, n, frames, 2))
        self.track_present = np.zeros((e, n, frames), dtype=bool)
        self.rotation = np.zeros(e)
        self.steps = np.zeros(e, dtype=np.int64)
        self.seeds = np.full(e, -1, dtype=np.int64)
        self._rngs: list[np.random.Generator | None] = [None] * e
        # Kernel parameters (the config is frozen) and buffers.
        fparams = np.empty(12)
        fparams[_F_DT] = config.dt
        fparams[_F_ROBOT_RADIUS] = config.robot_radius
        fparams[_F_ROBOT_V_PREF] = config.robot_v_pref
        fparams[_F_DISCOMFORT] = config.discomfort_dist
        fparams[_F_RADIUS_PAD] = config.orca.radius_pad
        fparams[_F_NEIGHBOR_DIST] = config.orca.neighbor_dist
        fparams[_F_TIME_HORIZON] = config.orca.time_horizon
        sf = config.social_force
        fparams[_F_SF_TAU], fparams[_F_SF_A], fparams[_F_SF_B] = sf.tau, sf.a, sf.b
        fparams[_F_SF_LAM], fparams[_F_SF_SPEED_FACTOR] = sf.lam, sf.max_speed_factor
        iparams = np.empty(6, dtype=np.int64)
        iparams[_I_MAX_NEIGHBORS] = config.orca.max_neighbors
        iparams[_I_MAX_STEPS] = config.max_steps
        iparams[_I_UNICYCLE] = config.kinematics == "unicycle"
        iparams[_I_VISIBLE] = config.visible_robot
        iparams[_I_RESPAWN] = config.respawn_on_arrival and n > 0
        iparams[_I_GOAL_FRAME] = config.action_frame == "goal"
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
        states = [scenarios.generate(self.config, seed) for seed in seeds]
        self.reset_states(states, env_ids)
        self.seeds[list(env_ids)] = seeds

    def reset_states(self, states: list[initial_state.InitialState], env_ids=None) -> None:
        """Start episodes from given initial states (the scenario protocol, docs/scenarios.md).

        Every state is checked first (a bad one raises and no environment is changed). A state
        with fewer humans than ``config.humans`` is padded with absent humans.
        """
        env_ids = range(self.num_envs) if env_ids is None else [int(i) for i in env_ids]
        if len(states) != len(env_ids):
            raise ValueError(f"got {len(states)} initial states for {len(env_ids)} environments")
        for state in states:
            check_state(state, self.config)
        for env, init in zip(env_ids, states, strict=True):
            k = init.humans
            self.robot_pos[env] = init.robot_pos
            self.robot_goal[env] = init.robot_goal
            self.robot_vel[env] = 0.0
            self.robot_theta[env] = init.heading()
            self.start_dist[env] = np.linalg.norm(init.robot_goal - init.robot_pos)
            self.human_vel[env] = 0.0
            if init.human_vel is not None:
                self.human_vel[env, :k] = init.human_vel
            self.human_pos[env, :k] = init.human_pos
            self.human_goal[env, :k] = init.human_goal
            self.human_radius[env, :k] = init.human_radius
            self.human_v_pref[env, :k] = init.human_v_pref
            self.human_kind[env, :k] = init.kinds()
            self.human_wait[env, :k] = init.waits()
            self.human_present[env, :k] = True
            # Padding: absent humans (masked out, never seen, moved or collided with).
            self.human_pos[env, k:] = self.human_goal[env, k:] = 0.0
            self.human_radius[env, k:] = self.config.human_radius
            self.human_v_pref[env, k:] = self.config.human_v_pref
            self.human_kind[env, k:] = initial_state.STATIC
            self.human_wait[env, k:] = np.inf
            self.human_present[env, k:] = False
            self.track[env] = 0.0
            self.track_present[env] = False
            if init.track is not None:
                self.track[env, :k] = init.track
                self.track_present[env, :k] = init.track_present
                replayed = init.kinds() == initial_state.REPLAY
                self.human_present[env, :k] = ~replayed | init.track_present[:, 0]
            self.rotation[env] = init.rotation
            self.steps[env] = 0
            self.seeds[env] = -1
            self._rngs[env] = init.rng

    def observe(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Raw observation: robot (E, 9), humans (E, N, 5), mask (E, N) (False: absent human).

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
            self.human_present,
            self.config.robot_radius,
            self.config.robot_v_pref,
        )

    # ------------------------------------------------------------------ step
    def robot_velocity(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """World-frame robot velocity and new heading for discrete actions (E,) or commands (E, 2).

        Discrete actions follow ``actions.action_velocities`` (in the configured action frame);
        commands are world-frame (vx, vy) for holonomic robots (clipped to v_pref) and
        (speed, rotation) for unicycle robots. (The numpy statement of what ``step`` does inside
        its kernel.)
        """
        actions = np.asarray(actions)
        if actions.dtype.kind in "iu" or actions.ndim == 1:
            cfg = self.config
            robot = self.observe()[0]
            actions = np.broadcast_to(check_actions(actions), (self.num_envs,))
            return action_velocities(
                actions, robot, cfg.kinematics, cfg.action_frame, cfg.speed_sampling
            )
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
        human_present = np.empty((e, n), dtype=bool)
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
            self.human_kind,
            self.human_present,
            self.human_wait,
            self.track,
            self.track_present,
            self._fparams,
            self._iparams,
            robot_pos,
            robot_vel,
            robot_theta,
            human_pos,
            human_vel,
            human_present,
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
        self.human_present = human_present
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
                self.rotation[env],
            )


def check_state(state: initial_state.InitialState, config: WorldConfig) -> None:
    """Refuse an initial state the world cannot play, naming the fix."""
    n = state.humans
    if n > config.humans:
        raise ValueError(
            f"the scene has {n} humans but the world was built for humans={config.humans}; "
            f"set humans to {n} or more"
        )
    shapes = {
        "robot_pos": (state.robot_pos, (2,)),
        "robot_goal": (state.robot_goal, (2,)),
        "human_pos": (state.human_pos, (n, 2)),
        "human_goal": (state.human_goal, (n, 2)),
        "human_radius": (state.human_radius, (n,)),
        "human_v_pref": (state.human_v_pref, (n,)),
        "human_kind": (state.kinds(), (n,)),
        "human_wait": (state.waits(), (n, 2)),
    }
    if state.human_vel is not None:
        shapes["human_vel"] = (state.human_vel, (n, 2))
    if state.track is not None:
        frames = config.max_steps + 1
        shapes["track"] = (state.track, (n, frames, 2))
        shapes["track_present"] = (state.track_present, (n, frames))
    for name, (value, shape) in shapes.items():
        if np.shape(value) != shape:
            raise ValueError(f"{name} must have shape {shape}, got {np.shape(value)}")
    kinds = state.kinds()
    if np.any((kinds < 0) | (kinds >= len(initial_state.HUMAN_KINDS))):
        raise ValueError(f"human_kind codes must be in 0..{len(initial_state.HUMAN_KINDS) - 1}")
    if np.any(kinds == initial_state.REPLAY) and state.track is None:
        raise ValueError("replayed humans (kind 'replay') need a track")
    if (
        np.any(kinds == initial_state.REPLAY)
        and config.scenario != "replay"
        and (config.replay_fraction == 0)
    ):
        raise ValueError(
            "this world holds no tracks: replayed humans need scenario 'replay' or replay_fraction"
        )
    if np.linalg.norm(state.robot_goal - state.robot_pos) < config.robot_radius:
        raise ValueError("the robot starts at its goal (closer than its radius)")
