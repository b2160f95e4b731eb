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

SCENARIOS = ("circle_crossing", "square_crossing", "replay", "custom")
KINEMATICS = ("holonomic", "unicycle")
ACTION_FRAMES = ("goal", "world")
REPLAY_SCENES = ("eth", "hotel", "zara1", "zara2", "univ")
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
class SocialForceConfig:
    """Social-force humans (Helbing & Molnar 1995; Helbing, Farkas & Vicsek 2000), per unit mass.

    Acceleration of human i: ``(v_pref * e_i - v_i) / tau`` towards its goal plus, for every other
    agent j, ``a * exp((r_i + r_j - d_ij) / b) * n_ji * w`` with ``n_ji`` the unit vector from j
    to i and the anisotropy ``w = lam + (1 - lam) * (1 + cos phi) / 2`` (phi: angle between i's
    desired direction and the direction to j). Speeds are capped at ``max_speed_factor * v_pref``.
    """

    tau: float = 0.5
    a: float = 2.1
    b: float = 0.3
    lam: float = 0.35
    max_speed_factor: float = 1.3

    def __post_init__(self) -> None:
        check_fields(self, "social_force")
        for name in ("tau", "a", "b", "max_speed_factor"):
            _positive(f"social_force.{name}", getattr(self, name))
        _require(0.0 <= self.lam <= 1.0, f"social_force.lam must be in [0, 1], got {self.lam!r}")


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
        circle_radius_min: when set, a circle_crossing episode with n of ``humans`` humans uses
            the radius max(circle_radius_min, circle_radius * sqrt(n / humans)): crowds keep the
            density (humans per disc area) of the full crowd at circle_radius, and small crowds
            keep at least circle_radius_min (e.g. the paper's 4 m with humans_min).
        square_width: side W of square_crossing (10 m).
        discomfort_dist: distance below which the discomfort penalty applies (0.2 m).
        placement_tries: rejection-sampling attempts per human before giving up.
        orca: ORCA parameters of the humans.
        action_frame: "goal" (holonomic action headings relative to the robot->goal direction;
            the default) or "world" (the paper's absolute headings); see ``sim/actions.py``.
        goal_rotation: the whole generated scene rotated by this many degrees about the origin.
        random_goal_direction: rotate each episode's scene by an angle drawn from its seed.
        humans_min: when set, each episode has N ~ U{humans_min..humans} humans (the others are
            absent: masked out and never collide).
        social_force_fraction, static_fraction, waiting_fraction: probability that a generated
            human is driven by the social force, stands still, or walks with ORCA but stops
            ``wait_after`` seconds into the episode for ``wait_for`` seconds (the rest are ORCA).
        plain_fraction: probability that a generated circle/square episode is plain: all its
            humans walk with ORCA at human_v_pref with human_radius (randomize_attributes and the
            kind fractions skip it; humans_min and circle_radius_min still apply), so that a
            mixture keeps rehearsing the nominal crowd it was fine-tuned from.
        replay_scenes: ETH/UCY scenes of the replay scenario (eth and hotel are for development
            and training; zara1, zara2 and univ are held out: measuring only).
        replay_min_humans: fewest replayed pedestrians near the robot's path in a replay case.
        replay_fraction: probability that a circle/square episode is a replay case instead.
        scenario_file: YAML scenario file of the "custom" scenario (docs/scenarios.md).
        social_force: parameters of social-force humans.
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
    circle_radius_min: float | None = None
    square_width: float = 10.0
    discomfort_dist: float = 0.2
    placement_tries: int = 1000
    orca: OrcaConfig = field(default_factory=OrcaConfig)
    action_frame: str = "goal"
    goal_rotation: float = 0.0
    random_goal_direction: bool = False
    humans_min: int | None = None
    social_force_fraction: float = 0.0
    static_fraction: float = 0.0
    waiting_fraction: float = 0.0
    plain_fraction: float = 0.0
    wait_after: float = 2.0
    wait_for: float = 5.0
    replay_scenes: tuple[str, ...] = ("eth", "hotel")
    replay_min_humans: int = 3
    replay_fraction: float = 0.0
    scenario_file: str | None = None
    social_force: SocialForceConfig = field(default_factory=SocialForceConfig)

    def paper_world(self) -> WorldConfig:
        """The default (the paper's) world with this world's robot: its kinematics, action frame
        and speed sampling (what ``--default-world`` evaluates a model in)."""
        own = ("kinematics", "action_frame", "speed_sampling")
        return WorldConfig(**{key: getattr(self, key) for key in own})

    def __post_init__(self) -> None:
        if isinstance(self.orca, dict):
            object.__setattr__(self, "orca", from_dict(OrcaConfig, self.orca, "world.orca"))
        if isinstance(self.social_force, dict):
            value = from_dict(SocialForceConfig, self.social_force, "world.social_force")
            object.__setattr__(self, "social_force", value)
        check_fields(self, "world")
        _require(
            isinstance(self.humans, int) and not isinstance(self.humans, bool) and self.humans >= 0,
            f"humans must be an integer >= 0, got {self.humans!r}",
        )
        self._check_generalization_options()
        _require(
            self.scenario in SCENARIOS,
            f"scenario must be one of {SCENARIOS}, got {self.scenario!r}",
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

    def _check_generalization_options(self) -> None:
        _require(
            self.action_frame in ACTION_FRAMES,
            f"action_frame must be one of {ACTION_FRAMES}, got {self.action_frame!r}",
        )
        _require(
            self.humans_min is None or 0 <= self.humans_min <= self.humans,
            f"humans_min must be between 0 and humans ({self.humans}), got {self.humans_min!r}",
        )
        fractions = ("social_force_fraction", "static_fraction", "waiting_fraction")
        for name in (*fractions, "plain_fraction", "replay_fraction"):
            value = getattr(self, name)
            _require(0.0 <= value <= 1.0, f"{name} must be in [0, 1], got {value!r}")
        total = sum(getattr(self, name) for name in fractions)
        _require(total <= 1.0, f"{' + '.join(fractions)} must be <= 1, got {total!r}")
        _require(
            self.circle_radius_min is None or 0 < self.circle_radius_min <= self.circle_radius,
            f"circle_radius_min must be in (0, circle_radius = {self.circle_radius}], "
            f"got {self.circle_radius_min!r}",
        )
        _require(
            self.circle_radius_min is None or not self.respawn_on_arrival,
            "circle_radius_min and respawn_on_arrival do not combine (a respawned goal is drawn "
            "on circle_radius, not on the episode's own radius): drop one of them",
        )
        _require(self.wait_after >= 0, f"wait_after must be >= 0, got {self.wait_after!r}")
        _require(self.wait_for >= 0, f"wait_for must be >= 0, got {self.wait_for!r}")
        unknown = [s for s in self.replay_scenes if s not in REPLAY_SCENES]
        _require(
            bool(self.replay_scenes) and not unknown,
            f"replay_scenes must be a non-empty list of {list(REPLAY_SCENES)}, "
            f"got {list(self.replay_scenes)!r}",
        )
        _require(
            self.replay_min_humans >= 1,
            f"replay_min_humans must be >= 1, got {self.replay_min_humans!r}",
        )
        _require(
            self.scenario != "replay" or self.humans >= self.replay_min_humans,
            f"the replay scenario places {self.replay_min_humans} or more pedestrians "
            f"(replay_min_humans) but humans is {self.humans}: raise humans (e.g. 10)",
        )
        _require(
            (self.scenario == "custom") == (self.scenario_file is not None),
            "scenario 'custom' needs scenario_file (a YAML scenario, docs/scenarios.md) and "
            f"scenario_file needs scenario 'custom'; got scenario {self.scenario!r} with "
            f"scenario_file {self.scenario_file!r}",
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
        name = f"{where}.{f.name}" if where else f.name
        value = _checked_value(name, getattr(obj, f.name), hints[f.name])
        object.__setattr__(obj, f.name, value)
        low, high = f.metadata.get("low"), f.metadata.get("high")
        choices = f.metadata.get("choices")
        if choices is not None and value not in choices:
            raise ValueError(f"{name} must be one of {list(choices)}, got {value!r}")
        too_low = low is not None and (value <= low if f.metadata.get("low_open") else value < low)
        if too_low or (high is not None and value > high):
            raise ValueError(f"{name} must be {_range_text(f.metadata)}, got {value!r}")


def check_below(low_name: str, low: float, high_name: str, high: float) -> None:
    """Refuse a pair of bounds whose lower one is not below the upper one."""
    if low >= high:
        raise ValueError(f"{low_name} ({low}) must be below {high_name} ({high})")


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
