"""Strategy rules (docs/strategies.md) on hand-made trajectories of each kind."""

from __future__ import annotations

import numpy as np
import pytest

from crowdplan.analysis.strategies import (
    STRATEGIES,
    classify,
    distribution,
    dominant,
    evidence,
)
from crowdplan.evaluation import Trace

DT = 0.25


def _trace(robot_y, humans) -> Trace:
    """Robot on the y axis from y = -4 to its goal at y = 4 along ``robot_y`` (one entry per
    state); ``humans`` (states, N, 2); velocities from positions."""
    robot = np.stack([np.zeros(len(robot_y)), np.asarray(robot_y, dtype=float)], axis=1)
    humans = np.asarray(humans, dtype=float)
    h_vel = np.concatenate([np.zeros((1, *humans.shape[1:])), np.diff(humans, axis=0) / DT])
    return Trace(
        robot_pos=robot,
        robot_vel=np.diff(robot, axis=0) / DT,
        robot_goal=np.array([0.0, 4.0]),
        robot_radius=0.3,
        human_pos=humans,
        human_goal=humans[-1],
        human_radius=np.full(humans.shape[1], 0.3),
        scores=None,
        dt=DT,
        human_vel=h_vel,
    )


def _straight(speed=1.0):
    return np.arange(-4.0, 4.0 + 1e-9, speed * DT)


def _still(point, states):
    return np.tile(np.asarray(point, dtype=float), (states, 1, 1))


def test_full_bypass_keeps_out_of_discomfort():
    y = _straight()
    assert classify(_trace(y, _still([[3.0, 0.0]], len(y))), "goal") == "full-bypass"


def test_partly_bypass_comes_close_to_one_side():
    y = _straight()
    trace = _trace(y, _still([[0.7, 0.0]], len(y)))  # gap 0.1 m when level with it
    assert evidence(trace, "goal").min_gap == pytest.approx(0.1)
    assert classify(trace, "goal") == "partly-bypass"


def test_follow_pass_walks_behind_a_human_going_its_way():
    y = _straight()
    human = np.stack([np.full(len(y), 0.1), y + 1.6], axis=1)[:, None, :]  # 1 m gap ahead
    assert evidence(_trace(y, human), "goal").follow_time >= 1.5
    assert classify(_trace(y, human), "goal") == "follow-pass"


def test_wait_pass_stands_while_a_human_crosses_in_front():
    y = np.concatenate([np.full(9, -4.0), np.arange(-4.0, 4.0 + 1e-9, DT)])
    x = np.concatenate([np.linspace(-1.0, 1.0, 9), np.linspace(1.25, 9.0, len(y) - 9)])
    human = np.stack([x, np.full(len(y), -3.2)], axis=1)[:, None, :]  # crosses 0.8 m ahead
    ev = evidence(_trace(y, human), "goal")
    assert ev.wait_time >= 1.0 and ev.retreat == 0.0
    assert classify(_trace(y, human), "goal") == "wait-pass"


def test_back_pass_retreats_along_the_start_goal_axis():
    y = np.concatenate(
        [np.arange(-4.0, -3.0, DT), np.arange(-3.0, -3.8, -DT), np.arange(-3.8, 4.01, DT)]
    )
    trace = _trace(y, _still([[2.0, -2.0]], len(y)))
    assert evidence(trace, "goal").retreat == pytest.approx(0.8)  # from y = -3.0 to -3.8
    assert classify(trace, "goal") == "back-pass"


def test_cross_cuts_between_two_humans_or_collides():
    y = _straight()
    pair = _still([[0.75, 0.0], [-0.75, 0.0]], len(y))  # 0.15 m gap on each side
    assert evidence(_trace(y, pair), "goal").cut_steps >= 1
    assert classify(_trace(y, pair), "goal") == "cross"
    assert classify(_trace(y, _still([[3.0, 0.0]], len(y))), "collision") == "cross"


def test_rules_apply_in_order_and_empty_scenes_are_full_bypass():
    y = np.concatenate(
        [np.arange(-4.0, -3.0, DT), np.arange(-3.0, -3.8, -DT), np.arange(-3.8, 4.01, DT)]
    )
    pair = _still([[0.75, 0.0], [-0.75, 0.0]], len(y))
    assert classify(_trace(y, pair), "goal") == "cross"  # cross before back-pass
    assert classify(_trace(_straight(), np.zeros((33, 0, 2))), "goal") == "full-bypass"


def test_distribution_and_dominant():
    labels = ["cross"] * 3 + ["follow-pass"] * 2 + ["full-bypass"]
    share = distribution(labels)
    assert list(share) == list(STRATEGIES) and share["cross"] == 0.5
    assert dominant(labels) == ["cross", "follow-pass"] and dominant([]) == []
