"""Double DQN on the 81 actions with any encoder of ``crowdplan.nets`` (RG-DQN with ``rg``).

Q network: encoder + MLP head (``q_hidden``) -> one Q-value per action. Target (double DQN):
``y = r + gamma (1 - terminated) Q_target(s', argmax_a' Q(s', a'))``, loss: Huber(Q(s, a), y);
a time-limit truncation bootstraps (its ``done`` is 0, as in the replay buffer of DSAC).
Exploration: epsilon-greedy, epsilon falling linearly from ``epsilon_start`` to ``epsilon_end``
over ``epsilon_episodes`` finished episodes. The target network is copied from the online one
every ``target_update`` gradient steps, or follows it by Polyak averaging (``tau``). The greedy
policy is the argmax of Q.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from crowdplan.algos.base import Observation, StepFeatures, Transitions, frozen_copy
from crowdplan.algos.buffer import ReplayBuffer
from crowdplan.config import WorldConfig, check_below, check_fields, from_dict, spec, to_dict
from crowdplan.models import GreedyPolicy, load_weights, require_format
from crowdplan.nets.encoders import Encoder, EncoderConfig, make_encoder, mlp
from crowdplan.sim.actions import N_ACTIONS

if TYPE_CHECKING:
    from crowdplan.training.config import TrainConfig

DQN_MODEL_FORMAT = "crowdplan-dqn-policy/1"


@dataclass
class DQNConfig:
    """Double-DQN hyper-parameters; YAML section ``dqn``.

    Attributes:
        gamma: discount per environment step.
        lr: Adam learning rate.
        batch_size: transitions per update.
        target_update: gradient steps between copies of the online network into the target
            (when ``tau`` is 0).
        tau: if above 0, the target instead follows the online network by Polyak averaging after
            every update, ``target <- (1 - tau) target + tau online`` (DSAC's target rule).
        epsilon_start, epsilon_end: exploration rate at the first episode and after the schedule.
        epsilon_episodes: finished episodes over which epsilon falls linearly.
        updates_per_step: gradient updates per environment transition.
        max_grad_norm: gradients are clipped to this global norm.
        q_hidden: hidden sizes of the Q head.
        learning_starts: transitions in the replay buffer before the first update.
        buffer_size: replay capacity in transitions.
        clip_q_targets: clamp the target ``y`` to ``[return_min, return_max]``, the discounted
            returns the world can give (as DSAC's option; docs/baselines.md, "RG-DQN"): a
            bootstrapped target outside them can only be the network's own overestimate.
        return_min, return_max: those bounds (DSAC's defaults, derived for gamma 0.95 per step).
    """

    gamma: float = spec(0.95, low=0.0, high=1.0)
    lr: float = spec(3e-4, low=0.0, low_open=True)
    batch_size: int = spec(128, low=1)
    target_update: int = spec(500, low=1)
    tau: float = spec(0.0, low=0.0, high=1.0)
    epsilon_start: float = spec(1.0, low=0.0, high=1.0)
    epsilon_end: float = spec(0.05, low=0.0, high=1.0)
    epsilon_episodes: int = spec(2000, low=1)
    updates_per_step: float = spec(1.0, low=0.0, low_open=True)
    max_grad_norm: float = spec(10.0, low=0.0, low_open=True)
    q_hidden: tuple[int, ...] = (128, 128)
    learning_starts: int = spec(1000, low=1)
    buffer_size: int = spec(200_000, low=1)
    clip_q_targets: bool = False
    return_min: float = -2.5
    return_max: float = 1.5

    def __post_init__(self) -> None:
        check_fields(self, "dqn")
        check_below("dqn.return_min", self.return_min, "dqn.return_max", self.return_max)


class QNetwork(nn.Module):
    """``forward(robot, humans, mask) -> (Q (B, 81), attention (B, N) or None)``."""

    def __init__(self, encoder: Encoder, hidden: tuple[int, ...]):
        super().__init__()
        self.encoder = encoder
        self.head = mlp([encoder.out_dim, *hidden, N_ACTIONS])

    def forward(self, robot: Tensor, humans: Tensor, mask: Tensor) -> tuple[Tensor, Tensor | None]:
        features, attention = self.encoder(robot, humans, mask)
        return self.head(features), attention


def double_dqn_target(
    reward: Tensor,
    done: Tensor,
    next_q_online: Tensor,
    next_q_target: Tensor,
    gamma: float,
    bounds: tuple[float, float] | None = None,
) -> Tensor:
    """``r + gamma (1 - done) Q_target(s', argmax_a' Q_online(s', a'))``, all (B,) / (B, A),
    clamped to ``bounds`` (low, high) if given."""
    best = next_q_online.argmax(dim=1, keepdim=True)
    target = reward + gamma * (1.0 - done) * next_q_target.gather(1, best).squeeze(1)
    return target if bounds is None else target.clamp(*bounds)


class DQNPolicy(GreedyPolicy):
    """Greedy policy (argmax of Q) over raw observations; the encoder's attention as scores."""

    def __init__(self, q: QNetwork, world: WorldConfig, name: str, metadata: dict | None = None):
        super().__init__(q, world, name, metadata)
        self.q = q


class DQNAgent:
    """Off-policy double DQN behind the training loop: epsilon-greedy rollouts into a replay
    buffer, ``updates_per_step`` updates per transition once it holds ``learning_starts``."""

    def __init__(self, config: TrainConfig, device: torch.device):
        self.config = config
        self.params: DQNConfig = config.algo_config
        self.device = device
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            self.q = QNetwork(make_encoder(config.encoder), self.params.q_hidden).to(device)
        self.q_target = frozen_copy(self.q)
        self.optimizer = torch.optim.Adam(self.q.parameters(), lr=self.params.lr)
        self.buffer = ReplayBuffer(
            self.params.buffer_size, config.world.humans, seed=config.seed + 1
        )
        self.rng = np.random.default_rng(config.seed + 2)
        self.unicycle = config.world.kinematics == "unicycle"
        self.features = StepFeatures(self.unicycle)
        self.epsilon = self.params.epsilon_start
        self.update_credit = 0.0
        self.n_updates = 0

    def pretrain(self, log: Any) -> None:
        """DQN learns from its own experience only."""
        return None

    @torch.no_grad()
    def act(self, obs: Observation, world: Any) -> np.ndarray:
        feats = self.features.of_observation(obs)
        q, _ = self.q(*(torch.from_numpy(x).to(self.device) for x in feats))
        greedy = q.argmax(dim=1).cpu().numpy()
        explore = self.rng.random(len(greedy)) < self.epsilon
        random = self.rng.integers(0, N_ACTIONS, size=len(greedy))
        return np.where(explore, random, greedy)

    def observe(self, step: Transitions) -> None:
        feats, next_feats = self.features.of_transition(step)
        self.buffer.add_step(feats, step, next_feats)
        if len(self.buffer) >= self.params.learning_starts:
            self.update_credit += len(step.actions) * self.params.updates_per_step

    def update(self) -> dict[str, float] | None:
        stats = None
        while self.update_credit >= 1.0:
            stats = self._learn(self.buffer.sample(self.params.batch_size, self.device))
            self.update_credit -= 1.0
        return stats

    def _learn(self, batch: dict[str, Tensor]) -> dict[str, float]:
        p = self.params
        with torch.no_grad():
            nxt = (batch["next_robot"], batch["next_humans"], batch["next_mask"])
            target = double_dqn_target(
                batch["reward"],
                batch["done"],
                self.q(*nxt)[0],
                self.q_target(*nxt)[0],
                p.gamma,
                (p.return_min, p.return_max) if p.clip_q_targets else None,
            )
        q, _ = self.q(batch["robot"], batch["humans"], batch["mask"])
        chosen = q.gather(1, batch["action"].unsqueeze(1)).squeeze(1)
        loss = F.smooth_l1_loss(chosen, target)
        self.optimizer.zero_grad()
        loss.backward()
        grad_norm = nn.utils.clip_grad_norm_(self.q.parameters(), p.max_grad_norm)
        self.optimizer.step()
        self.n_updates += 1
        if p.tau > 0.0:
            with torch.no_grad():
                pairs = zip(self.q_target.parameters(), self.q.parameters(), strict=True)
                for target, online in pairs:
                    target.lerp_(online, p.tau)
        elif self.n_updates % p.target_update == 0:
            self.q_target.load_state_dict(self.q.state_dict())
        return {
            "q_loss": float(loss.detach()),
            "mean_q": float(chosen.detach().mean()),
            "grad_norm": float(grad_norm),
            "epsilon": self.epsilon,
        }

    def episodes_done(self, episodes: int) -> None:
        """Linear epsilon schedule over finished episodes."""
        p = self.params
        fraction = min(episodes / p.epsilon_episodes, 1.0)
        self.epsilon = p.epsilon_start + fraction * (p.epsilon_end - p.epsilon_start)

    def policy(self, name: str) -> DQNPolicy:
        return DQNPolicy(self.q, self.config.world, name)

    def model_payload(self, info: dict[str, Any]) -> dict[str, Any]:
        params = {
            k: list(v) if isinstance(v, tuple) else v for k, v in to_dict(self.params).items()
        }
        return {
            "format": DQN_MODEL_FORMAT,
            "encoder": to_dict(self.config.encoder),
            "dqn": params,
            "world": to_dict(self.config.world),
            "info": info,
            "q": {k: v.cpu() for k, v in self.q.state_dict().items()},
        }

    def state_dict(self) -> dict[str, Any]:
        return {
            "q": self.q.state_dict(),
            "q_target": self.q_target.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "buffer": self.buffer.state_dict(),
            "rng": self.rng.bit_generator.state,
            "epsilon": self.epsilon,
            "update_credit": self.update_credit,
            "n_updates": self.n_updates,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.q.load_state_dict(state["q"])
        self.q_target.load_state_dict(state["q_target"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.buffer.load_state_dict(state["buffer"])
        self.rng.bit_generator.state = state["rng"]
        self.epsilon = float(state["epsilon"])
        self.update_credit = float(state["update_credit"])
        self.n_updates = int(state["n_updates"])


def load_dqn_payload(payload: dict[str, Any], path: Path) -> tuple[DQNPolicy, WorldConfig]:
    """The greedy policy of a DQN model file (format :data:`DQN_MODEL_FORMAT`)."""
    require_format(payload, path, DQN_MODEL_FORMAT, "a DQN")
    encoder = from_dict(EncoderConfig, payload["encoder"], f"{path}: encoder")
    params = from_dict(DQNConfig, payload["dqn"], f"{path}: dqn")
    world = WorldConfig.from_dict(payload["world"])
    q = QNetwork(make_encoder(encoder), params.q_hidden)
    load_weights(q, payload["q"], path, f"encoder {encoder.name!r}")
    name = payload["info"].get("name", f"{encoder.name}-dqn")
    metadata = {"model": str(path), "algo": "dqn", "encoder": encoder.name, **payload["info"]}
    return DQNPolicy(q.eval(), world, name, metadata), world
