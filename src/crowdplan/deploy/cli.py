"""The ``crowdplan export``, ``crowdplan deploy`` and ``crowdplan ros2`` subcommands."""

from __future__ import annotations

import argparse
import contextlib
import logging
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

from crowdplan.deploy.manifest import MANIFEST_FILE
from crowdplan.deploy.runtime_args import add_runtime_args, runtime_config
from crowdplan.world_args import add_world_args, world_from_args


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Register the deployment subcommands on the ``crowdplan`` parser."""
    from crowdplan.deploy.export import DEFAULT_MAX_HUMANS

    p = sub.add_parser("export", help="write a trained model as ONNX + manifest for deployment")
    p.add_argument("--model", required=True, help="run folder, model file or shipped name")
    p.add_argument("--out", required=True, help="folder for policy.onnx and manifest.json")
    p.add_argument(
        "--max-humans",
        type=int,
        default=DEFAULT_MAX_HUMANS,
        help=f"largest crowd the export is checked for (default {DEFAULT_MAX_HUMANS})",
    )
    p.set_defaults(func=cmd_export)

    p = sub.add_parser(
        "deploy", help="run the deployment runtime in closed loop against the simulator"
    )
    p.add_argument("--sim", action="store_true", help="the simulator stands in for the mocap")
    p.add_argument("--model", required=True, help="export folder, or a model (exported on the fly)")
    add_world_args(p)
    p.add_argument("--episodes", type=int, default=500)
    p.add_argument("--split", choices=("test", "val"), default="test")
    p.add_argument("--out", default=None, help="folder for summary.json and episodes.jsonl")
    add_runtime_args(p)
    g = p.add_argument_group("sensor model")
    g.add_argument("--position-noise", type=float, default=0.0, help="std of x, y noise (m)")
    g.add_argument("--yaw-noise", type=float, default=0.0, help="std of yaw noise (rad)")
    g.add_argument("--drift", type=float, default=0.0, help="random-walk drift (m / sqrt(s))")
    g.add_argument("--latency", type=float, default=0.0, help="pose latency (s)")
    g.add_argument("--drop-rate", type=float, default=0.0, help="share of samples lost")
    g.add_argument("--noise-seed", type=int, default=0)
    p.add_argument("--log-stops", action="store_true", help="log every safety stop and its reason")
    p.set_defaults(func=cmd_deploy)

    from crowdplan.deploy.ros2 import add_ros2_args

    p = sub.add_parser("ros2", help="ROS 2 node: mocap poses in, Twist commands out")
    add_ros2_args(p)
    add_runtime_args(p)
    p.set_defaults(func=cmd_ros2)


def cmd_export(args: argparse.Namespace) -> int:
    from crowdplan.deploy.export import export_model, verify_export

    manifest, path = export_model(args.model, args.out, args.max_humans)
    print(
        f"wrote {path} and {Path(args.out) / MANIFEST_FILE}: {manifest.algo} {manifest.network}, "
        f"{manifest.encoder or 'no'} encoder, "
        f"{manifest.kinematics}, {manifest.action_frame}-frame actions, outputs "
        f"{', '.join(manifest.outputs)}, up to {manifest.max_humans} humans"
    )
    if manifest.lookahead:
        print(f"actions: one-step {manifest.lookahead} lookahead, discount {manifest.gamma_step}")
    for n, diff in verify_export(args.model, args.out).items():
        print(
            f"onnxruntime vs torch, {n:>2} humans: "
            f"max |{manifest.outputs[0]} difference| {diff:.2e}"
        )
    return 0


def _export_folder(model: str, scratch: str) -> str:
    """``model`` itself if it is an export folder, else a fresh export of it in ``scratch``."""
    if (Path(model) / MANIFEST_FILE).is_file():
        return model
    from crowdplan.deploy.export import export_model

    export_model(model, scratch)
    return scratch


def cmd_deploy(args: argparse.Namespace) -> int:
    if not args.sim:
        raise ValueError(
            "only --sim runs here; real robots are driven by `crowdplan ros2` (docs/deploy.md)"
        )
    from crowdplan import evaluation
    from crowdplan.config import WorldConfig
    from crowdplan.deploy.onnx_policy import OnnxPolicy
    from crowdplan.deploy.simulate import (
        SensorModel,
        deployment_world,
        run_deployment,
        sensor_dict,
    )
    from crowdplan.policies import run_metadata

    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    sensor = SensorModel(
        position_noise=args.position_noise,
        yaw_noise=args.yaw_noise,
        drift=args.drift,
        latency=args.latency,
        drop_rate=args.drop_rate,
        seed=args.noise_seed,
    )
    with tempfile.TemporaryDirectory() as scratch:
        policy = OnnxPolicy(_export_folder(args.model, scratch))
    base = WorldConfig.from_dict(policy.manifest.world)
    config = deployment_world(world_from_args(args, policy, base), args.control_rate)
    seeds = (
        evaluation.validation_seeds(args.episodes)
        if args.split == "val"
        else evaluation.test_seeds(args.episodes)
    )
    start = time.perf_counter()
    with contextlib.nullcontext() if args.log_stops else _quiet_safety_stops():
        records, stats = run_deployment(
            policy, config, seeds, sensor, runtime_config(args, config.dt)
        )
    elapsed = time.perf_counter() - start
    summary = evaluation.summarize(records)
    title = (
        f"{policy.name} deployed in simulation on {config.scenario}, {config.humans} humans, "
        f"{len(seeds)} {args.split} cases"
    )
    print(evaluation.format_table(summary, title))
    print(f"{'safety stops':<20} {stats['safety_stop_share']:>8.3f}   (share of steps)")
    if args.out:
        meta = run_metadata(policy, config, seeds, args.split)
        meta.update(
            wall_seconds=elapsed,
            deploy={
                "sensor": sensor_dict(sensor),
                "runtime": {
                    "control_rate": 1.0 / config.dt,
                    "max_pose_age": args.max_pose_age,
                    "max_jump_speed": args.max_jump_speed,
                    "velocity_tau": args.velocity_tau,
                },
                **stats,
            },
        )
        evaluation.write_results(args.out, {**summary, **_stat_entries(stats)}, records, meta)
        print(f"wrote {Path(args.out) / 'summary.json'} and episodes.jsonl")
    return 0


def _stat_entries(stats: dict[str, float]) -> dict[str, dict]:
    return {key: {"value": value, "ci95": None} for key, value in stats.items()}


def cmd_ros2(args: argparse.Namespace) -> int:
    from crowdplan.deploy.ros2 import run_node

    return run_node(args)


@contextlib.contextmanager
def _quiet_safety_stops() -> Iterator[None]:
    """Errors only from the runtime's log for the duration; its level is restored after, so that
    a caller in the same process keeps its own logging."""
    logger = logging.getLogger("crowdplan.deploy")
    previous = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(previous)
