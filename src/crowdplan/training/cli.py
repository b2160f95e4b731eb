"""``crowdplan train``: a fresh run from a YAML config, or ``--resume`` of a run folder."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path
from typing import Any

import yaml

from crowdplan import evaluation
from crowdplan.command import run_command
from crowdplan.config_overrides import assign, parse_assignments
from crowdplan.io import atomic_write
from crowdplan.train_args import add_train_args
from crowdplan.training.config import TrainConfig, config_from_dict, load_config
from crowdplan.training.loop import Trainer


def _with_algo_option(config: TrainConfig, field: str, value: Any, applies_to: str) -> TrainConfig:
    """``config`` with its algorithm's ``field`` set to ``value`` from a command-line flag;
    an algorithm without that field is refused with ``applies_to`` and the run's algorithm."""
    if not hasattr(config.algo_config, field):
        raise ValueError(f"{applies_to}; this run trains {config.algo!r}")
    params = dataclasses.replace(config.algo_config, **{field: value})
    return dataclasses.replace(config, algo_config=params)


# (flag, its argparse attribute, the config key it sets): a flag and a --set of the same key
# would contradict each other
_FLAG_KEYS = (
    ("--seed", "seed", "seed"),
    ("--humans", "humans", "world.humans"),
    ("--episodes", "episodes", "episodes"),
    ("--val-interval", "val_interval", "val_interval"),
    ("--[no-]keep-validation-models", "keep_validation_models", "keep_validation_models"),
    ("--policy-average", "policy_average", "policy_average"),
    ("--[no-]parallel-update", "parallel_update", "dsac.parallel_update"),
    ("--lookahead", "lookahead", "value_rl.lookahead"),
)


def _with_overrides(config: TrainConfig, args: argparse.Namespace) -> TrainConfig:
    """``config`` with the ``--set KEY=VALUE`` assignments of the command line, checked like a
    YAML file's keys and values."""
    data = config.to_dict()
    for key, values in parse_assignments(args.overrides, data):
        if len(values) != 1:
            raise ValueError(
                f"--set {key}: crowdplan train takes one value, got {len(values)}; to train "
                f"each, use crowdplan sweep --config {args.config} --set {key}=..."
            )
        for flag, attribute, flag_key in _FLAG_KEYS:
            if flag_key == key and getattr(args, attribute) is not None:
                raise ValueError(f"--set {key} and {flag} both set {key}; give one of them")
        assign(data, key, values[0])
    try:
        return config_from_dict(data)
    except (ValueError, TypeError) as error:
        raise ValueError(f"--set: {error}") from error


def _new_run_config(args: argparse.Namespace) -> tuple[TrainConfig, Path]:
    if not args.config:
        raise ValueError("--config is required for a new run (e.g. configs/lsa_dsac_aln_avg.yaml)")
    config = load_config(args.config)
    if args.overrides:
        config = _with_overrides(config, args)
    if args.seed is not None:
        config = dataclasses.replace(config, seed=args.seed)
    if args.humans is not None:
        config = dataclasses.replace(config, world=config.world.replace(humans=args.humans))
    if args.lookahead is not None:
        config = _with_algo_option(
            config,
            "lookahead",
            args.lookahead,
            "--lookahead applies to the value-network baselines (algo: value_rl)",
        )
    run_dir = Path(args.out or f"runs/{config.name}-s{config.seed}")
    if (run_dir / "checkpoint.pt").exists():
        raise ValueError(f"{run_dir} already holds a run; use --resume or another --out")
    if run_dir.exists() and not run_dir.is_dir():
        raise ValueError(f"--out {run_dir} is a file; give a folder for the run")
    if run_dir.is_dir() and any(run_dir.iterdir()):
        found = ", ".join(sorted(p.name for p in run_dir.iterdir())[:5])
        raise ValueError(
            f"--out {run_dir} already holds files that are not a crowdplan run ({found}); "
            "give a new or empty folder so that the run's files are not mixed with them"
        )
    return config, run_dir


def _resumed_run_config(args: argparse.Namespace) -> tuple[TrainConfig, Path]:
    if not args.out:
        raise ValueError("--resume needs --out pointing at the run folder to continue")
    fixed = [
        flag
        for flag, value in (
            ("--config", args.config),
            ("--seed", args.seed),
            ("--humans", args.humans),
            ("--lookahead", args.lookahead),
            ("--set", args.overrides),
        )
        if value is not None
    ]
    if fixed:
        raise ValueError(
            f"--resume continues the run in {args.out} with its own config.yaml, so "
            f"{' and '.join(fixed)} cannot apply; only --episodes, --val-interval, "
            "--[no-]keep-validation-models, --policy-average and --[no-]parallel-update may "
            "change on resume "
            "(start a new --out to change the rest)"
        )
    run_dir = Path(args.out)
    if not (run_dir / "checkpoint.pt").is_file():
        raise FileNotFoundError(f"{run_dir} holds no checkpoint.pt to resume from")
    return load_config(run_dir / "config.yaml", legacy_defaults=True), run_dir


def train_from_cli(args: argparse.Namespace) -> int:
    """Run ``crowdplan train``; returns the exit status (130 when stopped by a signal)."""
    config, run_dir = _resumed_run_config(args) if args.resume else _new_run_config(args)
    overrides = {
        "episodes": args.episodes,
        "val_interval": args.val_interval,
        "keep_validation_models": args.keep_validation_models,
        "policy_average": args.policy_average,
    }
    config = dataclasses.replace(config, **{k: v for k, v in overrides.items() if v is not None})
    if args.parallel_update is not None:
        config = _with_algo_option(
            config,
            "parallel_update",
            args.parallel_update,
            "--[no-]parallel-update applies to DSAC's two-thread update",
        )
    config = config_from_dict(config.to_dict())  # the same checks as a YAML file gets
    trainer = Trainer(config, run_dir, progress=not args.no_progress, quiet=args.quiet)
    if args.resume:
        trainer.restore(run_dir / "checkpoint.pt")
        done = len(trainer.episodes)
        if config.episodes < done:
            raise ValueError(
                f"{run_dir} has already trained {done} episodes; --episodes must be at least "
                f"that (the budget to train up to, not a number of further episodes)"
            )
        print(f"resuming {run_dir} at episode {done}")
    run_dir.mkdir(parents=True, exist_ok=True)
    atomic_write(
        run_dir / "config.yaml", lambda f: yaml.safe_dump(config.to_dict(), f, sort_keys=False)
    )
    if not trainer.run():
        print(
            f"stopped at episode {len(trainer.episodes)}; checkpoint written. "
            f"Continue with: crowdplan train --out {run_dir} --resume"
        )
        return 130
    summary = trainer.test() if config.test_episodes else None
    trainer.write_logs()
    if summary:
        title = f"{config.name} (seed {config.seed}), best model, {config.test_episodes} test cases"
        print(evaluation.format_table(summary, title))
    return 0


def main(argv: list[str]) -> int:
    """``crowdplan train ARGV`` without the top-level command (what a sweep's trial runs);
    returns the exit status."""
    parser = argparse.ArgumentParser(prog="crowdplan train")
    add_train_args(parser)
    return run_command(train_from_cli, parser.parse_args(argv), "crowdplan train")
