"""Typed configuration: the world (SPEC.md sections 1-2) and the one strict loader of every config.

Every config dataclass checks its fields in ``__post_init__`` with :func:`check_fields` (type from
the annotation, range or choices from the field's metadata, see :func:`spec`), so a bad value fails
when the config is built, from YAML or from code, with a message that names the parameter and its
valid range. :func:`from_dict` builds any config dataclass from parsed YAML, refusing unknown keys.
"""

from __future__ import annotations

import dataclasses
import types
import typing
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
        check_fields(self, "orca")
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
        if isinstance(self.orca, dict):
            object.__setattr__(self, "orca", from_dict(OrcaConfig, self.orca, "world.orca"))
        check_fields(self, "world")
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

    @property
    def max_steps(self) -> int:
        """Number of steps before the episode is truncated (100 by default)."""
        return int(round(self.time_limit / self.dt))

    def replace(self, **changes: Any) -> WorldConfig:
        """Return a copy with some fields changed (validated again)."""
        return from_dict(type(self), {**dataclasses.asdict(self), **changes}, "world")

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> WorldConfig:
        """Build from a plain dict (YAML), rejecting unknown keys by name."""
        return from_dict(cls, data, "world")


# ---------------------------------------------------------------------- the strict loader
def spec(
    default: Any = dataclasses.MISSING,
    *,
    low: float | None = None,
    high: float | None = None,
    low_open: bool = False,
    choices: tuple[Any, ...] | None = None,
    default_factory: Any = dataclasses.MISSING,
) -> Any:
    """A dataclass field with its valid range (``low <= x <= high``; ``low < x`` with
    ``low_open``) or its valid choices, checked by :func:`check_fields`."""
    metadata = {"low": low, "high": high, "low_open": low_open, "choices": choices}
    return field(default=default, default_factory=default_factory, metadata=metadata)


def from_dict(cls: type, data: Any, where: str) -> Any:
    """Build the config dataclass ``cls`` from a plain mapping (parsed YAML).

    Unknown keys are refused by name; nested dataclass fields may be given as mappings; every
    value is then type- and range-checked by the class's own ``__post_init__``.
    """
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ValueError(f"{where} must be a mapping of keys to values, got {data!r}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ValueError(f"unknown key(s) {unknown} in {where}; valid keys are {sorted(fields)}")
    hints = typing.get_type_hints(cls)
    values = {}
    for name, value in data.items():
        hint = hints[name]
        if dataclasses.is_dataclass(hint) and isinstance(value, dict):
            value = from_dict(hint, value, f"{where}.{name}")
        values[name] = value
    return cls(**values)


def check_fields(obj: Any, where: str) -> None:
    """Check (and normalise: int -> float, list -> tuple) every field of a config dataclass.

    Raises ValueError naming ``where.field``, the expected type and the valid range.
    """
    hints = typing.get_type_hints(type(obj))
    for f in dataclasses.fields(obj):
        name = f"{where}.{f.name}"
        value = _checked_value(name, getattr(obj, f.name), hints[f.name])
        object.__setattr__(obj, f.name, value)
        low, high = f.metadata.get("low"), f.metadata.get("high")
        choices = f.metadata.get("choices")
        if choices is not None and value not in choices:
            raise ValueError(f"{name} must be one of {list(choices)}, got {value!r}")
        too_low = low is not None and (value <= low if f.metadata.get("low_open") else value < low)
        if too_low or (high is not None and value > high):
            raise ValueError(f"{name} must be {_range_text(f.metadata)}, got {value!r}")


def _range_text(metadata: Any) -> str:
    parts = []
    if metadata.get("low") is not None:
        parts.append(f"{'>' if metadata.get('low_open') else '>='} {metadata['low']}")
    if metadata.get("high") is not None:
        parts.append(f"<= {metadata['high']}")
    return " and ".join(parts)


def _checked_value(name: str, value: Any, hint: Any) -> Any:
    """``value`` converted to the annotation's type where that is lossless, else ValueError."""
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):
        options = [h for h in typing.get_args(hint) if h is not type(None)]
        if value is None and len(options) < len(typing.get_args(hint)):
            return None
        hint = options[0] if len(options) == 1 else hint
        origin = typing.get_origin(hint)
    if hint is bool:
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be true or false, got {value!r}")
    elif hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{name} must be an integer, got {value!r}")
    elif hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{name} must be a number, got {value!r}")
        return float(value)
    elif hint is str:
        if not isinstance(value, str):
            raise ValueError(f"{name} must be a string, got {value!r}")
    elif origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ValueError(f"{name} must be a list, got {value!r}")
        item_hint = typing.get_args(hint)[0]
        return tuple(_checked_value(f"{name}[{i}]", v, item_hint) for i, v in enumerate(value))
    elif dataclasses.is_dataclass(hint) and not isinstance(value, hint):
        raise ValueError(f"{name} must be a mapping of {hint.__name__} keys, got {value!r}")
    return value


def to_dict(obj: Any) -> dict[str, Any]:
    """Dataclass (nested) -> plain dict suitable for YAML/JSON."""
    return dataclasses.asdict(obj)
