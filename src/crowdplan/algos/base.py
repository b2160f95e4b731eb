"""The protocol between the training loop and a learning algorithm.

The loop (:mod:`crowdplan.training.loop`) steps a batched vector env, asks the agent for actions,
hands it every transition, calls :meth:`Agent.update` once per environment step and tells it when
episodes end. It knows nothing else about the algorithm: replay buffers, rollout storage,
exploration schedules, target networks and update-to-data ratios live in the agent.

An agent must be an exact function of its seed: the loop checkpoints :meth:`Agent.state_dict`
(networks, optimisers, buffers, random generators) and a resumed run continues bit for bit.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

import numpy as np
from torch import nn

from crowdplan.features import Features, robot_centric
from crowdplan.policy import Policy

Observation = dict[str, np.ndarray]
"""Raw batched observation of E environments: ``robot`` (E, 9), ``humans`` (E, N, 5), ``mask``
(E, N), as :class:`crowdplan.sim.env.CrowdNavVectorEnv` returns it."""


ModuleT = TypeVar("ModuleT", bound=nn.Module)


def frozen_copy(module: ModuleT) -> ModuleT:
    """A deep copy of ``module`` with gradients off, to serve as its target network.

    A deep copy gives each recurrent layer's weights their own tensors; on CUDA, cuDNN would then
    copy them into one block at every call (and warn), so they are re-packed here once. On the
    CPU ``flatten_parameters`` does nothing and the copy is exactly ``copy.deepcopy``.
    """
    target = copy.deepcopy(module).requires_grad_(False)
    for layer in target.modules():
        if isinstance(layer, nn.RNNBase):
            layer.flatten_parameters()
    return target


def observation_features(obs: Observation, unicycle: bool) -> Features:
    """Robot-centric features of a raw batched observation."""
    return robot_centric(obs["robot"], obs["humans"], obs["mask"].astype(bool), unicycle)


class StepFeatures:
    """Features of the observation an agent last acted on, reused when that step's transition
    arrives, so that each observation is encoded once."""

    def __init__(self, unicycle: bool):
        self.unicycle = unicycle
        self._acted_on: Features | None = None

    def of_observation(self, obs: Observation) -> Features:
        """Features of ``obs``, kept for the transition that follows."""
        self._acted_on = observation_features(obs, self.unicycle)
        return self._acted_on

    def of_transition(self, step: Transitions) -> tuple[Features, Features]:
        """Features of ``step.obs`` (the kept ones where the agent acted on it) and of
        ``step.next_obs``."""
        feats = self._acted_on
        if feats is None:
            feats = observation_features(step.obs, self.unicycle)
        self._acted_on = None
        return feats, observation_features(step.next_obs, self.unicycle)


@dataclass
class Transitions:
    """One step of E environments, as every agent sees it.

    ``next_obs`` is the true successor: where an episode ended it is the final observation, not
    the first observation of the next episode. ``terminated`` marks goal or collision (no
    bootstrapping); ``truncated`` marks the time limit (the state did not end: bootstrap).
    """

    obs: Observation
    actions: np.ndarray  # (E,) int64
    rewards: np.ndarray  # (E,) float32
    next_obs: Observation
    terminated: np.ndarray  # (E,) bool
    truncated: np.ndarray  # (E,) bool


class Agent(Protocol):
    """A learning algorithm behind the training loop (DSAC, value-network RL, A2C, ...)."""

    def pretrain(self, log: Any) -> dict[str, float] | None:
        """Work done once before the first environment step (e.g. imitation learning from
        demonstrations); ``log(line)`` prints progress. Returns summary statistics or None."""
        ...

    def act(self, obs: Observation, world: Any) -> np.ndarray:
        """Exploratory actions (E,) for the training rollout. ``world`` is the vector env's
        :class:`~crowdplan.sim.world.World`, for planners that query the simulator."""
        ...

    def observe(self, step: Transitions) -> None:
        """Receive the transition that followed the last :meth:`act`."""
        ...

    def update(self) -> dict[str, float] | None:
        """Learn, if the agent's schedule says so; statistics of the last gradient step or None."""
        ...

    def episodes_done(self, episodes: int) -> None:
        """Called after the step in which the total number of finished episodes became
        ``episodes`` (exploration schedules, target-network copies)."""
        ...

    def policy(self, name: str) -> Policy:
        """The greedy policy for validation, testing, rendering and export."""
        ...

    def model_payload(self, info: dict[str, Any]) -> dict[str, Any]:
        """A plain-data model file of the greedy policy (see :mod:`crowdplan.artifacts`)."""
        ...

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to resume exactly."""
        ...

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore what :meth:`state_dict` returned."""
        ...
