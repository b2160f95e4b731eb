"""Value-network RL with one-step lookahead: CADRL, LSTM-RL and SARL (SPEC section 6).

The recipe of CrowdNav's value-based baselines, batched over the loop's environments:

1. imitation learning (:meth:`ValueRLAgent.pretrain`): ``il_episodes`` ORCA demonstrations, the
   value network regressed on their discounted returns for ``il_epochs`` epochs; the
   demonstrations' transitions then seed the replay buffer (CrowdNav's memory held them too);
2. RL: the robot acts epsilon-greedily (``epsilon_start`` -> ``epsilon_end`` linearly over
   ``epsilon_decay_episodes`` episodes) on the one-step lookahead
   ``argmax_a r(s, a) + gamma_step * V(s'_a)`` (:mod:`crowdplan.sim.lookahead`); after every
   finished episode ``train_batches`` mini-batches regress ``V(s)`` on
   ``r + gamma_step * (1 - terminated) * V_target(s')``, the target network being copied from the
   value network every ``target_update_episodes`` episodes.

``gamma_step = gamma ** (dt * v_pref)``: ``gamma`` is the discount per second of travel at the
preferred speed. The target network only changes when it is copied, so ``V_target(s')`` of every
stored transition is computed once per copy, in large batches, and cached beside the replay
buffer (new transitions get theirs before the next update): the same targets as evaluating the
target network on every drawn batch, at a fraction of the cost. Differences from CrowdNav
(docs/baselines.md): targets use the current target network, not the one of the time the
episode was stored;
a time-limit truncation bootstraps instead of ending the return; candidates that end the episode
(collision, goal) are scored by their reward alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from crowdplan.algos.base import Observation, Transitions, frozen_copy, observation_features
from crowdplan.algos.buffer import ReplayBuffer
from crowdplan.algos.imitation import collect_demonstrations, demonstration_seeds, fit_values
from crowdplan.config import WorldConfig, check_fields, from_dict, spec, to_dict
from crowdplan.features import robot_centric
from crowdplan.models import initial_model_payload, load_weights, require_format
from crowdplan.nets.value import VALUE_NETWORKS, ValueNetwork, make_value_network
from crowdplan.policy import PolicyOutput
from crowdplan.sim.actions import N_ACTIONS
from crowdplan.sim.lookahead import (
    LOOKAHEAD_MODES,
    Candidates,
    action_values,
    check_precision,
    compiled_value_network,
    one_step,
    step_discount,
)

if TYPE_CHECKING:
    from crowdplan.sim.world import World
    from crowdplan.training.config import TrainConfig

MODEL_FORMAT = "crowdplan-value_rl-policy/1"


@dataclass
class ValueRLConfig:
    """Hyper-parameters of the value-based baselines (defaults: CrowdNav's); YAML ``value_rl``.

    Attributes:
        network: value network, ``cadrl``, ``lstm_rl`` or ``sarl``.
        lookahead: human next states in the lookahead, ``constant_velocity`` or ``oracle`` (the
            simulator's true next states, what CrowdNav did).
        gamma: discount per second of travel at v_pref (per step ``gamma ** (dt * v_pref)``).
        il_episodes: ORCA demonstration episodes (0: no imitation learning, RL starts from the
            random initialisation).
        il_epochs: passes over the demonstrations.
        il_lr: SGD learning rate of imitation learning.
        il_safety_space: ORCA safety space of the demonstrating robot (m).
        lr: SGD learning rate of RL.
        momentum: SGD momentum (imitation learning and RL).
        batch_size: states per mini-batch (imitation learning and RL).
        train_batches: RL mini-batches after every finished episode.
        buffer_size: replay capacity in transitions.
        epsilon_start, epsilon_end: exploration rate at the first RL episode and after the decay.
        epsilon_decay_episodes: episodes of the linear decay.
        target_update_episodes: episodes between copies of the value network to the target.
        init_model: a trained value_rl model file (or shipped model name, e.g. ``sarl``) whose
            value network starts the run instead of imitation learning (``il_episodes: 0``):
            same network, action frame and kinematics, any crowd size; the replay buffer and
            optimizer start empty. With ``validate_at_start`` the run keeps that model unless
            training beats it.
    """

    network: str = spec("sarl", choices=VALUE_NETWORKS)
    lookahead: str = spec("constant_velocity", choices=LOOKAHEAD_MODES)
    gamma: float = spec(0.9, low=0.0, high=1.0)
    il_episodes: int = spec(3000, low=0)
    il_epochs: int = spec(50, low=1)
    il_lr: float = spec(0.01, low=0.0, low_open=True)
    il_safety_space: float = spec(0.15, low=0.0)
    lr: float = spec(0.001, low=0.0, low_open=True)
    momentum: float = spec(0.9, low=0.0, high=1.0)
    batch_size: int = spec(100, low=1)
    train_batches: int = spec(100, low=0)
    buffer_size: int = spec(100_000, low=1)
    epsilon_start: float = spec(0.5, low=0.0, high=1.0)
    epsilon_end: float = spec(0.1, low=0.0, high=1.0)
    epsilon_decay_episodes: int = spec(4000, low=1)
    target_update_episodes: int = spec(50, low=1)
    init_model: str | None = None

    def __post_init__(self) -> None:
        check_fields(self, "value_rl")
        if self.init_model is not None and self.il_episodes > 0:
            raise ValueError(
                "value_rl.init_model and imitation learning (value_rl.il_episodes) both "
                "initialise the value network: set il_episodes: 0 to start from the model"
            )


class ValuePolicy:
    """Greedy one-step lookahead on a value network, over raw observations.

    The evaluation harness hands over the world it plays through :meth:`bind_world`: the
    lookahead then uses that world's configuration and, in ``oracle`` mode, queries it.
    Per-human scores are SARL's attention weights on the current state.
    """

    def __init__(
        self,
        net: ValueNetwork,
        world: WorldConfig,
        lookahead: str,
        gamma_step: float,
        name: str,
        metadata: dict | None = None,
    ):
        self.net = net
        self.world = world
        self.lookahead = lookahead
        self.gamma_step = gamma_step
        self.name = name
        self.metadata = {**(metadata or {}), "lookahead": lookahead}
        self.precision = "float32"
        self.compiled = False
        self._compiled_net: nn.Module | None = None  # made by the first set_compiled(True)
        self.kinematics = world.kinematics
        self._sim: World | None = None

    def set_lookahead(self, mode: str) -> None:
        """Propagate the humans by ``mode`` from the next decision on; recorded in the
        metadata (and so in every result written with this policy)."""
        if mode not in LOOKAHEAD_MODES:
            raise ValueError(f"lookahead must be one of {list(LOOKAHEAD_MODES)}, got {mode!r}")
        self.lookahead = mode
        self.metadata["lookahead"] = mode

    def set_precision(self, precision: str) -> None:
        """Run the lookahead's value call in ``precision`` (``float32`` or ``bfloat16``, see
        :func:`crowdplan.sim.lookahead.action_values`); recorded in the metadata when not
        float32."""
        check_precision(precision)
        self.precision = precision
        self._record_option("lookahead_precision", precision, default="float32")

    def set_compiled(self, compiled: bool) -> None:
        """Run the lookahead's value calls through ``torch.compile`` (``compiled``) or eagerly;
        recorded in the metadata when compiled (see
        :func:`crowdplan.sim.lookahead.compiled_value_network`)."""
        if compiled and self._compiled_net is None:
            self._compiled_net = compiled_value_network(self.net)
        self.compiled = compiled
        self._record_option("lookahead_compiled", compiled, default=False)

    def _record_option(self, key: str, value: Any, default: Any) -> None:
        """Write an option to the metadata (and so to every result) unless it has its default,
        so that results made with the defaults keep the keys they always had."""
        self.metadata.pop(key, None)
        if value != default:
            self.metadata[key] = value

    def __getstate__(self) -> dict[str, Any]:
        # a compiled module does not pickle (sharded evaluation sends the policy to workers):
        # each copy compiles its own
        state = self.__dict__.copy()
        state["_compiled_net"] = None
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self.set_compiled(self.compiled)

    def bind_world(self, world: World) -> None:
        """Play in ``world`` from now on (its observations are the ones :meth:`act` gets)."""
        self._sim = world

    def greedy(
        self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray, sim: World | None
    ) -> np.ndarray:
        """The best action (E,) of the lookahead; ``sim`` is the world the observation is of."""
        config = self.world if sim is None else sim.config
        candidates = one_step(robot, humans, mask, config, self.lookahead, sim)
        return self.candidate_values(candidates).argmax(dim=1).cpu().numpy()

    def candidate_values(self, candidates: Candidates) -> torch.Tensor:
        """(E, A) lookahead scores of ``candidates`` in this policy's precision, through the
        compiled network when :meth:`set_compiled` is on."""
        net = self._compiled_net if self.compiled else self.net
        return action_values(candidates, net, self.gamma_step, self.precision)

    @torch.no_grad()
    def act(self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray) -> PolicyOutput:
        actions = self.greedy(robot, humans, mask, self._sim)
        scores = None
        if self.net.has_scores:
            device = next(self.net.parameters()).device
            feats = robot_centric(robot, humans, mask, self.kinematics == "unicycle")
            _, attention = self.net(*(torch.from_numpy(x).to(device) for x in feats))
            scores = attention.cpu().numpy()
        return PolicyOutput(actions, scores)


class ValueRLAgent:
    """The training-loop agent of CADRL, LSTM-RL and SARL (see the module docstring)."""

    def __init__(self, config: TrainConfig, device: torch.device):
        self.config = config
        self.params: ValueRLConfig = config.algo_config
        self.device = device
        world = config.world
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(config.seed)
            self.net = make_value_network(self.params.network).to(device)
        if self.params.init_model is not None:
            self._load_initial_network(world)
        self.target = frozen_copy(self.net)
        self.optimizer = torch.optim.SGD(
            self.net.parameters(), lr=self.params.lr, momentum=self.params.momentum
        )
        self.buffer = ReplayBuffer(self.params.buffer_size, world.humans, seed=config.seed + 1)
        self.rng = np.random.default_rng(config.seed + 2)
        self.generator = torch.Generator().manual_seed(config.seed + 3)
        self.gamma_step = step_discount(self.params.gamma, world)
        self.unicycle = world.kinematics == "unicycle"
        self.episodes = 0
        self.target_copies = 0
        self.batch_credit = 0
        self.n_updates = 0
        # V_target(s') per buffer slot, valid up to buffer.added == values_synced
        self.next_values = np.zeros(self.params.buffer_size, dtype=np.float32)
        self.values_synced = 0
        self.values_stale = True  # the target changed: every cached value must be recomputed
        self._greedy = self.policy(config.name)

    def _load_initial_network(self, world: WorldConfig) -> None:
        payload, path = initial_model_payload(
            self.params.init_model, "value_rl", MODEL_FORMAT, "a value_rl", world
        )
        network = payload["value_rl"]["network"]
        if network != self.params.network:
            raise ValueError(
                f"value_rl.init_model {path} holds a {network!r} value network, the run trains "
                f"{self.params.network!r} (value_rl.network)"
            )
        load_weights(self.net, payload["network"], path, f"value network {network!r}")

    # ------------------------------------------------------------------ imitation learning
    def pretrain(self, log: Any) -> dict[str, float] | None:
        """Imitation learning from ORCA demonstrations; nothing when ``il_episodes`` is 0."""
        p = self.params
        if p.il_episodes == 0:
            start = p.init_model or "the random initialisation"
            log(f"value_rl: il_episodes is 0, RL starts from {start}")
            return None
        seeds = demonstration_seeds(p.il_episodes, self.config.seed)
        demos = collect_demonstrations(self.config.world, seeds, self.gamma_step, p.il_safety_space)
        loss = fit_values(
            self.net, demos, p.il_epochs, p.il_lr, p.batch_size, self.generator, p.momentum, log
        )
        self.target.load_state_dict(self.net.state_dict())
        self.values_stale = True
        self.buffer.add_batch(*demos.transitions())
        return {"demo_states": len(demos), "il_loss": loss, **demos.outcome_rates()}

    # ------------------------------------------------------------------ RL
    @property
    def epsilon(self) -> float:
        """Exploration rate of the current episode."""
        p = self.params
        fraction = min(self.episodes / p.epsilon_decay_episodes, 1.0)
        return p.epsilon_start + (p.epsilon_end - p.epsilon_start) * fraction

    def act(self, obs: Observation, world: Any) -> np.ndarray:
        num_envs = len(obs["robot"])
        explore = self.rng.random(num_envs) < self.epsilon
        actions = self.rng.integers(0, N_ACTIONS, size=num_envs)
        if not explore.all():
            mask = obs["mask"].astype(bool)
            greedy = self._greedy.greedy(obs["robot"], obs["humans"], mask, world)
            actions = np.where(explore, actions, greedy)
        return actions

    def observe(self, step: Transitions) -> None:
        self.buffer.add_step(
            observation_features(step.obs, self.unicycle),
            step,
            observation_features(step.next_obs, self.unicycle),
        )
        finished = int(np.count_nonzero(step.terminated | step.truncated))
        self.batch_credit += finished * self.params.train_batches

    def update(self) -> dict[str, float] | None:
        stats = None
        if self.batch_credit > 0:
            self._refresh_next_values()
        while self.batch_credit > 0:
            index = self.buffer.sample_index(self.params.batch_size)
            batch = self.buffer.gather(index, ("robot", "humans", "mask", "reward", "done"))
            batch = {k: v.to(self.device) for k, v in batch.items()}
            next_value = torch.from_numpy(self.next_values[index]).to(self.device)
            target = batch["reward"] + self.gamma_step * (1.0 - batch["done"]) * next_value
            loss = self.value_loss(batch["robot"], batch["humans"], batch["mask"], target)
            self.optimizer.zero_grad()
            loss.backward()
            self.optimizer.step()
            self.batch_credit -= 1
            self.n_updates += 1
            stats = {"value_loss": float(loss.detach()), "epsilon": self.epsilon}
        return stats

    def value_loss(
        self, robot: torch.Tensor, humans: torch.Tensor, mask: torch.Tensor, target: torch.Tensor
    ) -> torch.Tensor:
        """Mean squared error of the value network against ``target`` on one batch."""
        value, _ = self.net(robot, humans, mask)
        return F.mse_loss(value, target)

    def episodes_done(self, episodes: int) -> None:
        """Advance the exploration schedule; copy the target network every
        ``target_update_episodes`` episodes."""
        self.episodes = episodes
        copies = episodes // self.params.target_update_episodes
        if copies > self.target_copies:
            self.target.load_state_dict(self.net.state_dict())
            self.target_copies = copies
            self.values_stale = True

    @torch.no_grad()
    def _refresh_next_values(self, chunk: int = 4096) -> None:
        """Compute ``V_target(s')`` of the slots whose cached value is out of date: all of them
        after a target copy, else those added since the last refresh."""
        buffer = self.buffer
        if self.values_stale:
            slots = np.arange(len(buffer))
        else:
            slots = buffer.recent_slots(buffer.added - self.values_synced)
        for start in range(0, len(slots), chunk):
            part = slots[start : start + chunk]
            after = buffer.gather(part, ("next_robot", "next_humans", "next_mask"), self.device)
            values, _ = self.target(after["next_robot"], after["next_humans"], after["next_mask"])
            self.next_values[part] = values.cpu().numpy()
        self.values_synced = buffer.added
        self.values_stale = False

    # ------------------------------------------------------------------ policy, files, state
    def policy(self, name: str) -> ValuePolicy:
        return ValuePolicy(
            self.net, self.config.world, self.params.lookahead, self.gamma_step, name
        )

    def model_payload(self, info: dict[str, Any]) -> dict[str, Any]:
        return {
            "format": MODEL_FORMAT,
            "value_rl": to_dict(self.params),
            "world": to_dict(self.config.world),
            "info": {**info, "network": self.params.network, "lookahead": self.params.lookahead},
            "network": {k: v.cpu() for k, v in self.net.state_dict().items()},
        }

    def state_dict(self) -> dict[str, Any]:
        return {
            "net": self.net.state_dict(),
            "target": self.target.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "buffer": self.buffer.state_dict(),
            "rng": self.rng.bit_generator.state,
            "generator": self.generator.get_state(),
            "counters": {
                "episodes": self.episodes,
                "target_copies": self.target_copies,
                "batch_credit": self.batch_credit,
                "n_updates": self.n_updates,
                "values_synced": self.values_synced,
                "values_stale": self.values_stale,
            },
            "next_values": torch.from_numpy(self.next_values.copy()),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self.net.load_state_dict(state["net"])
        self.target.load_state_dict(state["target"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.buffer.load_state_dict(state["buffer"])
        self.rng.bit_generator.state = state["rng"]
        self.generator.set_state(state["generator"])
        counters = state["counters"]
        self.episodes = int(counters["episodes"])
        self.target_copies = int(counters["target_copies"])
        self.batch_credit = int(counters["batch_credit"])
        self.n_updates = int(counters["n_updates"])
        if "next_values" in state:
            self.next_values[:] = state["next_values"].numpy()
            self.values_synced = int(counters["values_synced"])
            self.values_stale = bool(counters["values_stale"])
        else:  # a checkpoint from before the cache: recompute every value
            self.values_stale = True


def load_value_rl_payload(payload: dict[str, Any], path: Path) -> tuple[ValuePolicy, WorldConfig]:
    """The greedy lookahead policy of a value_rl model file (format :data:`MODEL_FORMAT`)."""
    require_format(payload, path, MODEL_FORMAT, "a value_rl")
    params = from_dict(ValueRLConfig, payload["value_rl"], "value_rl")
    world = WorldConfig.from_dict(payload["world"])
    net = make_value_network(params.network)
    load_weights(net, payload["network"], path, f"value network {params.network!r}")
    info = payload["info"]
    metadata = {"model": str(path), "algo": "value_rl", **info}
    name = info.get("name", params.network)
    gamma_step = step_discount(params.gamma, world)
    return ValuePolicy(net.eval(), world, params.lookahead, gamma_step, name, metadata), world
