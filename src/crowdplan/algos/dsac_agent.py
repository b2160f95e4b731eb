"""DSAC as a training-loop agent: replay buffer, random warm-up, optional ORCA demonstrations
and behaviour cloning before the first step, update-to-data schedule.

The maths of an update is in :mod:`crowdplan.algos.dsac`; this module only feeds it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import torch

from crowdplan.algos.base import Observation, StepFeatures, Transitions
from crowdplan.algos.buffer import ReplayBuffer
from crowdplan.algos.dsac import DSAC
from crowdplan.algos.dsac_networks import initial_networks, networks_payload
from crowdplan.algos.imitation import collect_demonstrations, demonstration_seeds, fit_actions
from crowdplan.config import to_dict
from crowdplan.models import MODEL_FORMAT, DSACPolicy, model_payload

if TYPE_CHECKING:
    from crowdplan.training.config import TrainConfig


def initial_actor_state(config: TrainConfig) -> dict[str, torch.Tensor]:
    """The policy weights of ``config.algo_config.init_model``, checked against the run."""
    from crowdplan.models import initial_model_payload

    payload, path = initial_model_payload(
        config.algo_config.init_model, "dsac", MODEL_FORMAT, "a DSAC", config.world
    )
    if payload["encoder"] != to_dict(config.encoder):
        raise ValueError(
            f"dsac.init_model {path} has encoder {payload['encoder']}, the run "
            f"{to_dict(config.encoder)}; use the model's encoder section"
        )
    return payload["actor"]


class DSACAgent:
    """Off-policy DSAC: uniform random actions for the first ``random_steps`` transitions, then
    samples of the policy; ``updates_per_step`` updates per transition once the buffer holds
    ``learning_starts`` of them (fractional ratios carry their remainder to the next step)."""

    def __init__(self, config: TrainConfig, device: torch.device):
        self.config = config
        self.params = config.algo_config
        self.device = device
        self.core = DSAC(self.params, config.encoder, seed=config.seed, device=device)
        if self.params.init_networks is not None:
            self.core.load_networks(initial_networks(config))
        if self.params.init_model is not None:
            self.core.actor.load_state_dict(initial_actor_state(config))
            if self.params.anchor_weight > 0:
                self.core.anchor_to_actor()
        self.buffer = ReplayBuffer(
            self.params.buffer_size, config.world.humans, seed=config.seed + 1
        )
        self.rng = np.random.default_rng(config.seed + 2)
        self.generator = torch.Generator(device=device).manual_seed(config.seed + 3)
        self.unicycle = config.world.kinematics == "unicycle"
        self.features = StepFeatures(self.unicycle)
        self.env_steps = 0
        self.update_credit = 0.0
        self._entropy: np.ndarray | None = None  # of the policy that chose those actions

    def pretrain(self, log: Any) -> dict[str, float] | None:
        """ORCA demonstrations into the replay buffer and behaviour cloning of the policy, when
        ``demo_episodes`` / ``bc_epochs`` ask for them; by default (the paper) nothing."""
        p = self.params
        if p.demo_episodes == 0:
            return None
        seeds = demonstration_seeds(p.demo_episodes, self.config.seed)
        demos = collect_demonstrations(
            self.config.world, seeds, p.gamma, p.demo_safety_space, discrete=True
        )
        self.buffer.add_batch(*demos.transitions())
        stats = {"demo_transitions": float(len(demos)), **demos.outcome_rates()}
        if p.bc_epochs > 0:
            generator = torch.Generator().manual_seed(self.config.seed + 4)
            stats |= fit_actions(
                self.core.actor, demos, p.bc_epochs, p.bc_lr, p.batch_size, generator, log
            )
        return stats

    def act(self, obs: Observation, world: Any) -> np.ndarray:
        feats = self.features.of_observation(obs)
        num_envs = len(feats.robot)
        if self.env_steps < self.params.random_steps:
            self._entropy = np.full(num_envs, np.log(self.params.n_actions), np.float32)
            return self.rng.integers(0, self.params.n_actions, size=num_envs)
        inputs = (torch.from_numpy(x).to(self.device) for x in feats)
        actions, entropy = self.core.sample(*inputs, generator=self.generator)
        self._entropy = entropy.cpu().numpy()
        return actions.cpu().numpy()

    def observe(self, step: Transitions) -> None:
        feats, next_feats = self.features.of_transition(step)
        self.buffer.add_step(feats, step, next_feats, self._entropy)
        self._entropy = None
        self.env_steps += len(step.actions)
        if len(self.buffer) >= self.params.learning_starts:
            self.update_credit += len(step.actions) * self.params.updates_per_step

    def update(self) -> dict[str, float] | None:
        stats = None
        while self.update_credit >= 1.0:
            batch = self.buffer.sample(self.params.batch_size, self.device)
            stats = self.core.update(batch)
            self.update_credit -= 1.0
        return stats

    def episodes_done(self, episodes: int) -> None:
        """DSAC has no per-episode schedule."""

    @property
    def n_updates(self) -> int:
        """Gradient updates so far."""
        return self.core.n_updates

    def policy(self, name: str) -> DSACPolicy:
        return DSACPolicy(self.core.actor, self.config.world, name)

    def model_payload(self, info: dict[str, Any]) -> dict[str, Any]:
        return model_payload(
            self.core.actor, self.config.encoder, self.params, self.config.world, info
        )

    def networks_payload(self) -> dict[str, Any]:
        """The networks and temperature now, as a networks file holds them
        (:mod:`crowdplan.algos.dsac_networks`)."""
        return networks_payload(self.config.to_dict(), self.core.state_dict())

    def state_dict(self) -> dict[str, Any]:
        return {
            "dsac": self.core.state_dict(),
            "buffer": self.buffer.state_dict(),
            "rng": self.rng.bit_generator.state,
            "generator": self.generator.get_state(),
            "env_steps": self.env_steps,
            "update_credit": self.update_credit,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.core.load_state_dict(state["dsac"])
        self.buffer.load_state_dict(state["buffer"])
        self.rng.bit_generator.state = state["rng"]
        self.generator.set_state(state["generator"])
        self.env_steps = int(state["env_steps"])
        self.update_credit = float(state["update_credit"])
