"""How timeouts end (crowdplan.analysis.timeouts): hand-made traces of each kind and a CLI run."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crowdplan.analysis import timeouts
from crowdplan.analysis.timeouts import ending, stops_when_moving, summary_row, timeout_endings
from crowdplan.evaluation import EpisodeRecord, Trace
from crowdplan.policy import PolicyOutput

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


class _StopsWhenStill:
    """Discrete planner that stops exactly when the robot it observes stands still; records what
    it saw."""

    name = "stops-when-still"

    def act(self, robot, humans, mask):
        self.seen = (robot, humans, mask)
        still = np.hypot(robot[:, 2], robot[:, 3]) < 1e-9
        return PolicyOutput(np.where(still, 0, 5))


class _AlwaysStops:
    """Velocity-command planner that always commands zero velocity."""

    name = "always-stops"

    def act(self, robot, humans, mask):
        return PolicyOutput(np.zeros((len(robot), 2)))


def test_the_stop_probe_tells_a_fixed_point_of_standing_still_from_a_stop_for_the_scene():
    frozen = _trace(np.full(STEPS + 1, -1.0))
    standing = _StopsWhenStill()
    assert not stops_when_moving(standing, frozen, v_pref=1.0)
    robot, humans, mask = standing.seen
    # the robot at its last position, moving at 1 m/s straight to the goal at (0, 4)
    np.testing.assert_allclose(robot[0, :4], [0.0, -1.0, 0.0, 1.0])
    np.testing.assert_allclose(humans[0], [[3.0, 0.0, 0.0, 0.0, 0.3]])
    assert mask.tolist() == [[True]]
    assert stops_when_moving(_AlwaysStops(), frozen, v_pref=1.0)


def test_the_stop_probe_column_is_the_share_of_frozen_timeouts_that_stop():
    records = [_record(1, "timeout", _trace(np.full(STEPS + 1, -4.0)))]
    assert summary_row("m", records, [True, False])[-1] == "0.50"
    assert summary_row("m", [_record(2, "goal", None)], [])[-1] == "-"
    assert len(summary_row("m", records, [True])) == len(summary_row("m", records)) + 1


def test_cli_replays_the_shipped_cadrl_on_square_cases(capsys):
    timeouts.main(["cadrl", "--episodes", "2"])
    out = capsys.readouterr().out
    assert "square_crossing, 5 humans, test cases 0..1" in out
    assert "| cadrl | 2 |" in out


def test_cli_probe_stop_adds_its_column(capsys):
    timeouts.main(["cadrl", "--episodes", "2", "--probe-stop"])
    out = capsys.readouterr().out
    assert "frozen, stops also when moving to the goal |" in out
    assert "| cadrl | 2 |" in out


def test_cli_rejects_an_episode_count_outside_the_test_split(capsys):
    with pytest.raises(SystemExit):
        timeouts.main(["cadrl", "--episodes", "0"])
    assert "--episodes must be in 1..500" in capsys.readouterr().err


def test_cli_names_a_model_it_cannot_find(capsys):
    with pytest.raises(SystemExit):
        timeouts.main(["cadrl", "no-such-model"])
    assert "no model found at 'no-such-model'" in capsys.readouterr().err
