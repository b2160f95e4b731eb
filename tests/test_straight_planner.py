"""The blind straight-line baseline."""

import pytest

from crowdplan import evaluation
from crowdplan.policies import load_policy


def test_straight_reaches_an_empty_goal_at_full_speed():
    policy, world = load_policy("straight", None)
    records = evaluation.run_episodes(policy, world.replace(humans=0), evaluation.test_seeds(3))
    assert [r.outcome for r in records] == ["goal"] * 3
    # 8 m at 1 m/s, done once within the robot radius (7.7 m) of the goal: 31 steps of 0.25 s
    assert all(r.time == pytest.approx(7.75) for r in records)
