"""The ``crowdplan`` command: eval, render, train."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from crowdplan.config import SCENARIOS


def _add_world_args(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenario", default="circle_crossing", choices=SCENARIOS)
    parser.add_argument("--humans", type=int, default=None, help="number of humans (default 5)")
    parser.add_argument(
        "--option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="world option, e.g. visible_robot=true, kinematics=unicycle (repeatable)",
    )


def _add_policy_args(parser: argparse.ArgumentParser) -> None:
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--policy", default=None, help="built-in planner: orca")
    group.add_argument(
        "--model", default=None, help="trained model: a run folder, checkpoint or shipped name"
    )


def _world_config(args: argparse.Namespace, policy, base):
    """The model's (or default) world with the command line's scenario, humans and options."""
    from crowdplan.policies import check_compatible, parse_options

    changes = {"scenario": args.scenario, **parse_options(args.option)}
    if args.humans is not None:
        changes["humans"] = args.humans
    config = base.replace(**changes)
    check_compatible(policy, config)
    return config


def cmd_eval(args: argparse.Namespace) -> int:
    from crowdplan import evaluation
    from crowdplan.policies import load_policy, run_metadata

    policy, base = load_policy(args.policy, args.model)
    config = _world_config(args, policy, base)
    if args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    if args.batch_size < 1:
        raise ValueError(f"--batch-size must be >= 1, got {args.batch_size}")
    seeds = (
        evaluation.validation_seeds(args.episodes)
        if args.split == "val"
        else evaluation.test_seeds(args.episodes)
    )
    start = time.perf_counter()
    records = evaluation.run_episodes(policy, config, seeds, batch_size=args.batch_size)
    elapsed = time.perf_counter() - start
    summary = evaluation.summarize(records)
    title = (
        f"{policy.name} on {config.scenario}, {config.humans} humans, "
        f"{len(seeds)} {args.split} cases"
    )
    print(evaluation.format_table(summary, title))
    if args.out:
        meta = run_metadata(policy, config, seeds, args.split)
        meta["wall_seconds"] = elapsed
        evaluation.write_results(args.out, summary, records, meta)
        print(f"wrote {Path(args.out) / 'summary.json'} and episodes.jsonl")
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    from crowdplan import evaluation
    from crowdplan.policies import load_policy
    from crowdplan.sim.render import save_render

    policy, base = load_policy(args.policy, args.model)
    config = _world_config(args, policy, base)
    if args.case < 0:
        raise ValueError(f"--case must be >= 0, got {args.case}")
    seed = (
        evaluation.VAL_SEED_BASE if args.split == "val" else evaluation.TEST_SEED_BASE
    ) + args.case
    (record,) = evaluation.run_episodes(policy, config, [seed], record_traces=True)
    title = f"{policy.name}, {args.split} case {args.case}: {record.outcome} at {record.time:.2f} s"
    save_render(record.trace, args.out, title=title)
    print(f"{title}\nwrote {args.out}")
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from crowdplan.training import train_from_cli

    return train_from_cli(args)


def cmd_report(args: argparse.Namespace) -> int:
    from crowdplan.analysis.report import fill_markdown, report

    if args.fill:
        if args.folders:
            raise ValueError("give either result folders or --fill FILE.md, not both")
        print(f"filled {fill_markdown(args.fill)} report block(s) of {args.fill}")
        return 0
    if not args.folders:
        raise ValueError("give result folders to report on, or --fill FILE.md")
    print(report(args.folders), end="")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="crowdplan", description="Robot navigation among dense crowds."
    )
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("eval", help="evaluate a planner on the fixed test (or validation) cases")
    _add_policy_args(p)
    _add_world_args(p)
    p.add_argument("--episodes", type=int, default=500)
    p.add_argument("--split", choices=("test", "val"), default="test")
    p.add_argument("--batch-size", type=int, default=100, help="environments stepped together")
    p.add_argument("--out", default=None, help="folder for summary.json and episodes.jsonl")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("render", help="draw one episode to a .gif or .png")
    _add_policy_args(p)
    _add_world_args(p)
    p.add_argument("--case", type=int, default=0, help="test case k (seed 1000 + k)")
    p.add_argument("--split", choices=("test", "val"), default="test")
    p.add_argument("--out", required=True, help="output file, .gif or .png")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser("train", help="train a DSAC planner from a YAML config")
    p.add_argument("--config", help="YAML config, e.g. configs/lsa_dsac.yaml")
    p.add_argument("--seed", type=int, default=None)
    p.add_argument("--humans", type=int, default=None)
    p.add_argument("--episodes", type=int, default=None)
    p.add_argument(
        "--val-interval",
        type=int,
        default=None,
        help="episodes between validations (may change on --resume)",
    )
    p.add_argument(
        "--parallel-update",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="critic and policy halves of each update on two threads (bitwise the same results; "
        "may change on --resume)",
    )
    p.add_argument("--out", default=None, help="run folder (default runs/<name>-s<seed>)")
    p.add_argument("--resume", action="store_true", help="continue the run in --out")
    p.add_argument("--no-progress", action="store_true", help="plain log lines, no progress bar")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("report", help="markdown tables from result and run folders")
    p.add_argument("folders", nargs="*", help="folders searched for summary.json and runs")
    p.add_argument(
        "--fill",
        metavar="FILE.md",
        help="regenerate the '<!-- crowdplan report DIR ... -->' blocks of a markdown file",
    )
    p.set_defaults(func=cmd_report)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``crowdplan`` console script."""
    import torch

    torch.set_num_threads(1)
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, TypeError, FileNotFoundError) as error:
        print(f"crowdplan {args.command}: error: {error}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
