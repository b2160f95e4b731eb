"""Resolve planners by name or trained model, and describe a run for its result files."""

from __future__ import annotations

import subprocess
from pathlib import Path

import yaml

from crowdplan.config import WorldConfig, to_dict
from crowdplan.policy import Policy

BUILTIN_POLICIES = ("orca",)


def parse_options(items: list[str]) -> dict:
    """``["visible_robot=true", "kinematics=unicycle"]`` -> dict with YAML-typed values."""
    options = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ValueError(f"world option {item!r} must look like KEY=VALUE")
        options[key.strip()] = yaml.safe_load(value)
    return options


def load_policy(policy: str | None, model: str | None) -> tuple[Policy, WorldConfig]:
    """A policy plus the world config it expects (a trained model brings its own)."""
    if model is not None:
        from crowdplan.models import load_model_policy

        return load_model_policy(model)
    name = policy or "orca"
    if name == "orca":
        from crowdplan.algos.orca_planner import OrcaPlanner

        return OrcaPlanner(), WorldConfig()
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


def git_hash() -> str:
    """Commit of the source tree, with '+dirty' when it has uncommitted changes."""
    root = Path(__file__).resolve().parent
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
        return "unknown"
    return head + ("+dirty" if dirty else "")


def run_metadata(policy: Policy, config: WorldConfig, seeds: list[int], split: str) -> dict:
    """What a result file must say about how it was produced."""
    meta = {
        "policy": policy.name,
        "split": split,
        "seeds": [seeds[0], seeds[-1]] if seeds else [],
        "world": to_dict(config),
        "git": git_hash(),
    }
    meta.update(getattr(policy, "metadata", {}))
    return meta
