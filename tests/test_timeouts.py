"""How timeouts end (crowdplan.analysis.timeouts): hand-made traces of each kind and a CLI run."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crowdplan.analysis import timeouts
from crowdplan.analysis.timeouts import ending, summary_row, timeout_endings
from crowdplan.evaluation import EpisodeRecord, Trace

DT = 0.25
STEPS = 100  # a 25 s episode


def _trace(robot_y: np.ndarray, human_speed: float = 0.0) -> Trace:
    """Robot on the y axis, goal at y = 4, one human at (3, 0) walking along x at
    ``human_speed``."""
    robot = np.stack([np.zeros(len(robot_y)), robot_y], axis=1)
    human_vel = np.zeros((len(robot_y), 1, 2))
    human_vel[:, 0, 0] = human_speed
    return Trace(
        robot_pos=robot,
        robot_vel=np.diff(robot, axis=0) / DT,
        robot_goal=np.array([0.0, 4.0]),
        robot_radius=0.3,
        human_pos=np.tile([[[3.0, 0.0]]], (len(robot_y), 1, 1)),
        human_goal=np.array([[3.0, 0.0]]),
        human_radius=np.array([0.3]),
        scores=None,
        dt=DT,
        human_vel=human_vel,
    )


def _record(seed: int, outcome: str, trace: Trace | None) -> EpisodeRecord:
    return EpisodeRecord(
        seed, outcome, STEPS, 25.0, 0.0, 0.0, 1.0, 0.0, math.inf, 0, 0.0, 0.0, trace=trace
    )


def test_a_robot_that_stops_for_the_last_five_seconds_is_frozen():
    y = np.concatenate([np.linspace(-4, -1, 60), np.full(STEPS + 1 - 60, -1.0)])
    end = ending(_trace(y))
    assert end.kind == "frozen"
    assert end.goal_distance == pytest.approx(5.0)
    assert not end.beyond_start and end.crowd_at_rest


def test_a_robot_stepping_back_and_forth_is_cycling_and_may_end_beyond_its_start():
    # pushed back to y = -5 (9 m from the goal, 8 m at the start), then two positions 0.25 m apart
    y = np.concatenate([np.linspace(-4, -5, 21), -5 + 0.25 * (np.arange(STEPS - 20) % 2)])
    end = ending(_trace(y))
    assert end.kind == "cycling"
    assert end.beyond_start
    assert end.goal_distance == pytest.approx(4.0 - y[-1]) and y[-1] < -4.0


def test_a_robot_still_on_its_way_is_moving_and_a_walking_human_is_not_at_rest():
    y = np.linspace(-4, 2, STEPS + 1)
    end = ending(_trace(y, human_speed=1.0))
    assert end.kind == "moving"
    assert not end.crowd_at_rest


def test_only_timeouts_count_and_they_need_their_trace():
    still = _trace(np.full(STEPS + 1, -4.0))
    records = [
        _record(1, "goal", None),
        _record(2, "timeout", still),
        _record(3, "collision", None),
    ]
    assert [e.kind for e in timeout_endings(records)] == ["frozen"]
    row = summary_row("m", records)
    assert row[:5] == ["m", "3", "0.333", "0.333", "1.00"]
    with pytest.raises(ValueError, match="no trace"):
        timeout_endings([_record(4, "timeout", None)])


def test_a_model_without_timeouts_gets_dashes():
    row = summary_row("m", [_record(1, "goal", None)])
    assert row[:4] == ["m", "1", "1.000", "0.000"]
    assert set(row[4:]) == {"-"}


def test_cli_replays_the_shipped_cadrl_on_square_cases(capsys):
    timeouts.main(["cadrl", "--episodes", "2"])
    out = capsys.readouterr().out
    assert "square_crossing, 5 humans, test cases 0..1" in out
    assert "| cadrl | 2 |" in out


def test_cli_rejects_an_episode_count_outside_the_test_split(capsys):
    with pytest.raises(SystemExit):
        timeouts.main(["cadrl", "--episodes", "0"])
    assert "--episodes must be in 1..500" in capsys.readouterr().err


def test_cli_names_a_model_it_cannot_find(capsys):
    with pytest.raises(SystemExit):
        timeouts.main(["cadrl", "no-such-model"])
    assert "no model found at 'no-such-model'" in capsys.readouterr().err
