"""Helpers of the tests that train tiny runs through the real training loop."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from crowdplan.training import TrainConfig, Trainer, config_from_dict

# A DSAC run of a few seconds through the real training loop.
TINY = {
    "name": "tiny",
    "episodes": 6,
    "num_envs": 2,
    "random_steps": 16,
    "learning_starts": 16,
    "val_interval": 1000,
    "checkpoint_interval": 1000,
    "log_interval": 1000,
    "test_episodes": 0,
    "world": {"humans": 3, "time_limit": 4.0},
    "encoder": {"name": "lsa"},
    "dsac": {"batch_size": 16},
}


def train_tiny(base: dict, tmp_path: Path, name: str, episodes: int = 6, **changes) -> Trainer:
    """Train the config ``base`` (a YAML-like dict) with ``changes`` into ``tmp_path / name``."""
    config = dataclasses.replace(config_from_dict(base), episodes=episodes, **changes)
    trainer = Trainer(config, tmp_path / name, progress=False, quiet=True)
    trainer.run()
    return trainer


def flat_parameters(module: torch.nn.Module) -> torch.Tensor:
    """Every parameter of ``module`` in one flat tensor, for exact comparisons."""
    return torch.cat([p.detach().flatten() for p in module.parameters()])


def without_clock(rows: list[dict]) -> list[dict]:
    """Episode log rows without their wall-clock column (the only one that may differ)."""
    return [{k: v for k, v in row.items() if k != "train_seconds"} for row in rows]


def restored(config: TrainConfig, run_dir: Path) -> Trainer:
    """A trainer of ``config`` restored from the checkpoint in ``run_dir``, not yet run."""
    trainer = Trainer(config, run_dir, progress=False, quiet=True)
    trainer.restore(run_dir / "checkpoint.pt")
    return trainer
