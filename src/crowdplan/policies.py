"""Resolve planners by name or trained model, and describe a run for its result files."""

from __future__ import annotations

import platform
import subprocess
from pathlib import Path
from typing import Any

import torch
import yaml

from crowdplan.config import WorldConfig, to_dict
from crowdplan.policy import Policy

BUILTIN_POLICIES = ("orca", "straight")


def parse_options(items: list[str], own_flags: tuple[str, ...] = ()) -> dict:
    """``["visible_robot=true", "kinematics=unicycle"]`` -> dict with YAML-typed values.

    Keys given twice, and keys listed in ``own_flags`` (set through their own command-line flag,
    e.g. ``scenario``), are refused; the values' types and ranges are checked by ``WorldConfig``.
    """
    options = {}
    for item in items:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ValueError(f"world option {item!r} must look like KEY=VALUE")
        if key in own_flags:
            raise ValueError(f"set {key} with --{key.replace('_', '-')}, not --option {item}")
        if key in options:
            raise ValueError(f"world option {key!r} given twice")
        try:
            options[key] = yaml.safe_load(value)
        except yaml.YAMLError as error:
            why = getattr(error, "problem", None) or str(error).splitlines()[0]
            raise ValueError(f"world option {item!r}: cannot read the value ({why})") from None
    return options


def load_policy(
    policy: str | None,
    model: str | None,
    shield: float | None = None,
    lookahead: str | None = None,
    lookahead_precision: str | None = None,
    lookahead_compile: bool = False,
) -> tuple[Policy, WorldConfig]:
    """A policy plus the world config it expects (a trained model brings its own).

    ``shield``: a trained model's safety-shield horizon in seconds (0: off, None: the model's
    own; see :func:`crowdplan.models.load_model_policy`); built-in planners take none.
    ``lookahead``: the lookahead mode of a value-network model (None: the model's own).
    ``lookahead_precision``: ``float32`` or ``bfloat16`` for that lookahead's value call
    (None: float32). ``lookahead_compile``: run that value call through ``torch.compile``.
    """
    value_options = {
        flag: value
        for flag, value in (
            ("--lookahead", lookahead),
            ("--lookahead-precision", lookahead_precision),
            ("--lookahead-compile", True if lookahead_compile else None),
        )
        if value is not None
    }
    if model is not None:
        from crowdplan.models import load_model_policy

        loaded, world = load_model_policy(model, shield)
        if value_options:
            from crowdplan.algos.value_rl import ValuePolicy

            if not isinstance(loaded, ValuePolicy):
                flags = " and ".join(value_options)
                raise ValueError(
                    f"{flags}: only value-network models (cadrl, lstm-rl, sarl) have a "
                    f"lookahead; {model} is not one: drop {flags}"
                )
            if lookahead is not None:
                loaded.set_lookahead(lookahead)
            if lookahead_precision is not None:
                loaded.set_precision(lookahead_precision)
            if lookahead_compile:
                loaded.set_compiled(True)
        return loaded, world
    if value_options:
        flags = " and ".join(value_options)
        raise ValueError(f"{flags} set a value-network model's lookahead: use with --model")
    if shield:
        raise ValueError("--shield filters a trained model's action scores: use it with --model")
    name = policy or "orca"
    if name == "orca":
        from crowdplan.algos.orca_planner import OrcaPlanner

        return OrcaPlanner(), WorldConfig()
    if name == "straight":
        from crowdplan.algos.straight_planner import StraightPlanner

        return StraightPlanner(), WorldConfig()
    raise ValueError(
        f"unknown policy {name!r}; built-in policies are {BUILTIN_POLICIES}, "
        "or pass --model with a run folder, checkpoint or shipped model name"
    )


def check_compatible(policy: Policy, config: WorldConfig) -> None:
    """Refuse worlds a policy cannot drive (e.g. ORCA's velocity commands on a unicycle)."""
    needs = getattr(policy, "kinematics", None)
    if needs is not None and needs != config.kinematics:
        raise ValueError(
            f"policy {policy.name!r} drives {needs} robots but the world is {config.kinematics}; "
            f"drop the kinematics option or use a model trained for {config.kinematics} robots"
        )


def world_differences(policy: Policy, config: WorldConfig) -> dict[str, tuple[Any, Any]]:
    """``{option: (trained, now)}`` for every world option where ``config`` differs from the
    world a trained policy was trained in (nested options as ``orca.max_speed``); empty for
    planners that carry no training world."""
    trained = getattr(policy, "world", None)
    if trained is None:
        return {}
    before, now = _flatten(to_dict(trained)), _flatten(to_dict(config))
    return {key: (before[key], now.get(key)) for key in before if before[key] != now.get(key)}


def _flatten(data: dict, prefix: str = "") -> dict:
    flat = {}
    for key, value in data.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f"{prefix}{key}."))
        else:
            flat[f"{prefix}{key}"] = value
    return flat


def git_hash() -> str | None:
    """Commit of the source tree, with '+dirty' when it has uncommitted changes; None when the
    package is not run from a git checkout (an installed wheel)."""
    root = Path(__file__).resolve().parent
    if not (root.parents[1] / "pyproject.toml").is_file():
        return None  # installed: the directories above are not this project's
    try:
        head = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=root, capture_output=True, text=True, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=root,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("+dirty" if dirty else "")


def host_description() -> dict[str, str]:
    """The machine a process computes on: CPU model, the instruction set torch's CPU kernels use,
    and the torch build. The same code and seed can round differently on another host, so runs
    that part ways from their first updates can be told apart by it (docs/training.md section 7)."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu": cpu,
        "torch_cpu_capability": torch.backends.cpu.get_cpu_capability(),
        "torch": torch.__version__,
    }


def run_metadata(policy: Policy, config: WorldConfig, seeds: list[int], split: str) -> dict:
    """What a result file must say about how it was produced.

    ``eval_git`` is the commit that ran the evaluation; ``model_git`` (trained models only) the
    commit the model's training run started with.
    """
    from crowdplan import __version__

    info = dict(getattr(policy, "metadata", {}))
    model_git = info.pop("git", None)
    meta = {
        "policy": policy.name,
        "split": split,
        "seeds": [seeds[0], seeds[-1]] if seeds else [],
        "world": to_dict(config),
        "eval_git": git_hash(),
        "crowdplan_version": __version__,
        **info,
    }
    if model_git is not None:
        meta["model_git"] = model_git
    differences = world_differences(policy, config)
    if differences:
        meta["world_differs_from_training"] = {
            key: {"trained": before, "evaluated": now} for key, (before, now) in differences.items()
        }
    return meta
