"""LSTM-A2C (SPEC section 6): advantage actor-critic over the LSTM-RL encoder.

Network: :class:`~crowdplan.nets.lstm_rl.LSTMRLEncoder` (LSTM 13 -> 50 over the humans, closest
last, joined to the robot part: 56-d), shared by an actor MLP 56 -> 150 -> 100 -> 81 (logits of
the action table) and a critic MLP 56 -> 150 -> 100 -> 100 -> 1.

Training (synchronous A2C over the loop's E parallel environments): the agent samples actions
from the policy, collects ``n_steps`` environment steps (``n_steps * E`` transitions), then takes
one gradient step on

    loss = -mean(A_t log pi(a_t|s_t)) + value_coef * mean((G_t - V(s_t))^2) / 2
           - entropy_coef * mean(H(pi(.|s_t)))

with the GAE(lambda) advantages ``A_t = sum_k (gamma lambda)^k delta_{t+k}`` of the one-step
errors ``delta_t = r_t + gamma (1 - terminated_t) V(s'_t) - V(s_t)``, the trace cut at an episode's
end and at the rollout's end, and the critic's targets ``G_t = A_t + V(s_t)``. ``V(s'_t)`` is read
from the true last observation where step t is the rollout's last or was truncated by the time
limit (the state did not end: bootstrap). ``lambda = 1`` gives the plain n-step returns
``G_t = r_t + gamma (1 - terminated_t) G_{t+1}``. V is detached in the advantages, which may be
standardised per rollout (``normalize_advantages``). Gradients are clipped to ``max_grad_norm``.
With ``lr_schedule: linear`` the learning rate falls linearly from ``lr`` at the first episode
to 0 at the run's episode budget (OpenAI baselines' A2C default; off in the presets: tried and
not adopted, docs/baselines.md).
The greedy policy is the actor's argmax.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from crowdplan.algos.base import Observation, StepFeatures, Transitions
from crowdplan.config import WorldConfig, check_fields, from_dict, spec, to_dict
from crowdplan.models import GreedyPolicy, load_weights, require_format
from crowdplan.nets.heads import PolicyHead, ValueHead
from crowdplan.nets.lstm_rl import LSTMRLEncoder
from crowdplan.sim.actions import N_ACTIONS

if TYPE_CHECKING:
    from crowdplan.training.config import TrainConfig

A2C_MODEL_FORMAT = "crowdplan-a2c-policy/1"

# what the rollout stores per environment step, each (E, ...)
_ROLLOUT_KEYS = (
    "robot",
    "humans",
    "mask",
    "action",
    "reward",
    "terminated",
    "truncated",
    "next_robot",
    "next_humans",
    "next_mask",
)


@dataclass
class A2CConfig:
    """LSTM-A2C hyper-parameters; YAML section ``a2c`` (configs/lstm_a2c.yaml explains the
    preset's choices).

    Attributes:
        gamma: discount per environment step.
        lr: Adam learning rate of the whole network.
        n_steps: environment steps per rollout; one gradient step per rollout of
            ``n_steps * num_envs`` transitions.
        entropy_coef: weight of the policy-entropy bonus.
        value_coef: weight of the critic's squared-error loss.
        max_grad_norm: gradients are clipped to this global norm.
        gae_lambda: lambda of the GAE advantages (1: the plain n-step returns).
        normalize_advantages: standardise the advantages over each rollout (policy loss only).
        lr_schedule: ``constant``, or ``linear``: ``lr * (1 - episodes / budget)``, the budget
            being the run's ``episodes`` (a resume with a larger budget stretches the schedule).
        lstm_hidden: hidden size of the encoder's LSTM (SPEC: 50).
        actor_hidden: hidden sizes of the actor MLP.
        critic_hidden: hidden sizes of the critic MLP.
        init_model: an LSTM-A2C model file (or shipped model name) whose network (encoder,
            actor and critic) starts the run instead of a random one, e.g. the 5-human
            ``lstm-a2c`` for a 10-human run; same network sizes, action frame and kinematics
            as the run. The optimizer starts afresh.
    """

    gamma: float = spec(0.99, low=0.0, high=1.0)
    lr: float = spec(1e-3, low=0.0, low_open=True)
    n_steps: int = spec(5, low=1)
    entropy_coef: float = spec(0.01, low=0.0)
    value_coef: float = spec(0.5, low=0.0)
    max_grad_norm: float = spec(0.5, low=0.0, low_open=True)
    gae_lambda: float = spec(1.0, low=0.0, high=1.0)
    normalize_advantages: bool = False
    lr_schedule: str = spec("constant", choices=("constant", "linear"))
    lstm_hidden: int = spec(50, low=1)
    actor_hidden: tuple[int, ...] = (150, 100)
    critic_hidden: tuple[int, ...] = (150, 100, 100)
    init_model: str | None = None

    def __post_init__(self) -> None:
        check_fields(self, "a2c")


class ActorCritic(nn.Module):
    """Shared LSTM-RL encoder, actor and critic heads.

    ``forward(robot, humans, mask) -> (logits (B, 81), value (B,))``.
    """

    def __init__(self, params: A2CConfig):
        super().__init__()
        self.encoder = LSTMRLEncoder(params.lstm_hidden)
        self.actor = PolicyHead(self.encoder.out_dim, N_ACTIONS, params.actor_hidden)
        self.critic = ValueHead(self.encoder.out_dim, params.critic_hidden)

    def forward(self, robot: Tensor, humans: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        features, _ = self.encoder(robot, humans, mask)
        return self.actor(features), self.critic(features).squeeze(-1)

    def value(self, robot: Tensor, humans: Tensor, mask: Tensor) -> Tensor:
        """V(s), shape (B,)."""
        features, _ = self.encoder(robot, humans, mask)
        return self.critic(features).squeeze(-1)


def advantages_and_returns(
    rewards: Tensor,
    values: Tensor,
    terminated: Tensor,
    truncated: Tensor,
    bootstrap: Tensor,
    gamma: float,
    lam: float,
) -> tuple[Tensor, Tensor]:
    """GAE(lambda) advantages and the critic's targets ``A_t + V(s_t)`` of a rollout, all
    arguments (T, E) over T steps of E envs.

    ``values[t]`` is V(s_t); ``bootstrap[t]`` is V(s'_t), read where step t is the last one
    (t = T - 1) or truncated; elsewhere the successor's value is ``values[t + 1]``. A terminated
    step bootstraps from nothing (a step both terminated and truncated counts as terminated), and
    no trace crosses an episode's end. ``lam = 1`` gives the n-step returns (the whole rest of the
    rollout, then V), ``lam = 0`` the one-step TD errors.
    """
    cut = truncated.clone()
    cut[-1] = True
    successor = torch.where(cut, bootstrap, torch.cat([values[1:], values[-1:]]))
    deltas = rewards + gamma * (~terminated) * successor - values
    carry = gamma * lam * ~(terminated | cut)
    advantages = torch.empty_like(rewards)
    following = torch.zeros_like(rewards[0])
    for t in range(rewards.shape[0] - 1, -1, -1):
        following = deltas[t] + carry[t] * following
        advantages[t] = following
    return advantages, advantages + values


def _tensors(feats: Any, device: torch.device) -> tuple[Tensor, Tensor, Tensor]:
    return tuple(torch.from_numpy(np.ascontiguousarray(x)).to(device) for x in feats)


class A2CPolicy(GreedyPolicy):
    """Greedy LSTM-A2C policy (argmax of the actor's logits) over raw observations."""

    attention_output = False  # the network's second output is the critic's value

    def __init__(
        self, net: ActorCritic, world: WorldConfig, name: str, metadata: dict | None = None
    ):
        super().__init__(net, world, name, metadata)
        self.net = net


class A2CAgent:
    """Synchronous A2C behind the training loop: samples of the policy, one update per
    ``n_steps`` environment steps (the rollout storage is part of the checkpoint)."""

    def __init__(self, config: TrainConfig, device: torch.device):
        self.config = config
        self.params: A2CConfig = config.algo_config
        self.device = device
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            self.net = ActorCritic(self.params).to(device)
        if self.params.init_model is not None:
            self._load_initial_network(config.world)
        self.optimizer = torch.optim.Adam(self.net.parameters(), lr=self.params.lr)
        self.generator = torch.Generator(device=device).manual_seed(config.seed + 1)
        self.unicycle = config.world.kinematics == "unicycle"
        self.features = StepFeatures(self.unicycle)
        self.rollout: list[dict[str, np.ndarray]] = []
        self.n_updates = 0
        self.episodes = 0

    def _load_initial_network(self, world: WorldConfig) -> None:
        from crowdplan.models import initial_model_payload

        payload, path = initial_model_payload(
            self.params.init_model, "a2c", A2C_MODEL_FORMAT, "an LSTM-A2C", world
        )
        load_weights(self.net, payload["network"], path, "the run's a2c network sizes")

    def pretrain(self, log: Any) -> None:
        """A2C learns from its own experience only."""
        return None

    @torch.no_grad()
    def act(self, obs: Observation, world: Any) -> np.ndarray:
        logits, _ = self.net(*_tensors(self.features.of_observation(obs), self.device))
        probs = torch.softmax(logits, dim=1)
        return torch.multinomial(probs, 1, generator=self.generator).squeeze(1).cpu().numpy()

    def observe(self, step: Transitions) -> None:
        feats, nxt = self.features.of_transition(step)
        values = (
            *feats,
            np.asarray(step.actions, dtype=np.int64),
            np.asarray(step.rewards, dtype=np.float32),
            np.asarray(step.terminated, dtype=bool),
            np.asarray(step.truncated, dtype=bool),
            *nxt,
        )
        self.rollout.append(dict(zip(_ROLLOUT_KEYS, values, strict=True)))

    def update(self) -> dict[str, float] | None:
        """One gradient step once the rollout holds ``n_steps`` steps; then a fresh rollout."""
        if len(self.rollout) < self.params.n_steps:
            return None
        batch = {k: np.stack([step[k] for step in self.rollout]) for k in _ROLLOUT_KEYS}
        self.rollout = []
        return self._learn(batch)

    def _learn(self, batch: dict[str, np.ndarray]) -> dict[str, float]:
        p = self.params
        t = {k: torch.from_numpy(v).to(self.device) for k, v in batch.items()}
        steps, envs = t["reward"].shape
        flat = [t[k].flatten(0, 1) for k in ("robot", "humans", "mask")]
        logits, values = self.net(*flat)
        advantages, returns = advantages_and_returns(
            t["reward"],
            values.detach().view(steps, envs),
            t["terminated"],
            t["truncated"],
            self._bootstrap(t),
            p.gamma,
            p.gae_lambda,
        )
        advantages, returns = advantages.flatten(), returns.flatten()
        if p.normalize_advantages:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        log_probs = F.log_softmax(logits, dim=1)
        entropy = -(log_probs.exp() * log_probs).sum(dim=1).mean()
        chosen = log_probs.gather(1, t["action"].flatten().unsqueeze(1)).squeeze(1)
        policy_loss = -(advantages * chosen).mean()
        value_loss = 0.5 * (returns - values).pow(2).mean()
        loss = policy_loss + p.value_coef * value_loss - p.entropy_coef * entropy
        self.optimizer.zero_grad()
        loss.backward()
        grad_norm = nn.utils.clip_grad_norm_(self.net.parameters(), p.max_grad_norm)
        for group in self.optimizer.param_groups:
            group["lr"] = self.learning_rate()
        self.optimizer.step()
        self.n_updates += 1
        stats = {
            "policy_loss": policy_loss,
            "value_loss": value_loss,
            "entropy": entropy,
            "grad_norm": grad_norm,
            "mean_value": values.mean(),
        }
        return {k: float(v.detach()) for k, v in stats.items()}

    @torch.no_grad()
    def _bootstrap(self, t: dict[str, Tensor]) -> Tensor:
        """V(s'_t) (T, E) where step t is the last one or truncated (and not terminated); 0
        elsewhere, where :func:`advantages_and_returns` does not read it."""
        needed = t["truncated"].clone()
        needed[-1] = True
        needed &= ~t["terminated"]
        bootstrap = torch.zeros_like(t["reward"])
        if bool(needed.any()):
            rows = [t[k][needed] for k in ("next_robot", "next_humans", "next_mask")]
            bootstrap[needed] = self.net.value(*rows)
        return bootstrap

    def learning_rate(self) -> float:
        """The learning rate of the next gradient step (``lr_schedule``)."""
        p = self.params
        if p.lr_schedule == "constant":
            return p.lr
        return p.lr * max(0.0, 1.0 - self.episodes / self.config.episodes)

    def episodes_done(self, episodes: int) -> None:
        """Advance the learning-rate schedule."""
        self.episodes = episodes

    def policy(self, name: str) -> A2CPolicy:
        return A2CPolicy(self.net, self.config.world, name)

    def model_payload(self, info: dict[str, Any]) -> dict[str, Any]:
        return {
            "format": A2C_MODEL_FORMAT,
            "a2c": {
                k: list(v) if isinstance(v, tuple) else v for k, v in to_dict(self.params).items()
            },
            "world": to_dict(self.config.world),
            "info": info,
            "network": {k: v.cpu() for k, v in self.net.state_dict().items()},
        }

    def state_dict(self) -> dict[str, Any]:
        return {
            "network": self.net.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "generator": self.generator.get_state(),
            "rollout": self.rollout,
            "n_updates": self.n_updates,
            "episodes": self.episodes,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.net.load_state_dict(state["network"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.generator.set_state(state["generator"])
        self.rollout = list(state["rollout"])
        self.n_updates = int(state["n_updates"])
        self.episodes = int(state.get("episodes", 0))  # older checkpoints: constant rate only


def load_a2c_payload(payload: dict[str, Any], path: Path) -> tuple[A2CPolicy, WorldConfig]:
    """The greedy policy of an LSTM-A2C model file (format :data:`A2C_MODEL_FORMAT`)."""
    require_format(payload, path, A2C_MODEL_FORMAT, "an LSTM-A2C")
    params = from_dict(A2CConfig, payload["a2c"], f"{path}: a2c")
    world = WorldConfig.from_dict(payload["world"])
    net = ActorCritic(params)
    load_weights(net, payload["network"], path, "its a2c settings")
    name = payload["info"].get("name", "lstm-a2c")
    metadata = {"model": str(path), "algo": "a2c", "encoder": "lstm-rl", **payload["info"]}
    return A2CPolicy(net.eval(), world, name, metadata), world
