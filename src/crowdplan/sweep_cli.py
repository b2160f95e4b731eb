"""``crowdplan sweep``: a grid of settings x seeds as resumable training runs, locally or on Ray."""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys

from crowdplan.backends import BACKENDS, JobInterrupted
from crowdplan.command import EXIT_INTERRUPTED


def add_command(sub: argparse._SubParsersAction) -> None:
    """Register ``sweep`` among the ``crowdplan`` subcommands."""
    p = sub.add_parser(
        "sweep",
        help="train a grid of settings x seeds, one resumable run folder per trial",
        description="Re-running the same command skips finished trials and resumes stopped "
        "ones from their checkpoints. Layout of --out: crowdplan.backends.sweep; docs/scaling.md.",
    )
    p.add_argument("--config", required=True, help="base YAML config, e.g. configs/lsa_dsac.yaml")
    p.add_argument(
        "--seeds", default="0", help="training seeds: 0-9 (inclusive), 3 or 0,2,5 (default: 0)"
    )
    p.add_argument(
        "--set",
        dest="grid",
        action="append",
        default=[],
        metavar="KEY=V1,V2",
        help="repeatable; a config key (dotted, as in config.yaml, e.g. dsac.lr) and its values; "
        "the grid is every combination (default: none, the base config only)",
    )
    p.add_argument("--out", required=True, help="sweep folder (made if missing)")
    p.add_argument(
        "--backend", choices=BACKENDS, default="local", help="where trials run (default: local)"
    )
    p.add_argument(
        "--address",
        default=None,
        help="Ray cluster: auto, ray://HOST:PORT or HOST:PORT (default: none, a private local "
        "Ray instance)",
    )
    p.add_argument(
        "--workers",
        type=int,
        default=None,
        help="trials at once (default: local: CPUs // threads per trial; ray: as many as the "
        "cluster schedules)",
    )
    p.add_argument(
        "--threads-per-trial",
        type=int,
        default=None,
        help="torch threads (and CPUs reserved) per trial, >= 1 (default: the config's "
        "torch_threads)",
    )
    p.set_defaults(func=cmd_sweep)


def cmd_sweep(args: argparse.Namespace) -> int:
    from crowdplan.backends import make_backend
    from crowdplan.backends.sweep import expand, format_summary, parse_grid, parse_seeds, run_sweep
    from crowdplan.training import load_config

    if args.threads_per_trial is not None and args.threads_per_trial < 1:
        raise ValueError(f"--threads-per-trial must be >= 1, got {args.threads_per_trial}")
    base = load_config(args.config).to_dict()
    threads = args.threads_per_trial or base["torch_threads"]
    trials = expand(base, parse_grid(args.grid, base), parse_seeds(args.seeds), threads)
    if args.backend == "local" and args.address is not None:
        raise ValueError("--address applies to --backend ray only")
    if args.address is not None:  # an address that does not answer is refused before any work
        from crowdplan.backends.ray import cluster_address

        cluster_address(args.address)
    try:
        with _sigterm_as_interrupt():
            summary = run_sweep(
                args.out,
                base,
                trials,
                threads,
                lambda: make_backend(args.backend, args.workers, args.address),
                report=lambda line: print(line, file=sys.stderr, flush=True),
            )
    except JobInterrupted as stopped:  # a signal sent to one trial's worker process
        print(
            f"crowdplan sweep: {stopped}; the other running trials were stopped too. Run the "
            "same command again to resume them",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    print(format_summary(summary), end="")
    failed = [name for row in summary["settings"] for name in row["failed"]]
    if failed:
        print(
            f"crowdplan sweep: {len(failed)} trial(s) failed: {', '.join(failed)}", file=sys.stderr
        )
        return 1
    print(f"wrote {args.out}/summary.json and summary.md", file=sys.stderr)
    return 0


@contextlib.contextmanager
def _sigterm_as_interrupt():
    """While active, SIGTERM stops the sweep as Ctrl-C does: the running trials are told to stop
    and save their checkpoints, and the sweep waits for them before it exits (status 130). A
    second SIGTERM kills the sweep at once (its trials still stop on their own)."""

    def interrupt(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
