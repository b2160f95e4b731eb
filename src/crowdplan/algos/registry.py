"""Algorithm names -> their config section, their training agent and their model-file loader.

Adding an algorithm means one entry here: the training loop, the config loader, the checkpoint
and ``crowdplan eval --model`` find it through this table.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from crowdplan.algos.a2c import A2C_MODEL_FORMAT, A2CAgent, A2CConfig, load_a2c_payload
from crowdplan.algos.base import Agent
from crowdplan.algos.dqn import DQN_MODEL_FORMAT, DQNAgent, DQNConfig, load_dqn_payload
from crowdplan.algos.dsac import DSACConfig
from crowdplan.algos.dsac_agent import DSACAgent
from crowdplan.algos.value_rl import MODEL_FORMAT as VALUE_RL_MODEL_FORMAT
from crowdplan.algos.value_rl import ValueRLAgent, ValueRLConfig, load_value_rl_payload
from crowdplan.config import WorldConfig
from crowdplan.models import MODEL_FORMAT as DSAC_MODEL_FORMAT
from crowdplan.models import load_dsac_payload
from crowdplan.policy import Policy

if TYPE_CHECKING:
    from crowdplan.training.config import TrainConfig


@dataclass(frozen=True)
class Algorithm:
    """One trainable algorithm.

    Attributes:
        name: the name in configs (``algo: NAME``) and the key of its YAML section.
        config_class: dataclass of its hyper-parameters (the YAML section ``NAME:``).
        make_agent: ``(train_config, device) -> Agent``.
        model_format: the ``format`` string of its model files (versioned).
        load_policy: ``(model payload, path) -> (greedy Policy, WorldConfig it was trained in)``.
    """

    name: str
    config_class: type
    make_agent: Callable[[TrainConfig, torch.device], Agent]
    model_format: str
    load_policy: Callable[[dict[str, Any], Path], tuple[Policy, WorldConfig]]


ALGORITHMS: dict[str, Algorithm] = {
    algo.name: algo
    for algo in (
        Algorithm("dsac", DSACConfig, DSACAgent, DSAC_MODEL_FORMAT, load_dsac_payload),
        Algorithm("a2c", A2CConfig, A2CAgent, A2C_MODEL_FORMAT, load_a2c_payload),
        Algorithm("dqn", DQNConfig, DQNAgent, DQN_MODEL_FORMAT, load_dqn_payload),
        Algorithm(
            "value_rl", ValueRLConfig, ValueRLAgent, VALUE_RL_MODEL_FORMAT, load_value_rl_payload
        ),
    )
}


def get_algorithm(name: str) -> Algorithm:
    """The registered algorithm ``name``; a ValueError lists the valid names otherwise."""
    if name not in ALGORITHMS:
        raise ValueError(f"unknown algorithm {name!r}; valid algorithms: {', '.join(ALGORITHMS)}")
    return ALGORITHMS[name]


def algorithm_of_model(model_format: Any, path: Path) -> Algorithm:
    """The algorithm whose model files carry ``model_format``."""
    for algo in ALGORITHMS.values():
        if algo.model_format == model_format:
            return algo
    known = ", ".join(f"{a.model_format} ({a.name})" for a in ALGORITHMS.values())
    raise ValueError(
        f"{path} is not a crowdplan model file this version can read (format {model_format!r}; "
        f"known formats: {known})"
    )
