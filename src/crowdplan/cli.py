"""The ``crowdplan`` command: eval, render, train, report (docs/cli.md).

Exit status: 0 done, 1 failed while running (e.g. a disk error), 2 bad input (refused before any
work), 130 interrupted (Ctrl-C), 141 output pipe closed (``crowdplan eval | head``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from crowdplan import __version__
from crowdplan.command import run_command
from crowdplan.train_args import add_train_args
from crowdplan.world_args import add_world_args, world_from_args

if TYPE_CHECKING:
    from crowdplan.config import WorldConfig
    from crowdplan.policy import Policy

RESULT_FILES = ("summary.json", "episodes.jsonl")
SPLIT_HELP = "test: cases 0..499 = seeds 1000..1499; val: cases 0..999 = seeds 0..999"


def _add_policy_args(parser: argparse.ArgumentParser) -> None:
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--policy",
        default=None,
        help="built-in planner: orca or straight (default: orca unless --model)",
    )
    group.add_argument(
        "--model",
        default=None,
        help="trained model: a model file (model.pt, best_model.pt, final_model.pt), a run "
        "folder (its best_model.pt) or a shipped model name, e.g. lsa-dsac (default: none)",
    )
    parser.add_argument(
        "--shield",
        type=float,
        default=None,
        metavar="SECONDS",
        help="safety shield for --model policies that rank the 81 actions: drop actions predicted "
        "to hit a human within SECONDS (constant velocities; docs/generalization.md); 0: off "
        "(default: the model's own, e.g. 2.5 s for lsa-dsac, none for the paper's models)",
    )
    parser.add_argument(
        "--lookahead",
        choices=("constant_velocity", "oracle"),
        default=None,
        help="value-network models (cadrl, lstm-rl, sarl): the humans' next states in the "
        "one-step lookahead, constant velocity or the simulator's true ones (CrowdNav's "
        "protocol); recorded in summary.json (default: the model's own)",
    )
    parser.add_argument(
        "--lookahead-precision",
        choices=("float32", "bfloat16"),
        default=None,
        help="value-network models: run the lookahead's value network in float32 (default) or "
        "bfloat16 (CPU autocast; about 2x faster where the CPU has bfloat16 instructions, and "
        "some greedy actions change: docs/benchmarks.md); recorded in summary.json",
    )
    parser.add_argument(
        "--lookahead-compile",
        action="store_true",
        help="value-network models: run the lookahead's value network through torch.compile "
        "(needs a C++ compiler; the first decision compiles for seconds, then decisions are "
        "faster: docs/benchmarks.md); recorded in summary.json",
    )


def _policy_from_args(args: argparse.Namespace) -> tuple[Policy, WorldConfig]:
    """The policy and its world config named by the policy arguments of ``eval`` and ``render``."""
    from crowdplan.policies import load_policy

    return load_policy(
        args.policy,
        args.model,
        args.shield,
        args.lookahead,
        args.lookahead_precision,
        args.lookahead_compile,
    )


def _add_output_args(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument(
        "--force", action="store_true", help=f"replace {what} that already exist(s) in --out"
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress display")


def cmd_eval(args: argparse.Namespace) -> int:
    from crowdplan import evaluation
    from crowdplan.io import check_output_folder
    from crowdplan.policies import run_metadata
    from crowdplan.progress import Progress

    if args.episodes is not None and args.episodes < 1:
        raise ValueError(f"--episodes must be >= 1, got {args.episodes}")
    seeds = evaluation.SPLITS[args.split].seeds(args.episodes)
    if args.batch_size < 1:
        raise ValueError(f"--batch-size must be >= 1, got {args.batch_size}")
    run_episodes = evaluation.run_episodes
    if args.backend != "local" or args.shards > 1:
        from crowdplan.backends.shards import sharded_runner

        run_episodes = sharded_runner(args.backend, args.shards, args.address)
    if args.record and not args.out:
        raise ValueError("--record needs --out DIR (the folder that gets records.npz)")
    if args.out:
        files = RESULT_FILES + (("records.npz",) if args.record else ())
        check_output_folder(args.out, files, args.force)
    policy, base = _policy_from_args(args)
    config = world_from_args(args, policy, base)

    records: list = []

    def report_batch(batch: list) -> None:
        records.extend(batch)
        progress.update(
            len(batch),
            success=sum(r.outcome == "goal" for r in records) / len(records),
            reward=sum(r.discounted_return for r in records) / len(records),
        )

    start = time.perf_counter()
    with Progress(len(seeds), f"eval {policy.name}", quiet=args.quiet) as progress:
        run_episodes(
            policy,
            config,
            seeds,
            batch_size=args.batch_size,
            record_traces=args.record,
            on_batch=report_batch,
        )
    elapsed = time.perf_counter() - start
    summary = evaluation.summarize(records, config)
    if args.out:
        meta = run_metadata(policy, config, seeds, args.split)
        meta["wall_seconds"] = elapsed
        meta["default_world"] = args.default_world
        if args.record:
            from crowdplan.evaluation_records import write_records

            write_records(Path(args.out) / "records.npz", records)
        evaluation.write_results(args.out, summary, records, meta)
        note = f"wrote {Path(args.out) / 'summary.json'} and {Path(args.out) / 'episodes.jsonl'}"
        if args.record:
            note += f" and {Path(args.out) / 'records.npz'}"
    else:
        note = "nothing written (no --out): pass --out DIR to keep summary.json and episodes.jsonl"
    title = (
        f"{policy.name} on {config.scenario}, {config.humans} humans, "
        f"{len(seeds)} {args.split} cases"
    )
    print(evaluation.format_table(summary, title))
    sys.stdout.flush()  # a closed pipe shows here, after the results were written
    print(note, file=sys.stderr)
    return 0


def cmd_render(args: argparse.Namespace) -> int:
    from crowdplan import evaluation
    from crowdplan.io import check_output_file
    from crowdplan.sim.render import RENDER_SUFFIXES, save_render

    if args.case < 0:
        raise ValueError(f"--case must be >= 0, got {args.case}")
    seed = evaluation.SPLITS[args.split].seed(args.case)
    check_output_file(args.out, args.force, RENDER_SUFFIXES)
    policy, base = _policy_from_args(args)
    config = world_from_args(args, policy, base)
    (record,) = evaluation.run_episodes(policy, config, [seed], record_traces=True)
    title = f"{policy.name}, {args.split} case {args.case}: {record.outcome} at {record.time:.2f} s"
    save_render(record.trace, args.out, title=title)
    print(title)
    sys.stdout.flush()
    print(f"wrote {args.out}", file=sys.stderr)
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from crowdplan.training import train_from_cli

    return train_from_cli(args)


def cmd_report(args: argparse.Namespace) -> int:
    from crowdplan.analysis.markdown_fill import fill_markdown
    from crowdplan.analysis.report import report

    if args.out:
        if args.folders or args.fill or args.paper or args.seeds:
            raise ValueError(
                "--out makes the report from --results: give no folders, --fill, --paper or --seeds"
            )
        from crowdplan.analysis.html_report import build_report

        page = build_report(args.out, args.results)
        print(f"wrote {page} and {page.parent / 'tables.md'}")
        return 0
    if args.seeds:
        if args.fill or args.paper:
            raise ValueError(
                "--seeds prints the table of the run folders given: no --fill, --paper"
            )
        from crowdplan.analysis.seed_targets import seed_table

        print(seed_table(args.folders), end="")
        return 0
    if args.paper:
        if args.fill:
            raise ValueError("--paper prints the tables of the METHOD=DIR given: no --fill")
        from crowdplan.analysis.paper_tables import paper_report

        print(paper_report(args.folders), end="")
        return 0
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
        prog="crowdplan",
        description="Robot navigation among dense crowds.",
        epilog="exit status: 0 done, 1 failed while running, 2 bad input (nothing was run), "
        "130 interrupted, 141 output pipe closed. More: docs/cli.md",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("eval", help="evaluate a planner on the fixed test (or validation) cases")
    _add_policy_args(p)
    add_world_args(p)
    p.add_argument(
        "--episodes",
        type=int,
        default=None,
        help="how many cases, the split's first: 1..500 (test) or 1..1000 (val) "
        "(default: 500 (test) or 100 (val), the cases runs validate on by default)",
    )
    p.add_argument(
        "--split", choices=("test", "val"), default="test", help=f"{SPLIT_HELP} (default: test)"
    )
    p.add_argument(
        "--batch-size",
        type=int,
        default=100,
        help="environments stepped together, >= 1; results do not depend on it "
        "(default: %(default)s)",
    )
    p.add_argument(
        "--backend",
        choices=("local", "ray"),
        default="local",
        help="where the shards run: local processes or Ray (default: %(default)s)",
    )
    p.add_argument(
        "--shards",
        type=int,
        default=1,
        help="split the cases into this many jobs, >= 1; the results are the same "
        "(default: %(default)s, in this process)",
    )
    p.add_argument(
        "--address",
        default=None,
        help="Ray cluster for --backend ray: auto, ray://HOST:PORT or HOST:PORT "
        "(default: none, a private local Ray instance)",
    )
    p.add_argument(
        "--out",
        default=None,
        help="folder for summary.json and episodes.jsonl, made if missing "
        "(default: none, only the table is printed)",
    )
    p.add_argument(
        "--record",
        action="store_true",
        help="also write records.npz: every episode's trajectory, actions, d_min and attention "
        "(docs/report.md)",
    )
    _add_output_args(p, "summary.json and episodes.jsonl")
    p.set_defaults(func=cmd_eval)

    p = sub.add_parser("render", help="draw one episode to a .gif or .png")
    _add_policy_args(p)
    add_world_args(p)
    p.add_argument(
        "--case",
        type=int,
        default=0,
        help="case k of the split: 0..499 (test, seed 1000 + k) or 0..999 (val, seed k) "
        "(default: %(default)s)",
    )
    p.add_argument(
        "--split", choices=("test", "val"), default="test", help=f"{SPLIT_HELP} (default: test)"
    )
    p.add_argument(
        "--out", required=True, help="file to write: .gif (animation) or .png (whole episode)"
    )
    _add_output_args(p, "the --out file")
    p.set_defaults(func=cmd_render)

    p = sub.add_parser(
        "train", help="train a planner (DSAC, value RL, A2C, DQN) from a YAML config"
    )
    add_train_args(p)
    p.set_defaults(func=cmd_train)

    p = sub.add_parser(
        "report", help="HTML report (--out) or markdown tables (--fill) from result and run folders"
    )
    p.add_argument(
        "folders",
        nargs="*",
        help="folders searched for summary.json and runs; with --paper: METHOD=DIR words; "
        "with --seeds: training run folders",
    )
    p.add_argument(
        "--paper",
        action="store_true",
        help="the paper's tables II, VI, VII, VIII and IX with its values beside ours, from "
        "METHOD=DIR words (a method named again: one more seed; METHOD?=DIR: a run that may not "
        "be trained yet); a '<!-- crowdplan report --paper ... -->' block of --fill holds them",
    )
    p.add_argument(
        "--seeds",
        action="store_true",
        help="per seed and across seeds, whether the training run folders given (one preset's "
        "seeds) reach the training targets: test success, time to goal, stable validations "
        "(docs/training.md); a '<!-- crowdplan report --seeds ... -->' block of --fill holds it",
    )
    p.add_argument(
        "--fill",
        metavar="FILE.md",
        help="regenerate the '<!-- crowdplan report DIR ... -->' blocks of a markdown file "
        "(default: none, print the tables of the given folders)",
    )
    p.add_argument(
        "--out",
        metavar="DIR",
        help="write the evaluation report: DIR/index.html (self-contained) and DIR/tables.md, "
        "from the result folders under --results (docs/report.md) (default: none)",
    )
    p.add_argument(
        "--results",
        default="results",
        help="the result folders the --out report reads (default: %(default)s)",
    )
    p.set_defaults(func=cmd_report)

    from crowdplan.deploy.cli import add_commands as add_deploy_commands

    add_deploy_commands(sub)
    from crowdplan.sweep_cli import add_command as add_sweep_command

    add_sweep_command(sub)
    _show_defaults(parser)
    return parser


def _show_defaults(parser: argparse.ArgumentParser) -> None:
    """Add "(default: ...)" to the help of every option of every command that takes a value and
    does not state its default itself (required options say so instead)."""
    commands = [parser]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            commands += action.choices.values()
    for command in commands:
        for action in command._actions:
            if not action.option_strings or action.nargs == 0 or "default" in (action.help or ""):
                continue
            if action.required:
                note = "required"
            elif action.default in (None, []):
                note = "default: none"
            else:
                note = "default: %(default)s"
            action.help = f"{action.help} ({note})" if action.help else f"({note})"


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``crowdplan`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    return run_command(args.func, args, f"crowdplan {args.command}")


if __name__ == "__main__":
    sys.exit(main())
