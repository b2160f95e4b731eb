"""ROS 2 node: ``geometry_msgs/PoseStamped`` per tracked agent in, ``geometry_msgs/Twist`` per
robot out at the control rate (``crowdplan ros2``; extra ``[ros]``, rclpy is imported lazily).

Topics are patterns with ``{id}``: the defaults ``/{id}/pose`` (poses, in the mocap's world frame),
``/{id}/cmd_vel`` (commands) and ``/{id}/goal`` (new goals as PoseStamped) fit e.g. a VRPN or
OptiTrack bridge with ``--pose-topic /vrpn_mocap/{id}/pose``. Goals are also ROS parameters
``goal_<id>`` (``[x, y]``, settable at run time). Twists are in the robot's body frame: holonomic
robots get ``linear.x, linear.y``; differential-drive robots ``linear.x`` and ``angular.z``. On
shutdown every robot gets a zero Twist.
"""

from __future__ import annotations

import argparse
import math
from typing import Any

from crowdplan.deploy.drive import DRIVES, Command, Limits, to_body
from crowdplan.deploy.runtime import Agent, Runtime

ROS_MISSING = (
    "rclpy is not installed: install the ROS 2 wheels with `pip install -e .[ros]` "
    "(ros-rclpy, ros-geometry-msgs, ros-rmw-fastrtps-cpp)"
)


def add_ros2_args(p: argparse.ArgumentParser) -> None:
    """Command-line options of ``crowdplan ros2``."""
    p.add_argument("--model", required=True, help="export folder (crowdplan export)")
    p.add_argument(
        "--robot",
        action="append",
        default=[],
        metavar="ID[:GX,GY]",
        help="a robot driven by the model, with its goal (repeatable)",
    )
    p.add_argument(
        "--obstacle",
        action="append",
        default=[],
        metavar="ID:GX,GY",
        help="an obstacle robot driven by ORCA to its goal (repeatable)",
    )
    p.add_argument("--human", action="append", default=[], metavar="ID", help="(repeatable)")
    p.add_argument("--drive", choices=DRIVES, default="holonomic", help="drive of every robot")
    p.add_argument("--human-radius", type=float, default=0.3)
    p.add_argument("--pose-topic", default="/{id}/pose")
    p.add_argument("--cmd-topic", default="/{id}/cmd_vel")
    p.add_argument("--goal-topic", default="/{id}/goal")
    p.add_argument("--max-speed", type=float, default=math.inf, help="m/s")
    p.add_argument("--max-accel", type=float, default=math.inf, help="m/s^2")
    p.add_argument("--max-omega", type=float, default=math.inf, help="rad/s")
    p.add_argument("--max-alpha", type=float, default=math.inf, help="rad/s^2")


def parse_agent(text: str, need_goal: bool) -> tuple[str, tuple[float, float] | None]:
    """``"id:gx,gy"`` -> (id, goal); ``"id"`` -> (id, None) unless a goal is required."""
    key, sep, goal = text.partition(":")
    if not key or (need_goal and not sep):
        raise ValueError(f"{text!r}: expected ID:GX,GY")
    if not sep:
        return key, None
    try:
        gx, gy = (float(v) for v in goal.split(","))
    except ValueError as error:
        raise ValueError(f"{text!r}: expected ID:GX,GY with numbers") from error
    return key, (gx, gy)


def agents_from_args(args: argparse.Namespace, radius: float, v_pref: float) -> list[Agent]:
    """The tracked agents of the command line (robots get the model's radius and v_pref)."""
    limits = Limits(args.max_speed, args.max_accel, args.max_omega, args.max_alpha)
    agents = []
    for text in args.robot:
        key, goal = parse_agent(text, need_goal=False)
        agents.append(Agent(key, "robot", radius, v_pref, goal, args.drive, limits))
    for text in args.obstacle:
        key, goal = parse_agent(text, need_goal=True)
        agents.append(Agent(key, "obstacle", radius, v_pref, goal, args.drive, limits))
    agents += [Agent(key, "human", args.human_radius) for key in args.human]
    if not any(a.role != "human" for a in agents):
        raise ValueError("give at least one --robot or --obstacle")
    return agents


def yaw_of(q: Any) -> float:
    """Yaw (rad) of a quaternion message."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def twist_of(command: Command, drive: str, yaw: float, twist: Any) -> Any:
    """Fill a ``geometry_msgs/Twist`` with a command in the robot's body frame."""
    if drive == "holonomic":
        twist.linear.x, twist.linear.y = to_body(command.vx, command.vy, yaw)
    else:
        twist.linear.x, twist.angular.z = command.v, command.omega
    return twist


def build_node(
    runtime: Runtime,
    pose_topic: str = "/{id}/pose",
    cmd_topic: str = "/{id}/cmd_vel",
    goal_topic: str = "/{id}/goal",
    name: str = "crowdplan",
):
    """A started rclpy node driving ``runtime`` (``rclpy.init`` must have been called)."""
    from geometry_msgs.msg import PoseStamped, Twist
    from rcl_interfaces.msg import SetParametersResult
    from rclpy.node import Node
    from rclpy.parameter import Parameter

    class CrowdplanNode(Node):
        """Subscribes to poses and goals, publishes Twists on a timer at the control rate."""

        def __init__(self):
            super().__init__(name)
            self.runtime = runtime
            self.publishers_ = {}
            for agent in runtime.agents.values():
                self.create_subscription(
                    PoseStamped,
                    pose_topic.format(id=agent.id),
                    lambda msg, key=agent.id: self._on_pose(key, msg),
                    10,
                )
                if agent.role == "human":
                    continue
                self.publishers_[agent.id] = self.create_publisher(
                    Twist, cmd_topic.format(id=agent.id), 10
                )
                self.create_subscription(
                    PoseStamped,
                    goal_topic.format(id=agent.id),
                    lambda msg, key=agent.id: self._set_goal(
                        key, msg.pose.position.x, msg.pose.position.y
                    ),
                    10,
                )
                goal = runtime.goals[agent.id]
                self.declare_parameter(
                    f"goal_{agent.id}",
                    list(goal) if goal is not None else [math.nan, math.nan],
                )
            self.add_on_set_parameters_callback(self._on_parameters)
            self.create_timer(runtime.config.period, self._tick)

        def _now(self) -> float:
            return self.get_clock().now().nanoseconds * 1e-9

        def _on_pose(self, key: str, msg: Any) -> None:
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            p = msg.pose.position
            # bridges that leave the stamp empty get the arrival time
            self.runtime.pose(key, stamp or self._now(), p.x, p.y, yaw_of(msg.pose.orientation))

        def _set_goal(self, key: str, x: float, y: float) -> bool:
            try:
                self.runtime.set_goal(key, float(x), float(y))
            except ValueError as error:
                self.get_logger().warning(str(error))
                return False
            self.get_logger().info(f"goal of {key!r}: ({x:.2f}, {y:.2f})")
            return True

        def _on_parameters(self, params: list) -> Any:
            for param in params:
                key = param.name.removeprefix("goal_")
                value = param.value
                if param.type_ != Parameter.Type.DOUBLE_ARRAY or len(value) != 2:
                    return SetParametersResult(successful=False, reason="goal must be [x, y]")
                finite = math.isfinite(value[0]) and math.isfinite(value[1])
                if finite and not self._set_goal(key, value[0], value[1]):
                    return SetParametersResult(successful=False, reason="bad goal")
            return SetParametersResult(successful=True)

        def _tick(self) -> None:
            for key, command in self.runtime.step(self._now()).items():
                self._publish(key, command)

        def _publish(self, key: str, command: Command) -> None:
            track = self.runtime.estimator.tracks.get(key)
            yaw = track.yaw if track is not None else 0.0
            agent = self.runtime.agents[key]
            self.publishers_[key].publish(twist_of(command, agent.drive, yaw, Twist()))

        def stop_all(self) -> None:
            """Send every robot a zero Twist."""
            for key in self.publishers_:
                self._publish(key, Command(stop=True, reason="shutdown"))

    return CrowdplanNode()


def run_node(args: argparse.Namespace) -> int:
    """``crowdplan ros2``: run the node until Ctrl-C, then stop the robots."""
    try:
        import rclpy
    except ImportError as error:
        raise ValueError(f"{ROS_MISSING} ({error})") from error
    from crowdplan.deploy.onnx_policy import OnnxPolicy
    from crowdplan.deploy.runtime_args import runtime_config

    policy = OnnxPolicy(args.model)
    manifest = policy.manifest
    runtime = Runtime(
        policy,
        agents_from_args(args, manifest.robot_radius, manifest.v_pref),
        runtime_config(args, manifest.dt),
    )
    rclpy.init()
    node = build_node(runtime, args.pose_topic, args.cmd_topic, args.goal_topic)
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.stop_all()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
