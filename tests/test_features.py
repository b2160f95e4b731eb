"""The robot-centric rotation against hand-computed cases."""

import numpy as np
import pytest

from crowdplan.features import robot_centric


def _robot(px, py, vx, vy, gx, gy, theta=np.pi / 2, r=0.3, v_pref=1.0):
    return np.array([[px, py, vx, vy, r, gx, gy, v_pref, theta]])


def test_goal_straight_up_is_a_quarter_turn():
    # Robot at origin, goal at (0, 4): the x-axis of the frame points up (+y of the world).
    robot = _robot(0, 0, 0.0, 1.0, 0, 4)
    humans = np.array([[[1.0, 2.0, -1.0, 0.0, 0.4]]])
    feats = robot_centric(robot, humans, np.ones((1, 1), bool))
    np.testing.assert_allclose(feats.robot[0], [4.0, 1.0, 0.0, 0.3, 1.0, 0.0], atol=1e-6)
    # world (1, 2) -> frame (2, -1); world velocity (-1, 0) -> frame (0, 1)
    np.testing.assert_allclose(
        feats.humans[0, 0], [2.0, -1.0, 0.0, 1.0, 0.4, np.sqrt(5), 0.7], atol=1e-6
    )


def test_diagonal_goal():
    robot = _robot(1, 1, 1.0, 0.0, 4, 4)
    humans = np.array([[[2.0, 1.0, 0.0, 0.0, 0.3]]])
    feats = robot_centric(robot, humans, np.ones((1, 1), bool))
    s = np.sqrt(0.5)
    np.testing.assert_allclose(feats.robot[0], [3 * np.sqrt(2), 1.0, 0.0, 0.3, s, -s], atol=1e-6)
    np.testing.assert_allclose(feats.humans[0, 0, :2], [s, -s], atol=1e-6)


def test_unicycle_heading_is_relative_to_goal_direction():
    robot = _robot(0, 0, 0, 0, 0, 4, theta=0.0)
    feats = robot_centric(robot, np.zeros((1, 0, 5)), np.zeros((1, 0), bool), unicycle=True)
    assert feats.robot[0, 2] == pytest.approx(-np.pi / 2)
    holonomic = robot_centric(robot, np.zeros((1, 0, 5)), np.zeros((1, 0), bool))
    assert holonomic.robot[0, 2] == 0.0


def test_padding_rows_are_zero_and_batch_shapes_hold():
    robot = np.repeat(_robot(0, -4, 0, 0, 0, 4), 3, axis=0)
    humans = np.random.default_rng(0).normal(size=(3, 4, 5))
    mask = np.array([[1, 1, 0, 0], [1, 0, 0, 0], [0, 0, 0, 0]], bool)
    feats = robot_centric(robot, humans, mask)
    assert feats.robot.shape == (3, 6) and feats.humans.shape == (3, 4, 7)
    assert feats.humans.dtype == np.float32
    assert np.all(feats.humans[~mask] == 0)
    assert np.all(feats.humans[mask] != 0)
