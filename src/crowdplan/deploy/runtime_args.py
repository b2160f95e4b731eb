"""Command-line options of the deployment runtime (``crowdplan deploy`` and ``crowdplan ros2``)."""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # the runtime (onnxruntime, numba) is imported only by the commands that run it
    from crowdplan.deploy.runtime import RuntimeConfig


def add_runtime_args(p: argparse.ArgumentParser) -> None:
    """Control rate, pose staleness and jump limits, velocity filter."""
    g = p.add_argument_group("runtime")
    g.add_argument(
        "--control-rate", type=float, default=None, help="Hz (default: 1 / the model's dt)"
    )
    g.add_argument("--max-pose-age", type=float, default=0.5, help="stale after this (s)")
    g.add_argument("--max-jump-speed", type=float, default=5.0, help="faster is a jump (m/s)")
    g.add_argument("--velocity-tau", type=float, default=0.0, help="velocity filter (s)")


def runtime_config(args: argparse.Namespace, dt: float) -> RuntimeConfig:
    """The runtime settings of the command line (control rate default: the model's 1 / dt)."""
    from crowdplan.deploy.runtime import RuntimeConfig

    return RuntimeConfig(
        control_rate=args.control_rate or 1.0 / dt,
        max_pose_age=args.max_pose_age,
        max_jump_speed=args.max_jump_speed,
        velocity_tau=args.velocity_tau,
    )
