"""``crowdplan train``: a fresh run from a YAML config, or ``--resume`` of a run folder."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import yaml

from crowdplan import evaluation
from crowdplan.command import run_command
from crowdplan.config_overrides import assign, parse_assignments
from crowdplan.io import atomic_write
from crowdplan.train_args import add_train_args
from crowdplan.training.config import TrainConfig, config_from_dict, load_config
from crowdplan.training.loop import Trainer


@dataclasses.dataclass(frozen=True)
class _Flag:
    """A ``crowdplan train`` flag that sets one config key."""

    name: str  # as --help spells it
    attribute: str  # its argparse destination
    key: str  # the config key it sets
    on_resume: bool  # whether it may change when a run resumes
    applies_to: str = ""  # for an algorithm's key: why a run of another algorithm refuses it


_FLAGS = (
    _Flag("--seed", "seed", "seed", on_resume=False),
    _Flag("--humans", "humans", "world.humans", on_resume=False),
    _Flag(
        "--lookahead",
        "lookahead",
        "value_rl.lookahead",
        False,
        "--lookahead applies to the value-network baselines (algo: value_rl)",
    ),
    _Flag("--episodes", "episodes", "episodes", on_resume=True),
    _Flag("--val-interval", "val_interval", "val_interval", on_resume=True),
    _Flag(
        "--[no-]keep-validation-models",
        "keep_validation_models",
        "keep_validation_models",
        on_resume=True,
    ),
    _Flag(
        "--[no-]keep-validation-networks",
        "keep_validation_networks",
        "keep_validation_networks",
        on_resume=True,
    ),
    _Flag("--policy-average", "policy_average", "policy_average", on_resume=True),
    _Flag(
        "--[no-]parallel-update",
        "parallel_update",
        "dsac.parallel_update",
        True,
        "--[no-]parallel-update applies to DSAC's two-thread update",
    ),
)


def _with_flags(config: TrainConfig, args: argparse.Namespace) -> TrainConfig:
    """``config`` with the keys that the given flags set, checked like a YAML file's (a resumed
    run has refused the flags that may not change before this)."""
    data = config.to_dict()
    for flag in _FLAGS:
        value = getattr(args, flag.attribute)
        if value is None:
            continue
        if flag.applies_to and flag.key.split(".")[0] not in data:
            raise ValueError(f"{flag.applies_to}; this run trains {config.algo!r}")
        assign(data, flag.key, value)
    return config_from_dict(data)


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
        for flag in _FLAGS:
            if flag.key == key and getattr(args, flag.attribute) is not None:
                raise ValueError(f"--set {key} and {flag.name} both set {key}; give one of them")
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
    config = _with_flags(config, args)
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
        name for name, value in (("--config", args.config), ("--set", args.overrides)) if value
    ]
    fixed += [f.name for f in _FLAGS if not f.on_resume and getattr(args, f.attribute) is not None]
    if fixed:
        mutable = [f.name for f in _FLAGS if f.on_resume]
        raise ValueError(
            f"--resume continues the run in {args.out} with its own config.yaml, so "
            f"{' and '.join(fixed)} cannot apply; only {', '.join(mutable[:-1])} and "
            f"{mutable[-1]} may change on resume (start a new --out to change the rest)"
        )
    run_dir = Path(args.out)
    if not (run_dir / "checkpoint.pt").is_file():
        raise FileNotFoundError(f"{run_dir} holds no checkpoint.pt to resume from")
    return _with_flags(load_config(run_dir / "config.yaml", legacy_defaults=True), args), run_dir


def train_from_cli(args: argparse.Namespace) -> int:
    """Run ``crowdplan train``; returns the exit status (130 when stopped by a signal)."""
    config, run_dir = _resumed_run_config(args) if args.resume else _new_run_config(args)
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
