"""Training for every algorithm: config, loop, checkpoints, logs and the ``train`` command."""

from crowdplan.training.cli import train_from_cli
from crowdplan.training.config import TrainConfig, config_from_dict, load_config
from crowdplan.training.loop import Trainer

__all__ = ["TrainConfig", "Trainer", "config_from_dict", "load_config", "train_from_cli"]
