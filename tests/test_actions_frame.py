"""Actions in the goal frame: a holonomic policy over robot-centric features is exactly equivariant
to rotations and translations of the whole scene; the paper's world frame stays available."""

from dataclasses import replace

import numpy as np
import pytest

from crowdplan.config import WorldConfig
from crowdplan.features import robot_centric
from crowdplan.sim import scenarios
from crowdplan.sim.actions import N_ACTIONS, action_table, action_velocities
from crowdplan.sim.world import RUNNING, World

WEIGHTS = np.random.default_rng(7).normal(size=(6 + 5 * 7, N_ACTIONS))


def feature_policy(robot, humans, mask, unicycle=False):
    """A fixed random linear scorer of robot-centric features (no trained model)."""
    feats = robot_centric(robot, humans, mask, unicycle)
    flat = np.concatenate([feats.robot, feats.humans.reshape(len(robot), -1)], axis=1)
    return np.argmax(flat.astype(np.float64) @ WEIGHTS, axis=1)


def moved(state, angle, shift):
    """The scene turned by ``angle`` about the origin, then shifted by ``shift``."""
    turned = scenarios.rotate(state, angle)
    return replace(
        turned,
        robot_pos=turned.robot_pos + shift,
        robot_goal=turned.robot_goal + shift,
        human_pos=turned.human_pos + shift,
        human_goal=turned.human_goal + shift,
    )


def rollout(config, state, steps=100):
    world = World(config)
    world.reset_states([state])
    path, humans, done = [world.robot_pos[0].copy()], [world.human_pos[0].copy()], False
    for _ in range(steps):
        result = world.step(
            feature_policy(*world.observe(), unicycle=config.kinematics == "unicycle")
        )
        path.append(world.robot_pos[0].copy())
        humans.append(world.human_pos[0].copy())
        if result.outcome[0] != RUNNING:
            done = True
            break
    return np.array(path), np.array(humans), done


@pytest.mark.parametrize("kinematics", ["holonomic", "unicycle"])
@pytest.mark.parametrize("seed", [1000, 1003])
def test_rotated_and_shifted_scene_gives_rotated_and_shifted_trajectory(kinematics, seed):
    config = WorldConfig(humans=5, kinematics=kinematics)
    state = scenarios.generate(config, seed)
    angle, shift = 2.1, np.array([3.5, -7.25])
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    path, humans, _ = rollout(config, state)
    path2, humans2, _ = rollout(config, moved(state, angle, shift))
    assert len(path) == len(path2) and len(path) > 10
    np.testing.assert_allclose(path2, path @ rot.T + shift, rtol=0, atol=1e-6)
    np.testing.assert_allclose(humans2, humans @ rot.T + shift, rtol=0, atol=1e-6)


def test_world_frame_actions_are_absolute_headings():
    config = WorldConfig(humans=5, action_frame="world")
    state = scenarios.generate(config, 1000)
    path, _, _ = rollout(config, state, steps=3)
    path2, _, _ = rollout(config, moved(state, np.pi / 2, np.zeros(2)), steps=3)
    rot = np.array([[0.0, -1.0], [1.0, 0.0]])
    assert not np.allclose(path2, path @ rot.T, atol=1e-3)  # the paper's actions do not turn


def test_action_velocities_both_frames():
    # Robot at (1, 1) with its goal straight to the east: heading 0 in the goal frame is east.
    robot = np.array([[1.0, 1.0, 0.0, 0.0, 0.3, 5.0, 1.0, 1.0, np.pi / 2]] * 3)
    actions = np.array([0, 1 + 4 * 5 + 4, 1 + 0 * 5 + 2])  # stop, k=4 full speed, k=0 0.6
    vel, theta = action_velocities(actions, robot, action_frame="goal")
    np.testing.assert_allclose(vel, [[0, 0], [0, 1], [0.6, 0]], atol=1e-12)
    np.testing.assert_array_equal(theta, robot[:, 8])
    vel, _ = action_velocities(actions, robot, action_frame="world")
    np.testing.assert_allclose(vel, [[0, 0], [0, 1], [0.6, 0]], atol=1e-12)
    robot[:, 5:7] = [1.0, 5.0]  # goal to the north: goal-frame headings turn by pi/2
    vel, _ = action_velocities(actions, robot, action_frame="goal")
    np.testing.assert_allclose(vel, [[0, 0], [-1, 0], [0, 0.6]], atol=1e-12)
    table = action_table(2.0, "holonomic", "exponential")
    robot[:, 7] = 2.0
    vel, _ = action_velocities(actions, robot, action_frame="world", sampling="exponential")
    np.testing.assert_allclose(np.hypot(*vel.T), table[actions, 0], atol=1e-12)


def test_unicycle_actions_turn_the_robot_heading_in_both_frames():
    robot = np.array([[0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 4.0, 1.0, 0.3]])
    last = np.array([N_ACTIONS - 1])
    for frame in ("goal", "world"):
        vel, theta = action_velocities(last, robot, "unicycle", frame)
        assert theta[0] == pytest.approx(0.3 + np.pi / 4)
        np.testing.assert_allclose(vel[0], [np.cos(theta[0]), np.sin(theta[0])], atol=1e-12)


def test_world_uses_action_velocities():
    for frame in ("goal", "world"):
        world = World(WorldConfig(humans=3, action_frame=frame, random_goal_direction=True), 4)
        world.reset([1000, 1001, 1002, 1003])
        actions = np.array([0, 7, 42, 80])
        expected, _ = action_velocities(actions, world.observe()[0], action_frame=frame)
        np.testing.assert_allclose(world.robot_velocity(actions)[0], expected, atol=0)
        world.step(actions)
        np.testing.assert_allclose(world.robot_vel, expected, rtol=0, atol=1e-12)


def test_bad_frame_and_shapes():
    robot = np.zeros((2, 9))
    with pytest.raises(ValueError, match="action_frame must be one of"):
        action_velocities(np.array([1, 2]), robot, action_frame="robot")
    with pytest.raises(ValueError, match=r"robot states must have shape \(3, 9\)"):
        action_velocities(np.array([1, 2, 3]), robot)
    with pytest.raises(ValueError, match="action_frame must be one of"):
        WorldConfig(action_frame="north")
