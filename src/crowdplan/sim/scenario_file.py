"""Scenario files: one's own starts, goals and crowds as YAML (the "custom" scenario).

Format (docs/scenarios.md)::

    scenes:
      - robot: {start: [0, -4], goal: [0, 4]}          # heading: radians, default towards goal
        humans:
          - {start: [3, 0], goal: [-3, 0]}              # kind orca, radius / v_pref from world
          - {start: [-3, 1], goal: [3, 1], kind: social_force, radius: 0.4, v_pref: 1.2}
          - {start: [0.8, 4.5], kind: static}           # standing (goal = start)
          - {start: [2, 2], goal: [-2, -2], kind: waiting, wait: [2.0, 5.0]}  # stop at 2 s, 5 s

Episode seed s plays scene ``s mod len(scenes)``. Every error names the file, the line and the
fix; a file is checked whole before any episode starts, and :func:`save_scenes` writes
atomically (never half a file).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from crowdplan.config import WorldConfig
from crowdplan.io import atomic_write
from crowdplan.sim.initial_state import HUMAN_KINDS, REPLAY, STATIC, WAITING, InitialState

FILE_KINDS = tuple(k for k in HUMAN_KINDS if k != "replay")
_ROBOT_KEYS = ("start", "goal", "heading")
_HUMAN_KEYS = ("start", "goal", "radius", "v_pref", "kind", "wait")


class ScenarioFileError(ValueError):
    """A scenario file that cannot be played; the message names the file, the line and the fix."""


class _Mapping(dict):
    line = 0


class _LineLoader(yaml.SafeLoader):
    """YAML loader that remembers the line of every mapping (for error messages)."""


def _construct_mapping(loader: _LineLoader, node: yaml.MappingNode):
    mapping = _Mapping()
    mapping.line = node.start_mark.line + 1
    yield mapping
    mapping.update(loader.construct_mapping(node))


_LineLoader.add_constructor("tag:yaml.org,2002:map", _construct_mapping)


def load_scenes(path: str | Path, config: WorldConfig | None = None) -> list[InitialState]:
    """Read and check every scene of a scenario file (defaults for radii and speeds: ``config``)."""
    config = config or WorldConfig()
    path = Path(path)
    try:
        data = yaml.load(path.read_text(), Loader=_LineLoader)  # a SafeLoader subclass
    except OSError as error:
        raise ScenarioFileError(f"cannot read scenario file {path}: {error}") from error
    except yaml.YAMLError as error:
        raise ScenarioFileError(f"{path} is not valid YAML: {error}") from error
    if (
        not isinstance(data, dict)
        or set(data) != {"scenes"}
        or not isinstance(data["scenes"], list)
    ):
        raise ScenarioFileError(
            f"{path}: a scenario file is a mapping with one key, 'scenes', holding a list of "
            "scenes (see docs/scenarios.md)"
        )
    if not data["scenes"]:
        raise ScenarioFileError(f"{path}: 'scenes' is empty; give at least one scene")
    return [_scene(path, i, raw, config) for i, raw in enumerate(data["scenes"])]


def save_scenes(path: str | Path, states: list[InitialState]) -> None:
    """Write scenes to a scenario file (atomically); :func:`load_scenes` reads them back."""
    scenes = []
    for state in states:
        kinds = state.kinds()
        if np.any(kinds == REPLAY):
            raise ValueError("replayed humans cannot be written to a scenario file")
        robot = {"start": _floats(state.robot_pos), "goal": _floats(state.robot_goal)}
        if state.robot_theta is not None:
            robot["heading"] = float(state.robot_theta)
        humans = []
        waits = state.waits()
        for h in range(state.humans):
            human = {
                "start": _floats(state.human_pos[h]),
                "goal": _floats(state.human_goal[h]),
                "radius": float(state.human_radius[h]),
                "v_pref": float(state.human_v_pref[h]),
                "kind": HUMAN_KINDS[kinds[h]],
            }
            if kinds[h] == WAITING:
                human["wait"] = [float(waits[h, 0]), float(waits[h, 1] - waits[h, 0])]
            humans.append(human)
        scenes.append({"robot": robot, "humans": humans})
    text = yaml.safe_dump({"scenes": scenes}, sort_keys=False, default_flow_style=None)
    atomic_write(path, lambda f: f.write(text))


@functools.lru_cache(maxsize=8)
def _cached(path: str, mtime: float, config: WorldConfig) -> tuple[InitialState, ...]:
    del mtime  # part of the cache key: an edited file is read again
    return tuple(load_scenes(path, config))


def scene_for_seed(config: WorldConfig, seed: int) -> InitialState:
    """The scene of the configured file that episode ``seed`` plays (seed mod number of scenes)."""
    path = Path(config.scenario_file)
    if not path.is_file():
        raise ScenarioFileError(f"scenario file {path} does not exist; check scenario_file")
    scenes = _cached(str(path), path.stat().st_mtime, config)
    scene = scenes[seed % len(scenes)]
    if scene.humans > config.humans:
        raise ScenarioFileError(
            f"{path}: scene {seed % len(scenes)} has {scene.humans} humans but the world holds "
            f"humans={config.humans}; set humans to {max(s.humans for s in scenes)} or more "
            "(e.g. --humans)"
        )
    return InitialState(
        **{k: v for k, v in vars(scene).items() if k != "rng"},
        rng=np.random.default_rng(seed),
    )


def _floats(values) -> list[float]:
    return [float(v) for v in values]


def _scene(path: Path, index: int, raw: Any, config: WorldConfig) -> InitialState:
    line = getattr(raw, "line", 0)
    where = f"{path}, line {line}, scene {index}"
    if not isinstance(raw, dict) or not {"robot"} <= set(raw) <= {"robot", "humans"}:
        raise ScenarioFileError(f"{where}: a scene is a mapping with 'robot' and 'humans' keys")
    robot = _mapping(raw["robot"], f"{where}, robot", _ROBOT_KEYS, required=("start", "goal"))
    start = _point(robot["start"], f"{where}, robot start")
    goal = _point(robot["goal"], f"{where}, robot goal")
    heading = robot.get("heading")
    if heading is not None and not _is_number(heading):
        raise ScenarioFileError(f"{where}: robot heading must be a number (radians) or absent")
    if np.hypot(*(goal - start)) < config.robot_radius:
        raise ScenarioFileError(
            f"{where}: the robot's goal is within its radius ({config.robot_radius} m) of its "
            "start; move the goal away"
        )
    raw_humans = raw.get("humans") or []
    if not isinstance(raw_humans, list):
        raise ScenarioFileError(f"{where}: 'humans' must be a list of humans")
    humans = []
    for h, raw_h in enumerate(raw_humans):
        human_where = f"{path}, line {getattr(raw_h, 'line', line)}, scene {index}, human {h}"
        humans.append(_human(raw_h, human_where, config))
    n = len(humans)
    state = InitialState(
        robot_pos=start,
        robot_goal=goal,
        human_pos=np.array([h["start"] for h in humans]).reshape(n, 2),
        human_goal=np.array([h["goal"] for h in humans]).reshape(n, 2),
        human_radius=np.array([h["radius"] for h in humans], dtype=np.float64),
        human_v_pref=np.array([h["v_pref"] for h in humans], dtype=np.float64),
        robot_theta=None if heading is None else float(heading),
        human_kind=np.array([h["kind"] for h in humans], dtype=np.int64),
        human_wait=np.array([h["wait"] for h in humans], dtype=np.float64).reshape(n, 2),
    )
    _check_geometry(state, [h["where"] for h in humans], where, config)
    return state


def _human(raw: Any, where: str, config: WorldConfig) -> dict:
    human = _mapping(raw, where, _HUMAN_KEYS, required=("start",))
    kind_name = human.get("kind", "orca")
    if kind_name not in FILE_KINDS:
        raise ScenarioFileError(
            f"{where}: kind must be one of {list(FILE_KINDS)}, got {kind_name!r}"
        )
    kind = HUMAN_KINDS.index(kind_name)
    start = _point(human["start"], f"{where}, start")
    if "goal" not in human and kind != STATIC:
        raise ScenarioFileError(f"{where}: a {kind_name} human needs a goal: [x, y]")
    goal = start if kind == STATIC else _point(human["goal"], f"{where}, goal")
    radius = human.get("radius", config.human_radius)
    v_pref = human.get("v_pref", config.human_v_pref)
    for name, value in (("radius", radius), ("v_pref", v_pref)):
        if not _is_number(value) or value <= 0:
            raise ScenarioFileError(f"{where}: {name} must be a positive number, got {value!r}")
    wait = [np.inf, np.inf]
    if kind == WAITING:
        window = human.get("wait", [config.wait_after, config.wait_for])
        if not (
            isinstance(window, list)
            and len(window) == 2
            and all(_is_number(v) and v >= 0 for v in window)
        ):
            raise ScenarioFileError(
                f"{where}: wait must be [after, for]: seconds of walking before the stop and "
                f"seconds of standing, both >= 0; got {window!r}"
            )
        wait = [float(window[0]), float(window[0]) + float(window[1])]
    elif "wait" in human:
        raise ScenarioFileError(f"{where}: only humans of kind 'waiting' take 'wait'; remove it")
    return {
        "start": start,
        "goal": goal,
        "radius": float(radius),
        "v_pref": float(v_pref),
        "kind": kind,
        "wait": wait,
        "where": where,
    }


def _check_geometry(state: InitialState, names: list[str], where: str, config: WorldConfig):
    """Overlapping starts and goals inside standing humans are errors."""
    pos = np.vstack([state.robot_pos, state.human_pos])
    radii = np.concatenate([[config.robot_radius], state.human_radius])
    labels = [f"{where}: the robot", *names]
    for i in range(len(pos)):
        for j in range(i):
            gap = np.hypot(*(pos[i] - pos[j])) - radii[i] - radii[j]
            if gap < 0:
                raise ScenarioFileError(
                    f"{labels[i]} starts overlapping {'the robot' if j == 0 else names[j - 1]} "
                    f"(by {-gap:.3f} m); move the starts at least {radii[i] + radii[j]:.2f} m apart"
                )
    for h in np.flatnonzero(state.kinds() == STATIC):
        gap = np.hypot(*(state.robot_goal - state.human_pos[h])) - state.human_radius[h]
        if gap < config.robot_radius:
            raise ScenarioFileError(
                f"{where}: the robot's goal is inside standing {names[h].split(', ')[-1]} "
                f"({names[h]}); it can never be reached: move the goal or the human at least "
                f"{config.robot_radius + state.human_radius[h]:.2f} m apart"
            )


def _mapping(raw: Any, where: str, keys: tuple[str, ...], required: tuple[str, ...]) -> dict:
    if not isinstance(raw, dict):
        raise ScenarioFileError(f"{where}: expected a mapping with keys {list(keys)}, got {raw!r}")
    unknown = sorted(set(raw) - set(keys))
    if unknown:
        raise ScenarioFileError(f"{where}: unknown key(s) {unknown}; valid keys are {list(keys)}")
    missing = [k for k in required if k not in raw]
    if missing:
        raise ScenarioFileError(f"{where}: missing {missing}; give them as [x, y] in metres")
    return raw


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value)


def _point(value: Any, where: str) -> np.ndarray:
    if not (isinstance(value, list) and len(value) == 2 and all(_is_number(v) for v in value)):
        raise ScenarioFileError(f"{where}: expected a point [x, y] of two numbers, got {value!r}")
    return np.array(value, dtype=np.float64)
