"""Loopback test of the ROS 2 node: a fake mocap publisher driven by the simulator, the node, and
a subscriber that integrates the robot's Twists; the robot reaches its goal among 5 humans."""

from __future__ import annotations

import math
import os
import time

import numpy as np
import pytest

from crowdplan.deploy.ros2 import ROS_MISSING, yaw_of

try:
    import rclpy
    from geometry_msgs.msg import PoseStamped, Twist
    from rclpy.executors import SingleThreadedExecutor
except ImportError as error:  # the [ros] extra is not installed
    pytest.skip(f"{ROS_MISSING} ({error})", allow_module_level=True)

from crowdplan.deploy.runtime import Agent, Runtime, RuntimeConfig
from crowdplan.models import load_model_policy
from crowdplan.sim.world import RUNNING, World

RATE = 10.0  # Hz: poses, commands and simulator steps


@pytest.fixture(scope="module")
def exported_lsa(tmp_path_factory):
    """The shipped model exported once per test session (shared by the deploy test files)."""
    from crowdplan.deploy.export import export_model

    folder = tmp_path_factory.getbasetemp() / "export-lsa-dsac-paper"
    if not (folder / "manifest.json").is_file():
        export_model("lsa-dsac-paper", folder)
    return folder


@pytest.fixture
def ros_localhost(monkeypatch):
    # loopback only, on a domain of its own
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv("ROS_LOCALHOST_ONLY", "1")
    monkeypatch.setenv("ROS_DOMAIN_ID", str(50 + os.getpid() % 50))
    rclpy.init()
    yield
    rclpy.try_shutdown()


def test_yaw_of_quaternion():
    q = PoseStamped().pose.orientation
    q.z, q.w = math.sin(0.3), math.cos(0.3)
    assert yaw_of(q) == pytest.approx(0.6)


def test_loopback_robot_reaches_goal_among_five_humans(ros_localhost, exported_lsa):
    from crowdplan.deploy.onnx_policy import OnnxPolicy
    from crowdplan.deploy.ros2 import build_node

    _, world_config = load_model_policy("lsa-dsac-paper")
    world = World(world_config.replace(dt=1.0 / RATE), 1)
    world.reset([1000])
    humans = [f"h{k}" for k in range(world_config.humans)]
    agents = [Agent("robot", "robot", goal=tuple(world.robot_goal[0]))]
    agents += [Agent(h, "human") for h in humans]
    runtime = Runtime(OnnxPolicy(exported_lsa), agents, RuntimeConfig(control_rate=RATE))
    node = build_node(runtime)

    mocap = rclpy.create_node("fake_mocap")
    pubs = {
        key: mocap.create_publisher(PoseStamped, f"/{key}/pose", 10) for key in agents_ids(agents)
    }
    twists: list[Twist] = []
    mocap.create_subscription(Twist, "/robot/cmd_vel", twists.append, 10)
    outcome = [RUNNING]

    def publish_poses():
        stamp = mocap.get_clock().now().to_msg()
        positions = np.concatenate([world.robot_pos, world.human_pos[0]])
        for key, (x, y) in zip(agents_ids(agents), positions, strict=True):
            msg = PoseStamped()
            msg.header.stamp = stamp
            msg.header.frame_id = "world"
            msg.pose.position.x, msg.pose.position.y = float(x), float(y)
            yaw = world.robot_theta[0] if key == "robot" else 0.0
            msg.pose.orientation.z, msg.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
            pubs[key].publish(msg)

    def integrate():
        # the robot moves with the last Twist it got (body frame, heading fixed at pi/2)
        if outcome[0] != RUNNING:
            return
        command = np.zeros((1, 2))
        if twists:
            yaw = world.robot_theta[0]
            bx, by = twists[-1].linear.x, twists[-1].linear.y
            command[0] = (
                bx * math.cos(yaw) - by * math.sin(yaw),
                bx * math.sin(yaw) + by * math.cos(yaw),
            )
        outcome[0] = int(world.step(command).outcome[0])
        publish_poses()

    publish_poses()
    mocap.create_timer(1.0 / RATE, integrate)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    executor.add_node(mocap)
    deadline = time.monotonic() + 60.0
    while outcome[0] == RUNNING and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    assert outcome[0] != RUNNING, "the episode did not end within 60 s"
    final = np.linalg.norm(world.robot_pos[0] - world.robot_goal[0])
    assert final < world_config.robot_radius, f"ended {final:.2f} m from the goal"
    assert any(abs(t.linear.x) + abs(t.linear.y) > 0.1 for t in twists)

    count = len(twists)
    node.stop_all()
    deadline = time.monotonic() + 5.0
    while len(twists) == count and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    assert twists[-1].linear.x == 0.0 and twists[-1].linear.y == 0.0
    executor.shutdown()
    node.destroy_node()
    mocap.destroy_node()


def agents_ids(agents: list[Agent]) -> list[str]:
    return [a.id for a in agents]
