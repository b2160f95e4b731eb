"""Deployment runtime: no torch, velocity estimation, safety stops, goals in any direction,
several robots sharing one model, ORCA obstacle robots, drive limits."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("onnxruntime", reason="the onnx extra is not installed")

from crowdplan.deploy.drive import Command, Limits, diff_drive_command  # noqa: E402
from crowdplan.deploy.export import export_model  # noqa: E402
from crowdplan.deploy.manifest import MANIFEST_FILE  # noqa: E402
from crowdplan.deploy.onnx_policy import OnnxPolicy  # noqa: E402
from crowdplan.deploy.runtime import Agent, Runtime, RuntimeConfig  # noqa: E402
from crowdplan.deploy.velocity import VelocityEstimator  # noqa: E402


@pytest.fixture(scope="module")
def exported_lsa(tmp_path_factory):
    """The shipped model exported once per test session (shared by the deploy test files)."""
    folder = tmp_path_factory.getbasetemp() / "export-lsa-dsac-paper"
    if not (folder / MANIFEST_FILE).is_file():
        export_model("lsa-dsac-paper", folder)
    return folder


@pytest.fixture(scope="module")
def policy(exported_lsa):
    return OnnxPolicy(exported_lsa)


def test_runtime_imports_no_torch():
    code = (
        "import sys, crowdplan.deploy.runtime, crowdplan.deploy.ros2; "
        "assert 'torch' not in sys.modules, 'torch was imported'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_velocity_estimator_rejects_bad_samples():
    est = VelocityEstimator(tau=0.0, max_speed=3.0)
    assert est.update("a", 0.0, 0.0, 0.0, 0.0) == ""
    assert est.update("a", 0.1, 0.1, 0.0, 0.0) == ""
    assert est.tracks["a"].vx == pytest.approx(1.0)
    assert "did not advance" in est.update("a", 0.05, 0.2, 0.0, 0.0)
    assert "not finite" in est.update("a", 0.2, math.nan, 0.0, 0.0)
    assert "jumped" in est.update("a", 0.3, 5.0, 0.0, 0.0)
    assert est.update("a", 0.4, 5.1, 0.0, 0.0) == ""  # the jump is the new anchor
    assert est.tracks["a"].fault == "" and est.tracks["a"].vx == pytest.approx(1.0)


def test_velocity_filter_smooths_jitter():
    rng = np.random.default_rng(0)
    raw, filtered = VelocityEstimator(0.0), VelocityEstimator(0.5)
    errors = {0: [], 1: []}
    for k in range(200):
        t = k * 0.1 + rng.uniform(-0.01, 0.01)  # timing jitter
        x = 0.5 * t + rng.normal(0, 0.01)
        for i, est in enumerate((raw, filtered)):
            est.update("h", t, x, 0.0, 0.0)
            if k > 20:
                errors[i].append(est.tracks["h"].vx - 0.5)
    assert np.std(errors[1]) < 0.5 * np.std(errors[0])


def _scene(angle: float, humans: int = 5):
    """A robot 8 m from its goal in direction ``angle``, humans on a circle (static)."""
    c, s = math.cos(angle), math.sin(angle)
    start, goal = (-4 * c, -4 * s), (4 * c, 4 * s)
    agents = [Agent("r", "robot", goal=goal)]
    poses = [("r", *start, 0.0)]
    for k in range(humans):
        a = angle + 0.5 + 2 * math.pi * k / humans
        agents.append(Agent(f"h{k}", "human"))
        poses.append((f"h{k}", 4 * math.cos(a), 4 * math.sin(a), 0.0))
    return agents, poses, start


@pytest.mark.parametrize("angle", [math.pi / 2, 0.0, 2.0, -2.5])
def test_commands_rotate_with_the_scene(policy, angle):
    agents, poses, _ = _scene(angle)
    runtime = Runtime(policy, agents)
    runtime.frame(0.0, poses)
    command = runtime.step(0.0)["r"]
    assert not command.stop
    reference_agents, reference_poses, _ = _scene(math.pi / 2)
    reference = Runtime(policy, reference_agents)
    reference.frame(0.0, reference_poses)
    ref = reference.step(0.0)["r"]
    turn = angle - math.pi / 2
    expected = (
        ref.vx * math.cos(turn) - ref.vy * math.sin(turn),
        ref.vx * math.sin(turn) + ref.vy * math.cos(turn),
    )
    assert (command.vx, command.vy) == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("angle", [0.0, 2.4])
def test_robot_reaches_goals_in_any_direction(policy, angle):
    # (the shipped model was trained with 5 humans: it needs a crowd to behave)
    agents, poses, start = _scene(angle)
    runtime = Runtime(policy, agents)
    pos = np.array(start, dtype=float)
    for step in range(60):
        runtime.frame(step * 0.25, [("r", pos[0], pos[1], 0.0), *poses[1:]])
        command = runtime.step(step * 0.25)["r"]
        if command.reason == "at goal":
            break
        pos += 0.25 * np.array([command.vx, command.vy])
    assert np.linalg.norm(pos - agents[0].goal) < 0.3


def test_two_robots_and_an_obstacle_robot_swap_without_collision(policy):
    agents = [
        Agent("a", "robot", goal=(0.0, 4.0)),
        Agent("b", "robot", goal=(0.0, -4.0)),
        Agent("o", "obstacle", goal=(-4.0, 0.0)),
    ]
    pos = {"a": np.array([0.0, -4.0]), "b": np.array([0.05, 4.0]), "o": np.array([4.0, 0.0])}
    runtime = Runtime(policy, agents)
    closest = math.inf
    for step in range(100):
        t = step * 0.25
        runtime.frame(t, [(k, *p, 0.0) for k, p in pos.items()])
        commands = runtime.step(t)
        assert not any(c.stop for c in commands.values())
        for key, command in commands.items():
            pos[key] = pos[key] + 0.25 * np.array([command.vx, command.vy])
        keys = list(pos)
        closest = min(
            closest,
            min(np.linalg.norm(pos[i] - pos[j]) for i in keys for j in keys if i < j),
        )
    assert np.linalg.norm(pos["a"] - (0, 4)) < 0.3 and np.linalg.norm(pos["b"] - (0, -4)) < 0.3
    assert np.linalg.norm(pos["o"] - (-4, 0)) < 0.3
    assert closest > 0.6  # never touched (radii 0.3 each)


def test_safety_stops_and_bad_input_never_crash(policy, caplog):
    agents, poses, _ = _scene(math.pi / 2)
    runtime = Runtime(policy, agents, RuntimeConfig(max_pose_age=0.5))
    assert runtime.step(0.0)["r"].reason == "own pose: no pose received"
    runtime.frame(0.0, poses)
    assert not runtime.step(0.0)["r"].stop
    assert "own pose: pose is 0.60 s old" in runtime.step(0.6)["r"].reason
    runtime.pose("r", 0.6, *poses[0][1:])
    assert "neighbour 'h0': pose is 0.60 s old" in runtime.step(0.6)["r"].reason
    runtime.frame(1.0, poses)
    runtime.pose("h1", 1.1, math.nan, 0.0, 0.0)
    assert "not finite" in runtime.step(1.1)["r"].reason
    runtime.frame(1.2, poses)
    runtime.pose("h2", 0.9, 0.0, 0.0, 0.0)  # time going backwards
    assert "did not advance" in runtime.step(1.2)["r"].reason
    runtime.frame(1.3, [*poses, ("h3", 1.0, 1.0, 0.0)])  # duplicate id
    assert "duplicate" in runtime.step(1.3)["r"].reason
    runtime.frame(1.4, [*poses, ("ghost", 0.0, 0.0, 0.0), "garbage"])
    runtime.pose("h0", "t", [], {}, 0)
    runtime.pose(None, 1.4, 0.0, 0.0, 0.0)
    command = runtime.step(1.4)["r"]
    assert not command.stop
    assert "unknown agent 'ghost'" in caplog.text and "malformed" in caplog.text
    assert "stopping 'r'" in caplog.text


def test_more_humans_than_the_export_allows_is_a_stop(policy):
    agents, poses, _ = _scene(math.pi / 2, humans=policy.max_humans + 1)
    runtime = Runtime(policy, agents)
    runtime.frame(0.0, poses)
    assert "exported for" in runtime.step(0.0)["r"].reason


def test_diff_drive_turns_first_and_respects_limits():
    limits = Limits(max_speed=0.5, max_accel=1.0, max_omega=1.0, max_alpha=4.0)
    # the planned velocity points left of the heading: turn, drive slowly
    command = diff_drive_command(0.0, 1.0, 0.0, Command(), limits, 0.25)
    assert command.omega == pytest.approx(1.0) and command.v == pytest.approx(0.0)
    command = diff_drive_command(1.0, 0.0, 0.0, Command(), limits, 0.25)
    assert command.v == pytest.approx(0.25)  # acceleration limit: 1 m/s^2 * 0.25 s
    for _ in range(5):
        command = diff_drive_command(1.0, 0.0, 0.0, command, limits, 0.25)
    assert command.v == pytest.approx(0.5)  # speed limit
