"""The options of ``crowdplan train`` (a fresh run from a config, or ``--resume``).

Kept apart from the training code so that building the command line imports no torch, and so
that a sweep's trial parses exactly what a user's ``crowdplan train`` parses.
"""

from __future__ import annotations

import argparse


def add_train_args(parser: argparse.ArgumentParser) -> None:
    """--config, --seed, --humans, --episodes, the validation and update options, --out,
    --resume and the progress display."""
    parser.add_argument(
        "--config",
        help="YAML config, e.g. configs/lsa_dsac.yaml (default: none; required for a new run)",
    )
    parser.add_argument(
        "--seed", type=int, default=None, help="training seed (default: the config's seed)"
    )
    parser.add_argument(
        "--humans",
        type=int,
        default=None,
        help="number of humans, >= 0 (default: the config's world.humans)",
    )
    parser.add_argument(
        "--episodes",
        type=int,
        default=None,
        help="episode budget, >= 1 (default: the config's episodes)",
    )
    parser.add_argument(
        "--val-interval",
        type=int,
        default=None,
        help="episodes between validations, >= 1; may change on --resume "
        "(default: the config's val_interval)",
    )
    parser.add_argument(
        "--keep-validation-models",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="write the greedy policy of every validation to validation_models/ in the run "
        "folder, for python -m crowdplan.analysis.argmax_flips; may change on --resume "
        "(default: the config's keep_validation_models)",
    )
    parser.add_argument(
        "--keep-validation-networks",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="DSAC only: also write the actor, critics and temperature of every validation to "
        "validation_networks/, for python -m crowdplan.analysis.frozen_critic; may change on "
        "--resume (default: the config's keep_validation_networks)",
    )
    parser.add_argument(
        "--policy-average",
        type=int,
        default=None,
        metavar="K",
        help="validate, keep as best model and test the mean of the weights of the last K "
        "validated policies, >= 1; training is unchanged and it may change on --resume "
        "(default: the config's policy_average)",
    )
    parser.add_argument(
        "--parallel-update",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="critic and policy halves of each update on two threads (bitwise the same results; "
        "may change on --resume) (default: the config's dsac.parallel_update)",
    )
    parser.add_argument(
        "--lookahead",
        choices=("constant_velocity", "oracle"),
        default=None,
        help="value-network baselines: humans' next states in the one-step lookahead, propagated "
        "at constant velocity or queried from the simulator (CrowdNav) (default: the config's "
        "value_rl.lookahead)",
    )
    parser.add_argument(
        "--set",
        action="append",
        default=None,
        dest="overrides",
        metavar="KEY=VALUE",
        help="set one config key of a new run, as config.yaml writes it (e.g. dsac.lr=1e-4, "
        "world.scenario=square_crossing, dsac.q_hidden=[128,128]); repeatable; checked like the "
        "YAML file (default: the config's values)",
    )
    parser.add_argument("--out", default=None, help="run folder (default: runs/<name>-s<seed>)")
    parser.add_argument("--resume", action="store_true", help="continue the run in --out")
    parser.add_argument(
        "--no-progress", action="store_true", help="plain progress lines, no bar (as in a log file)"
    )
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress display")
