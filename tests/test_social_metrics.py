"""Social-navigation metrics against values computed by hand on small trajectories."""

from __future__ import annotations

import math

import numpy as np

from crowdplan.evaluation import Trace, run_episodes, summarize
from crowdplan.social_metrics import (
    angular_jerk,
    episode_metrics,
    path_irregularity,
    personal_space_intrusion,
    time_to_collision,
)


def _trace(robot_pos, human_pos, human_vel, dt=1.0) -> Trace:
    robot_pos = np.asarray(robot_pos, dtype=float)
    human_pos = np.asarray(human_pos, dtype=float)
    return Trace(
        robot_pos=robot_pos,
        robot_vel=np.diff(robot_pos, axis=0) / dt,
        robot_goal=robot_pos[-1],
        robot_radius=0.3,
        human_pos=human_pos,
        human_goal=human_pos[-1],
        human_radius=np.full(human_pos.shape[1], 0.3),
        scores=None,
        dt=dt,
        human_vel=np.asarray(human_vel, dtype=float),
    )


def test_personal_space_and_distance_by_hand():
    # Robot walks x = 0, 1, 2, 3 along y = 0; one still human at (2, 1.0): centre distances
    # at states 1..3 are sqrt(2), 1.0, sqrt(2); gaps (minus 0.6) 0.814, 0.4, 0.814.
    robot = [[0, 0], [1, 0], [2, 0], [3, 0]]
    human = [[[2, 1.0]]] * 4
    m = episode_metrics(_trace(robot, human, np.zeros((4, 1, 2))))
    assert m["personal_space_intrusion"] == 1 / 3  # only state 2 is within 0.45 m
    gap = math.sqrt(2) - 0.6
    assert math.isclose(m["mean_human_distance"], (2 * gap + 0.4) / 3)
    assert m["path_irregularity"] == 0.0  # always straight at the goal


def test_time_to_collision_by_hand():
    # Head-on: 5 m apart centre to centre, closing at 2 m/s, radii 0.3 + 0.3 -> (5 - 0.6) / 2.
    assert math.isclose(time_to_collision(np.array([5.0, 0]), np.array([-2.0, 0]), 0.6), 2.2)
    # Passing 1 m to the side never touches; moving apart never; overlapping now is 0.
    assert time_to_collision(np.array([5.0, 1.0]), np.array([-2.0, 0]), 0.6) == math.inf
    assert time_to_collision(np.array([5.0, 0]), np.array([2.0, 0]), 0.6) == math.inf
    assert time_to_collision(np.array([0.5, 0]), np.array([1.0, 0]), 0.6) == 0.0
    # Robot at rest with a human walking at it from 3 m: state 1 has TTC (3 - 0.6) / 1 - 1.
    robot = [[0, 0]] * 3
    human = [[[3, 0]], [[2, 0]], [[1.5, 0]]]
    vel = [[[-1, 0]], [[-1, 0]], [[-0.5, 0]]]
    m = episode_metrics(_trace(robot, human, vel))
    assert math.isclose(m["min_ttc"], min(1.4 / 1.0, 0.9 / 0.5))


def test_path_irregularity_and_angular_jerk_by_hand():
    # Goal at (10, 0): the robot moves at 45 degrees off it, then straight at it: mean pi/8.
    pos = np.array([[0.0, 0], [1, 1], [1.9, 0.9]])
    vel = np.diff(pos, axis=0)
    assert math.isclose(path_irregularity(pos, vel, np.array([10.0, 0.0])), math.pi / 8)
    # Headings 0, 0, pi/2, pi/2 (dt 0.5): one third difference, h3 - 3 h2 + 3 h1 - h0 = -pi,
    # divided by dt^3 = 0.125.
    vel = np.array([[1.0, 0], [1, 0], [0, 1], [0, 1]])
    assert math.isclose(angular_jerk(vel, 0.5), math.pi / 0.125)
    assert personal_space_intrusion(np.zeros((0, 1))) == 0.0


def test_evaluation_reports_the_social_metrics():
    from crowdplan.algos.orca_planner import OrcaPlanner
    from crowdplan.config import WorldConfig

    records = run_episodes(OrcaPlanner(), WorldConfig(humans=3), [1000, 1001])
    summary = summarize(records)
    for key in ("path_irregularity", "angular_jerk", "personal_space_intrusion", "min_ttc"):
        assert math.isfinite(summary[key]["value"]), key
    assert 0.0 <= summary["personal_space_intrusion"]["value"] <= 1.0
