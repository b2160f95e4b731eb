"""Command-line options that choose the world a planner is evaluated in (eval, render, deploy)."""

from __future__ import annotations

import argparse
import sys

from crowdplan.config import SCENARIOS, WorldConfig


def add_world_args(parser: argparse.ArgumentParser) -> None:
    """--scenario, --humans, --option KEY=VALUE and --default-world."""
    parser.add_argument(
        "--scenario",
        default=None,
        choices=SCENARIOS,
        help="crowd scenario (default: the model's training scenario, else circle_crossing)",
    )
    parser.add_argument(
        "--humans",
        type=int,
        default=None,
        help="number of humans, >= 0 (default: the model's training world, else 5)",
    )
    parser.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="world option, repeatable, e.g. visible_robot=true, kinematics=unicycle; keys and "
        "ranges: crowdplan.config.WorldConfig (default: the model's training world, else the "
        "WorldConfig defaults)",
    )
    parser.add_argument(
        "--default-world",
        action="store_true",
        help="start from the default world (the paper's) instead of the model's training world; "
        "the model keeps its kinematics, action frame and speeds (default: off)",
    )


def _warn(command: str, message: str) -> None:
    print(f"crowdplan {command}: warning: {message}", file=sys.stderr)


def world_from_args(args: argparse.Namespace, policy, base: WorldConfig) -> WorldConfig:
    """The model's (or default) world with the command line's scenario, humans and options;
    warns once per option that differs from the world a trained model was trained in (one line
    in all with ``--default-world``, which asks for another world on purpose)."""
    from crowdplan.policies import check_compatible, parse_options, world_differences

    if args.default_world:
        base = base.paper_world()
    changes = parse_options(args.option, own_flags=("scenario", "humans"))
    if args.scenario is not None:
        changes["scenario"] = args.scenario
    if args.humans is not None:
        changes["humans"] = args.humans
    config = base.replace(**changes)
    check_compatible(policy, config)
    differences = world_differences(policy, config)
    if args.default_world and differences:
        # asked for explicitly: one line that names what differs, not one line per option
        _warn(
            args.command,
            f"model {policy.name} was trained in another world ({', '.join(differences)} "
            "differ); --default-world evaluates it in the paper's world",
        )
        return config
    for key, (trained, now) in differences.items():
        _warn(
            args.command,
            f"model {policy.name} was trained with {key}={trained}, this world has {key}={now}",
        )
    return config
