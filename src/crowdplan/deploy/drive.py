"""Velocity commands for real robots: holonomic (vx, vy) or differential drive (v, omega), with
speed and acceleration limits.

Frames: the planner's velocities are in the world (mocap) frame. A holonomic command keeps them
in the world frame (``vx``, ``vy``); :func:`to_body` turns them into the robot's body frame (what
a ROS ``Twist`` carries). A differential-drive robot gets a forward speed ``v`` along its yaw and
a turn rate ``omega``: it turns towards the planned velocity within one control period and drives
forward with the part of the planned velocity along its heading (never backwards).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

DRIVES = ("holonomic", "diff_drive")


@dataclass(frozen=True)
class Limits:
    """Command limits; ``inf`` means unlimited.

    Attributes:
        max_speed: m/s. max_accel: m/s^2 (change of the commanded velocity per second).
        max_omega: rad/s. max_alpha: rad/s^2 (differential drive only).
    """

    max_speed: float = math.inf
    max_accel: float = math.inf
    max_omega: float = math.inf
    max_alpha: float = math.inf

    def __post_init__(self) -> None:
        for name in ("max_speed", "max_accel", "max_omega", "max_alpha"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)!r}")


@dataclass(frozen=True)
class Command:
    """One robot's command. Holonomic: world-frame ``vx``, ``vy``; differential drive: ``v``
    (forward, m/s) and ``omega`` (rad/s, counter-clockwise). ``stop`` with its ``reason`` marks
    a safety stop (all zero)."""

    vx: float = 0.0
    vy: float = 0.0
    v: float = 0.0
    omega: float = 0.0
    stop: bool = False
    reason: str = ""


def wrap(angle: float) -> float:
    """Angle in [-pi, pi)."""
    return (angle + math.pi) % (2 * math.pi) - math.pi


def to_body(vx: float, vy: float, yaw: float) -> tuple[float, float]:
    """World-frame velocity -> body frame (x forward, y left) of a robot with heading ``yaw``."""
    c, s = math.cos(yaw), math.sin(yaw)
    return vx * c + vy * s, vy * c - vx * s


def _step_towards(value: float, target: float, max_change: float) -> float:
    return value + max(-max_change, min(max_change, target - value))


def holonomic_command(
    vx: float, vy: float, last: Command, limits: Limits, period: float
) -> Command:
    """Clip the planned world velocity to the speed limit, then to the acceleration limit."""
    speed = math.hypot(vx, vy)
    if speed > limits.max_speed:
        vx, vy = vx * limits.max_speed / speed, vy * limits.max_speed / speed
    dvx, dvy = vx - last.vx, vy - last.vy
    change, max_change = math.hypot(dvx, dvy), limits.max_accel * period
    if change > max_change:
        vx, vy = last.vx + dvx * max_change / change, last.vy + dvy * max_change / change
    return Command(vx=vx, vy=vy)


def diff_drive_command(
    vx: float,
    vy: float,
    yaw: float,
    last: Command,
    limits: Limits,
    period: float,
    turn: float | None = None,
) -> Command:
    """Differential-drive command that follows a planned world velocity.

    ``turn``: the rotation to make this period (a unicycle model's action); default: turn
    towards the planned velocity (a holonomic model's action).
    """
    speed = math.hypot(vx, vy)
    if turn is None:
        turn = wrap(math.atan2(vy, vx) - yaw) if speed > 0 else 0.0
        v = speed * max(math.cos(turn), 0.0)
    else:
        v = speed
    omega = max(-limits.max_omega, min(limits.max_omega, turn / period))
    v = min(v, limits.max_speed)
    v = _step_towards(last.v, v, limits.max_accel * period)
    omega = _step_towards(last.omega, omega, limits.max_alpha * period)
    return Command(v=v, omega=omega)
