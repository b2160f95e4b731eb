"""Scenario generators: seed -> initial state of one episode (SPEC.md section 1).

Each episode is a pure function of (config, seed): all draws come from
``np.random.default_rng(seed)``, in a fixed order, never from a global RNG.

Rejection rule (as CrowdNav): a human is redrawn when it is closer than
``r_h + r_other + 0.2`` to an already placed agent (the robot included). circle_crossing tests the
human's start against the others' starts and goals (its goal is the mirror of its start);
square_crossing tests the start against the others' starts and, separately, the goal against the
others' goals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from crowdplan.config import WorldConfig

PLACEMENT_MARGIN = 0.2


class PlacementError(ValueError):
    """The crowd could not be placed within the allowed number of rejection-sampling tries."""


@dataclass
class InitialState:
    """Initial state of one episode; the generator is kept for later draws (respawn on arrival)."""

    robot_pos: np.ndarray  # (2,)
    robot_goal: np.ndarray  # (2,)
    human_pos: np.ndarray  # (N, 2)
    human_goal: np.ndarray  # (N, 2)
    human_radius: np.ndarray  # (N,)
    human_v_pref: np.ndarray  # (N,)
    rng: np.random.Generator


def check_seed(seed: object) -> int:
    """Seeds are non-negative Python or numpy integers."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise TypeError(
            f"seed must be a non-negative integer, got {seed!r} ({type(seed).__name__})"
        )
    return int(seed)


def generate(config: WorldConfig, seed: int) -> InitialState:
    """Draw the initial state of the episode with this seed."""
    rng = np.random.default_rng(check_seed(seed))
    n = config.humans
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
    return InitialState(
        robot_pos=robot_pos,
        robot_goal=robot_goal,
        human_pos=np.array(starts[1:]).reshape(n, 2),
        human_goal=np.array(goals[1:]).reshape(n, 2),
        human_radius=human_radius,
        human_v_pref=human_v_pref,
        rng=rng,
    )


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
    config: WorldConfig, rng: np.random.Generator, position: np.ndarray, v_pref: float
) -> np.ndarray:
    """A new goal for a human that arrived (the "respawn on arrival" option).

    circle_crossing: a fresh noisy point on the circle; square_crossing: a point on the side
    opposite to the human's current side.
    """
    if config.scenario == "circle_crossing":
        angle = rng.random() * 2 * np.pi
        noise = (rng.random(2) - 0.5) * v_pref
        return config.circle_radius * np.array([np.cos(angle), np.sin(angle)]) + noise
    side = -1.0 if position[0] > 0 else 1.0
    width = config.square_width
    return np.array([rng.random() * width * 0.5 * side, (rng.random() - 0.5) * width])
