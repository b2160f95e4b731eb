"""The averaged validation policy: the mean of the weights of the last K validated policies.

A policy trained towards a vanishing temperature is close to deterministic, and in some states
its greedy action flips between two validations while the critic is settled: the greedy dips of
docs/training.md, section 6. The mean of its weights over the last K validations moves more
slowly than any one of them. Training does not see it: the agent acts, explores and learns with
its own current weights; only the policy that is validated, kept as the best model and tested is
the average (``policy_average`` in :class:`crowdplan.training.config.TrainConfig`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from crowdplan.policy import Policy


def average_payloads(payloads: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """A model file whose floating-point tensors are the element-wise mean of those of
    ``payloads`` (model files of one run, oldest first); every other entry is the last one's, and
    ``info["averaged_episodes"]`` lists the episodes the averaged policies were trained for."""
    if not payloads:
        raise ValueError("average_payloads needs at least one model payload")
    averaged = _mean(list(payloads))
    averaged["info"] = {
        **averaged["info"],
        "averaged_episodes": [p["info"].get("episodes_trained") for p in payloads],
    }
    return averaged


def _mean(values: list[Any]) -> Any:
    last = values[-1]
    if isinstance(last, torch.Tensor) and last.is_floating_point():
        return torch.stack(values).mean(dim=0)
    if isinstance(last, dict):
        return {key: _mean([value[key] for value in values]) for key in last}
    return last


def payload_policy(payload: dict[str, Any], name: str) -> Policy:
    """The greedy policy of an in-memory model file, as :func:`crowdplan.models.load_model_policy`
    would load it from disk (without a safety shield)."""
    from crowdplan.algos.registry import algorithm_of_model

    where = Path(f"<averaged policy of {name}>")
    policy, _ = algorithm_of_model(payload["format"], where).load_policy(payload, where)
    return policy
