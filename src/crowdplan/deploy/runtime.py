"""The host loop of a deployment (SPEC.md section 8), numpy + onnxruntime only.

At the control rate the caller feeds the latest timestamped poses of every tracked agent
(:meth:`Runtime.pose` / :meth:`Runtime.frame`) and asks for commands (:meth:`Runtime.step`):

- robots (role "robot") share one exported policy; each sees every other agent (humans, the
  other robots, obstacle robots) as a human, builds its raw observation from the estimated
  velocities, and gets the greedy action as a velocity command for its drive;
- obstacle robots (role "obstacle") are driven by the project's ORCA towards their goals, seeing
  every other agent;
- humans (role "human") are only observed.

Safety: a robot or obstacle robot whose own pose or any neighbour's pose is missing, older than
``max_pose_age``, not finite, not newer than the previous one or jumping faster than
``max_jump_speed`` gets a stop command with the reason, logged once per change of reason. So
does a robot with more neighbours than the export was checked for. Unknown ids, duplicate ids in
one frame and malformed samples are logged and dropped; nothing raises out of the loop.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from crowdplan.config import OrcaConfig
from crowdplan.deploy.drive import (
    DRIVES,
    Command,
    Limits,
    diff_drive_command,
    holonomic_command,
    wrap,
)
from crowdplan.deploy.onnx_policy import OnnxPolicy
from crowdplan.deploy.velocity import VelocityEstimator
from crowdplan.sim.orca import orca_velocities, preferred_velocities

ROLES = ("robot", "obstacle", "human")
log = logging.getLogger("crowdplan.deploy")


@dataclass(frozen=True)
class Agent:
    """One tracked agent: its id (as the pose source names it), role, disc radius, preferred
    speed, goal (robots and obstacle robots), drive and command limits."""

    id: str
    role: str = "human"
    radius: float = 0.3
    v_pref: float = 1.0
    goal: tuple[float, float] | None = None
    drive: str = "holonomic"
    limits: Limits = field(default_factory=Limits)

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise ValueError(f"agent {self.id!r}: role must be one of {ROLES}, got {self.role!r}")
        if self.drive not in DRIVES:
            raise ValueError(f"agent {self.id!r}: drive must be one of {DRIVES}")
        if not (self.radius > 0 and self.v_pref > 0):
            raise ValueError(f"agent {self.id!r}: radius and v_pref must be > 0")


@dataclass(frozen=True)
class RuntimeConfig:
    """Loop settings.

    Attributes:
        control_rate: commands per second (Hz); one period is the time a command is held.
        max_pose_age: poses older than this (s) are stale.
        max_jump_speed: a pose implying a faster motion (m/s) since the last one is a jump.
        velocity_tau: time constant (s) of the velocity filter (0: plain finite differences).
        goal_tolerance: a robot closer than this to its goal stops (None: its radius).
        orca: ORCA parameters of the obstacle robots.
    """

    control_rate: float = 4.0
    max_pose_age: float = 0.5
    max_jump_speed: float = 5.0
    velocity_tau: float = 0.0
    goal_tolerance: float | None = None
    orca: OrcaConfig = field(default_factory=OrcaConfig)

    def __post_init__(self) -> None:
        for name in ("control_rate", "max_pose_age", "max_jump_speed"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")

    @property
    def period(self) -> float:
        """Seconds between two commands."""
        return 1.0 / self.control_rate


class Runtime:
    """Poses in, velocity commands out, for robots sharing one policy and ORCA obstacle robots.

    Args:
        policy: the exported policy of the robots (None if there are no robots).
        agents: every tracked agent; ids must be unique.
        config: loop settings.
    """

    def __init__(
        self,
        policy: OnnxPolicy | None,
        agents: Iterable[Agent],
        config: RuntimeConfig | None = None,
    ):
        self.config = config or RuntimeConfig()
        agents = list(agents)
        self.agents = {a.id: a for a in agents}
        ids = [a.id for a in agents]
        if len(ids) != len(self.agents):
            raise ValueError(f"agent ids must be unique, got {ids}")
        self.robots = [a for a in self.agents.values() if a.role == "robot"]
        self.obstacles = [a for a in self.agents.values() if a.role == "obstacle"]
        if self.robots and policy is None:
            raise ValueError("robots need a policy (an export folder)")
        if policy is not None:
            for robot in self.robots:
                if robot.v_pref != policy.manifest.v_pref:
                    raise ValueError(
                        f"robot {robot.id!r} has v_pref {robot.v_pref} but the model was trained "
                        f"for {policy.manifest.v_pref}"
                    )
        self.policy = policy
        self.goals = {a.id: a.goal for a in self.agents.values()}
        # direction of each robot's trip, from where it was when it got its goal
        self.trip_heading: dict[str, float] = {}
        self.estimator = VelocityEstimator(self.config.velocity_tau, self.config.max_jump_speed)
        self.last = {a.id: Command() for a in self.agents.values()}
        self._reasons: dict[str, str] = {}
        self._warned: set[str] = set()

    # ------------------------------------------------------------------ input
    def pose(self, agent_id: object, t: object, x: object, y: object, yaw: object) -> bool:
        """Feed one timestamped pose (s, m, m, rad); returns whether it was accepted."""
        key = str(agent_id)
        if key not in self.agents:
            if key not in self._warned:
                self._warned.add(key)
                log.warning("ignoring poses of unknown agent %r", key)
            return False
        try:
            values = [float(v) for v in (t, x, y, yaw)]
        except (TypeError, ValueError):
            log.warning("malformed pose of %r dropped: %r", key, (t, x, y, yaw))
            return False
        reason = self.estimator.update(key, *values)
        if reason:
            log.warning("pose of %r rejected: %s", key, reason)
        return not reason

    def frame(self, t: float, poses: Iterable[object]) -> None:
        """Feed one mocap frame: ``(id, x, y, yaw)`` tuples stamped ``t``. An id that appears
        twice is ambiguous: both samples are dropped and the agent is marked faulty."""
        rows = []
        for row in poses:
            if isinstance(row, (tuple, list)) and len(row) == 4:
                rows.append(row)
            else:
                log.warning("malformed pose entry dropped: %r", row)
        ids = [str(row[0]) for row in rows]
        for row, key in zip(rows, ids, strict=True):
            if ids.count(key) > 1:
                track = self.estimator.tracks.get(key)
                if track is not None:
                    track.fault = "duplicate id in one frame"
                log.warning("agent %r appears %d times in one frame: dropped", key, ids.count(key))
                continue
            self.pose(key, t, *row[1:])

    def set_goal(self, agent_id: str, x: float, y: float) -> None:
        """Give a robot or obstacle robot a (new) goal."""
        if agent_id not in self.agents or self.agents[agent_id].role == "human":
            raise ValueError(f"{agent_id!r} is not a robot or obstacle robot")
        if not (math.isfinite(x) and math.isfinite(y)):
            raise ValueError(f"goal of {agent_id!r} must be finite, got {(x, y)}")
        self.goals[agent_id] = (float(x), float(y))
        self.trip_heading.pop(agent_id, None)

    # ------------------------------------------------------------------ state
    def problem(self, agent_id: str, now: float) -> str:
        """Why ``agent_id``'s pose cannot be used at ``now`` ("" if it can)."""
        track = self.estimator.tracks.get(agent_id)
        if track is None:
            return "no pose received"
        if track.fault:
            return track.fault
        age = now - track.t
        if age > self.config.max_pose_age:
            return f"pose is {age:.2f} s old"
        return ""

    def _stop_reason(self, agent: Agent, now: float) -> str:
        own = self.problem(agent.id, now)
        if own:
            return f"own pose: {own}"
        if self.goals[agent.id] is None:
            return "no goal"
        for other in self.agents:
            if other != agent.id:
                problem = self.problem(other, now)
                if problem:
                    return f"neighbour {other!r}: {problem}"
        return ""

    def _state(self, agent: Agent) -> tuple[float, float, float, float, float]:
        track = self.estimator.tracks[agent.id]
        return track.x, track.y, track.vx, track.vy, track.yaw

    # ------------------------------------------------------------------ output
    def step(self, now: float) -> dict[str, Command]:
        """Commands of every robot and obstacle robot for the poses received up to ``now``."""
        commands: dict[str, Command] = {}
        ready = {}
        for agent in (*self.robots, *self.obstacles):
            reason = self._stop_reason(agent, now)
            if agent.role == "robot" and not reason:
                n = len(self.agents) - 1
                if n > self.policy.max_humans:
                    reason = f"{n} neighbours; the model was exported for {self.policy.max_humans}"
            if reason:
                commands[agent.id] = Command(stop=True, reason=reason)
            else:
                ready[agent.id] = agent
        robots = [a for a in self.robots if a.id in ready]
        if robots:
            commands.update(self._robot_commands(robots))
        obstacles = [a for a in self.obstacles if a.id in ready]
        if obstacles:
            commands.update(self._obstacle_commands(obstacles))
        for key, command in commands.items():
            if command.reason != self._reasons.get(key, ""):
                if command.stop:
                    log.warning("stopping %r: %s", key, command.reason)
                else:
                    log.info("%r resumes", key)
                self._reasons[key] = command.reason
            self.last[key] = command
        return commands

    def _observation(self, robots: list[Agent]) -> tuple[np.ndarray, np.ndarray]:
        """Raw observations robot (E, 9) and humans (E, N, 5): everyone else is a human."""
        ids = list(self.agents)
        states = np.array([self._state(self.agents[i]) for i in ids], dtype=np.float64)
        radii = np.array([self.agents[i].radius for i in ids])
        rows_robot, rows_humans = [], []
        for agent in robots:
            k = ids.index(agent.id)
            x, y, vx, vy, yaw = states[k]
            gx, gy = self.goals[agent.id]
            rows_robot.append([x, y, vx, vy, agent.radius, gx, gy, agent.v_pref, yaw])
            others = [j for j in range(len(ids)) if j != k]
            rows_humans.append(np.column_stack([states[others, :4], radii[others]]))
        return np.array(rows_robot), np.array(rows_humans).reshape(len(robots), -1, 5)

    def _robot_commands(self, robots: list[Agent]) -> dict[str, Command]:
        robot, humans = self._observation(robots)
        mask = np.ones(humans.shape[:2], dtype=bool)
        actions = self.policy.act(robot, humans, mask).actions
        for k, agent in enumerate(robots):
            if agent.id not in self.trip_heading:
                dx, dy = robot[k, 5] - robot[k, 0], robot[k, 6] - robot[k, 1]
                self.trip_heading[agent.id] = math.atan2(dy, dx)
        trip = np.array([self.trip_heading[a.id] for a in robots])
        vel, theta = self.policy.velocities(actions, robot, trip)
        out = {}
        tolerance = self.config.goal_tolerance
        for k, agent in enumerate(robots):
            goal_dist = math.hypot(robot[k, 5] - robot[k, 0], robot[k, 6] - robot[k, 1])
            if goal_dist < (agent.radius if tolerance is None else tolerance):
                out[agent.id] = Command(reason="at goal")
                continue
            turn = None
            if self.policy.kinematics == "unicycle":
                turn = wrap(float(theta[k]) - robot[k, 8])
            out[agent.id] = self._shape(agent, vel[k], robot[k, 8], turn)
        return out

    def _obstacle_commands(self, obstacles: list[Agent]) -> dict[str, Command]:
        ids = list(self.agents)
        states = np.array([self._state(self.agents[i]) for i in ids], dtype=np.float64)
        solving = {a.id for a in obstacles}
        solve = np.array([i in solving for i in ids])
        speeds = np.array([self.agents[i].v_pref for i in ids])
        goals = np.array([self.goals[i] if solve[k] else (0.0, 0.0) for k, i in enumerate(ids)])
        pref = np.where(solve[:, None], preferred_velocities(states[:, :2], goals, speeds), 0.0)
        orca = self.config.orca
        vel = orca_velocities(
            states[None, :, :2],
            states[None, :, 2:4],
            np.array([self.agents[i].radius for i in ids])[None] + orca.radius_pad,
            pref[None],
            speeds[None],
            True,
            solve[None],
            self.config.period,
            orca.neighbor_dist,
            orca.max_neighbors,
            orca.time_horizon,
        )[0]
        return {
            i: self._shape(self.agents[i], vel[k], states[k, 4], None)
            for k, i in enumerate(ids)
            if solve[k]
        }

    def _shape(self, agent: Agent, vel: np.ndarray, yaw: float, turn: float | None) -> Command:
        period, last = self.config.period, self.last[agent.id]
        if agent.drive == "holonomic":
            return holonomic_command(float(vel[0]), float(vel[1]), last, agent.limits, period)
        return diff_drive_command(
            float(vel[0]), float(vel[1]), float(yaw), last, agent.limits, period, turn
        )
