"""Scenario generators: seed -> initial state of one episode (SPEC.md section 1).

The scenario protocol: a scenario is any function ``(WorldConfig, seed) -> InitialState``; the
world plays an ``InitialState`` with ``World.reset_states`` (``World.reset`` plays the seeds of
the configured scenario). Built in: circle_crossing, square_crossing, replay (recorded ETH/UCY
pedestrians, ``sim/replay.py``) and custom (a YAML file, ``sim/scenario_file.py``).

Each episode is a pure function of (config, seed): all draws come from
``np.random.default_rng(seed)``, in a fixed order, never from a global RNG. The options added
after the paper's setting (crowd size range, kinds of humans, scene rotation, replay mixture)
draw from their own streams ``default_rng([seed, k])``, so the paper's cases are unchanged.

Rejection rule (as CrowdNav): a human is redrawn when it is closer than
``r_h + r_other + 0.2`` to an already placed agent (the robot included). circle_crossing tests the
human's start against the others' starts and goals (its goal is the mirror of its start);
square_crossing tests the start against the others' starts and, separately, the goal against the
others' goals.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from crowdplan.config import WorldConfig
from crowdplan.sim.initial_state import (
    ORCA,
    PLACEMENT_MARGIN,
    SOCIAL_FORCE,
    STATIC,
    WAITING,
    InitialState,
    PlacementError,
)

# Independent random streams of one episode: default_rng([seed, stream]).
_STREAM_COUNT, _STREAM_KINDS, _STREAM_ROTATION, _STREAM_REPLAY_MIX, _STREAM_PLAIN = 1, 2, 3, 4, 5


def check_seed(seed: object) -> int:
    """Seeds are non-negative Python or numpy integers."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise TypeError(
            f"seed must be a non-negative integer, got {seed!r} ({type(seed).__name__})"
        )
    return int(seed)


def generate(config: WorldConfig, seed: int) -> InitialState:
    """The initial state of the episode with this seed in the configured scenario."""
    seed = check_seed(seed)
    if config.scenario == "custom":
        from crowdplan.sim.scenario_file import scene_for_seed

        state = scene_for_seed(config, seed)
    elif config.scenario == "replay" or (
        config.replay_fraction > 0
        and np.random.default_rng([seed, _STREAM_REPLAY_MIX]).random() < config.replay_fraction
    ):
        from crowdplan.sim.replay import replay_case

        state = replay_case(config, seed)
    else:
        state = _crossing(config, seed)
    angle = np.deg2rad(config.goal_rotation)
    if config.random_goal_direction:
        angle += np.random.default_rng([seed, _STREAM_ROTATION]).uniform(0.0, 2 * np.pi)
    return rotate(state, angle) if angle else state


def rotate(state: InitialState, angle: float) -> InitialState:
    """The same scene rotated by ``angle`` (rad) about the origin."""
    cos, sin = np.cos(angle), np.sin(angle)
    rot = np.array([[cos, -sin], [sin, cos]])

    def turn(points):
        return None if points is None else np.asarray(points) @ rot.T

    return replace(
        state,
        robot_pos=turn(state.robot_pos),
        robot_goal=turn(state.robot_goal),
        human_pos=turn(state.human_pos),
        human_goal=turn(state.human_goal),
        human_vel=turn(state.human_vel),
        track=turn(state.track),
        robot_theta=None if state.robot_theta is None else state.robot_theta + angle,
        rotation=state.rotation + angle,
    )


def _crossing(config: WorldConfig, seed: int) -> InitialState:
    """circle_crossing or square_crossing, with the crowd-size and kind options."""
    rng = np.random.default_rng(seed)
    n = config.humans
    if config.humans_min is not None:
        n = int(np.random.default_rng([seed, _STREAM_COUNT]).integers(config.humans_min, n + 1))
    if (
        config.circle_radius_min is not None
        and config.scenario == "circle_crossing"
        and config.humans
    ):
        radius = max(config.circle_radius_min, config.circle_radius * np.sqrt(n / config.humans))
        config = replace(config, circle_radius=float(radius))
    if (
        config.plain_fraction > 0
        and np.random.default_rng([seed, _STREAM_PLAIN]).random() < config.plain_fraction
    ):
        config = replace(
            config,
            randomize_attributes=False,
            social_force_fraction=0.0,
            static_fraction=0.0,
            waiting_fraction=0.0,
        )
    robot_pos = np.array([0.0, -config.circle_radius])
    robot_goal = np.array([0.0, config.circle_radius])
    starts = [robot_pos]
    goals = [robot_goal]
    radii = [config.robot_radius]
    human_radius = np.empty(n)
    human_v_pref = np.empty(n)
    for i in range(n):
        if config.randomize_attributes:
            human_v_pref[i] = rng.uniform(0.5, 1.5)
            human_radius[i] = rng.uniform(0.3, 0.5)
        else:
            human_v_pref[i] = config.human_v_pref
            human_radius[i] = config.human_radius
        place = _place_circle if config.scenario == "circle_crossing" else _place_square
        start, goal = place(config, rng, human_radius[i], human_v_pref[i], starts, goals, radii, i)
        starts.append(start)
        goals.append(goal)
        radii.append(human_radius[i])
    human_pos = np.array(starts[1:]).reshape(n, 2)
    human_goal = np.array(goals[1:]).reshape(n, 2)
    kinds, waits = _draw_kinds(config, seed, n)
    human_goal[kinds == STATIC] = human_pos[kinds == STATIC]
    return InitialState(
        robot_pos=robot_pos,
        robot_goal=robot_goal,
        human_pos=human_pos,
        human_goal=human_goal,
        human_radius=human_radius,
        human_v_pref=human_v_pref,
        rng=rng,
        human_kind=kinds,
        human_wait=waits,
    )


def _draw_kinds(config: WorldConfig, seed: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Kinds of n generated humans from the configured fractions, and their stop windows."""
    kinds = np.full(n, ORCA, dtype=np.int64)
    fractions = (config.social_force_fraction, config.static_fraction, config.waiting_fraction)
    if any(fractions):
        draw = np.random.default_rng([seed, _STREAM_KINDS]).random(n)
        edges = np.cumsum(fractions)
        kinds = np.select(
            [draw < edges[0], draw < edges[1], draw < edges[2]],
            [SOCIAL_FORCE, STATIC, WAITING],
            ORCA,
        ).astype(np.int64)
    waits = np.full((n, 2), np.inf)
    waits[kinds == WAITING] = [config.wait_after, config.wait_after + config.wait_for]
    return kinds, waits


def _too_close(point: np.ndarray, others: list[np.ndarray], radius: float, radii: list) -> bool:
    others_arr = np.asarray(others)
    min_dist = radius + np.asarray(radii) + PLACEMENT_MARGIN
    return bool(np.any(np.hypot(*(others_arr - point).T) < min_dist))


def _give_up(config: WorldConfig, index: int) -> PlacementError:
    return PlacementError(
        f"could not place human {index} of {config.humans} in {config.scenario} after "
        f"{config.placement_tries} tries (placement_tries); the crowd is too dense for this "
        f"scene: lower humans, enlarge circle_radius/square_width or use smaller human radii"
    )


def _place_circle(config, rng, radius, v_pref, starts, goals, radii, index):
    for _ in range(config.placement_tries):
        angle = rng.random() * 2 * np.pi
        noise = (rng.random(2) - 0.5) * v_pref
        start = config.circle_radius * np.array([np.cos(angle), np.sin(angle)]) + noise
        if not (
            _too_close(start, starts, radius, radii) or _too_close(start, goals, radius, radii)
        ):
            return start, -start
    raise _give_up(config, index)


def _place_square(config, rng, radius, v_pref, starts, goals, radii, index):
    width = config.square_width
    sign = -1.0 if rng.random() > 0.5 else 1.0
    for _ in range(config.placement_tries):
        start = np.array([rng.random() * width * 0.5 * sign, (rng.random() - 0.5) * width])
        if not _too_close(start, starts, radius, radii):
            break
    else:
        raise _give_up(config, index)
    for _ in range(config.placement_tries):
        goal = np.array([rng.random() * width * 0.5 * -sign, (rng.random() - 0.5) * width])
        if not _too_close(goal, goals, radius, radii):
            return start, goal
    raise _give_up(config, index)


def respawn_goal(
    config: WorldConfig,
    rng: np.random.Generator,
    position: np.ndarray,
    v_pref: float,
    rotation: float = 0.0,
) -> np.ndarray:
    """A new goal for a human that arrived (the "respawn on arrival" option).

    circle_crossing (and the scenarios without a crossing of their own): a fresh noisy point on
    the circle; square_crossing: a point on the side opposite to the human's current side. Drawn
    in the unrotated scene, then turned by the scene's ``rotation``.
    """
    cos, sin = np.cos(rotation), np.sin(rotation)
    if config.scenario != "square_crossing":
        angle = rng.random() * 2 * np.pi
        noise = (rng.random(2) - 0.5) * v_pref
        goal = config.circle_radius * np.array([np.cos(angle), np.sin(angle)]) + noise
    else:
        unrotated_x = position[0] * cos + position[1] * sin
        side = -1.0 if unrotated_x > 0 else 1.0
        width = config.square_width
        goal = np.array([rng.random() * width * 0.5 * side, (rng.random() - 0.5) * width])
    if not rotation:
        return goal
    return np.array([goal[0] * cos - goal[1] * sin, goal[0] * sin + goal[1] * cos])
