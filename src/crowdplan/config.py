"""Typed configuration of the world; defaults follow SPEC.md sections 1-2 (CrowdNav / LSA-DSAC).

Every field is validated in ``__post_init__`` so that a bad value fails early with a message that
names the parameter and its valid range.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

SCENARIOS = ("circle_crossing", "square_crossing")
KINEMATICS = ("holonomic", "unicycle")
SPEED_SAMPLINGS = ("linear", "exponential")


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ValueError(message)


def _positive(name: str, value: float) -> None:
    _require(
        isinstance(value, (int, float)) and value > 0,
        f"{name} must be a positive number, got {value!r}",
    )


@dataclass(frozen=True)
class OrcaConfig:
    """ORCA parameters of the humans (SPEC.md section 1, CrowdNav defaults)."""

    neighbor_dist: float = 10.0
    max_neighbors: int = 10
    time_horizon: float = 5.0
    time_horizon_obst: float = 5.0
    max_speed: float = 1.0
    radius_pad: float = 0.01  # ORCA radius = body radius + pad (CrowdNav)

    def __post_init__(self) -> None:
        _positive("orca.neighbor_dist", self.neighbor_dist)
        _require(
            isinstance(self.max_neighbors, int) and self.max_neighbors >= 1,
            f"orca.max_neighbors must be an integer >= 1, got {self.max_neighbors!r}",
        )
        _positive("orca.time_horizon", self.time_horizon)
        _positive("orca.time_horizon_obst", self.time_horizon_obst)
        _positive("orca.max_speed", self.max_speed)
        _require(self.radius_pad >= 0, f"orca.radius_pad must be >= 0, got {self.radius_pad!r}")


@dataclass(frozen=True)
class WorldConfig:
    """Everything that defines an episode besides its seed.

    Attributes:
        scenario: "circle_crossing" (training) or "square_crossing" (transfer).
        humans: number of humans N (>= 0).
        dt: simulation time step in seconds (0.25).
        time_limit: episode length in seconds (25 s = 100 steps).
        robot_radius, robot_v_pref: robot disc radius and preferred speed.
        human_radius, human_v_pref: human disc radius and preferred speed.
        randomize_attributes: draw human v_pref in [0.5, 1.5] and radius in [0.3, 0.5].
        visible_robot: humans see (and avoid) the robot with ORCA.
        respawn_on_arrival: a human that reached its goal gets a new goal.
        kinematics: "holonomic" (world-frame velocity commands) or "unicycle".
        speed_sampling: "linear" {0.2..1.0} * v_pref (paper) or "exponential" (CrowdNav).
        circle_radius: radius R of circle_crossing (4 m).
        square_width: side W of square_crossing (10 m).
        discomfort_dist: distance below which the discomfort penalty applies (0.2 m).
        placement_tries: rejection-sampling attempts per human before giving up.
        orca: ORCA parameters of the humans.
    """

    scenario: str = "circle_crossing"
    humans: int = 5
    dt: float = 0.25
    time_limit: float = 25.0
    robot_radius: float = 0.3
    robot_v_pref: float = 1.0
    human_radius: float = 0.3
    human_v_pref: float = 1.0
    randomize_attributes: bool = False
    visible_robot: bool = False
    respawn_on_arrival: bool = False
    kinematics: str = "holonomic"
    speed_sampling: str = "linear"
    circle_radius: float = 4.0
    square_width: float = 10.0
    discomfort_dist: float = 0.2
    placement_tries: int = 1000
    orca: OrcaConfig = field(default_factory=OrcaConfig)

    def __post_init__(self) -> None:
        _require(
            self.scenario in SCENARIOS,
            f"scenario must be one of {SCENARIOS}, got {self.scenario!r}",
        )
        _require(
            isinstance(self.humans, int) and not isinstance(self.humans, bool) and self.humans >= 0,
            f"humans must be an integer >= 0, got {self.humans!r}",
        )
        for name in (
            "dt",
            "time_limit",
            "robot_radius",
            "robot_v_pref",
            "human_radius",
            "human_v_pref",
            "circle_radius",
            "square_width",
        ):
            _positive(name, getattr(self, name))
        _require(
            self.discomfort_dist >= 0,
            f"discomfort_dist must be >= 0, got {self.discomfort_dist!r}",
        )
        _require(
            self.kinematics in KINEMATICS,
            f"kinematics must be one of {KINEMATICS}, got {self.kinematics!r}",
        )
        _require(
            self.speed_sampling in SPEED_SAMPLINGS,
            f"speed_sampling must be one of {SPEED_SAMPLINGS}, got {self.speed_sampling!r}",
        )
        _require(
            isinstance(self.placement_tries, int) and self.placement_tries >= 1,
            f"placement_tries must be an integer >= 1, got {self.placement_tries!r}",
        )
        if isinstance(self.orca, dict):
            object.__setattr__(self, "orca", OrcaConfig(**self.orca))

    @property
    def max_steps(self) -> int:
        """Number of steps before the episode is truncated (100 by default)."""
        return int(round(self.time_limit / self.dt))

    def replace(self, **changes: Any) -> WorldConfig:
        """Return a copy with some fields changed (validated again)."""
        return _from_dict(type(self), {**dataclasses.asdict(self), **changes}, "world")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> WorldConfig:
        """Build from a plain dict (YAML), rejecting unknown keys by name."""
        return _from_dict(cls, data, "world")


def _from_dict(cls: type, data: dict[str, Any], where: str) -> Any:
    if not isinstance(data, dict):
        raise ValueError(f"{where} must be a mapping, got {type(data).__name__}")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(
            f"unknown option(s) {unknown} in {where}; valid options are {sorted(known)}"
        )
    return cls(**data)


def to_dict(obj: Any) -> dict[str, Any]:
    """Dataclass (nested) -> plain dict suitable for YAML/JSON."""
    return dataclasses.asdict(obj)
