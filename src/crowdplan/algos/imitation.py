"""Imitation learning from ORCA demonstrations (SPEC section 6).

The robot is driven by the ORCA planner (:mod:`crowdplan.algos.orca_planner`, safety space 0.15
as CrowdNav's demonstrations); every visited state is labelled with its discounted return
``G_t = sum_k gamma_step^k r_{t+k}`` to the end of its episode (a timeout ends it too, as in
CrowdNav). The value baselines regress their value network on these returns (MSE, SGD with
momentum, :func:`fit_values`). With ``discrete=True`` the robot executes, at every step, the one
of the 81 actions nearest to ORCA's command, so that the demonstrations are transitions a
discrete-action agent could have made (DSAC's warm start, :mod:`crowdplan.algos.dsac_agent`).

Demonstration episodes use their own seeds, ``DEMO_SEED_BASE + 100000 * run_seed + k``, disjoint
from the test (1000..1499), validation (0..999) and training (2000, 2001, ...) episodes.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from crowdplan.algos.orca_planner import OrcaPlanner
from crowdplan.config import WorldConfig
from crowdplan.features import Features, robot_centric
from crowdplan.sim.actions import every_action_velocity
from crowdplan.sim.world import OUTCOME_NAMES, RUNNING, World

DEMO_SEED_BASE = 1_000_000
SEEDS_PER_RUN = 100_000


@dataclass
class Demonstrations:
    """Transitions of the demonstrated episodes, one row per step (features robot-centric).

    ``returns`` are the discounted returns from each state; ``terminated`` marks goal or
    collision (a timeout is not terminal for the transitions handed to a replay buffer);
    ``actions`` are the executed action indices of discrete demonstrations (else None).
    """

    states: Features
    next_states: Features
    rewards: np.ndarray
    terminated: np.ndarray
    returns: np.ndarray
    outcomes: dict[str, int]
    actions: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.rewards)

    def outcome_rates(self) -> dict[str, float]:
        """``demo_<outcome>_rate`` of the demonstrated episodes (for a run's statistics)."""
        episodes = sum(self.outcomes.values())
        return {f"demo_{k}_rate": v / episodes for k, v in sorted(self.outcomes.items())}

    def transitions(self) -> tuple[np.ndarray, ...]:
        """The arguments of :meth:`crowdplan.algos.buffer.ReplayBuffer.add_batch`; continuous
        demonstrations store action 0 (ORCA's commands are not discrete actions)."""
        actions = self.actions if self.actions is not None else np.zeros(len(self), np.int64)
        done = self.terminated.astype(np.float32)
        return (*self.states, actions, self.rewards, *self.next_states, done)


def demonstration_seeds(episodes: int, run_seed: int) -> list[int]:
    """Seeds of the demonstration episodes of a run."""
    if not 1 <= episodes <= SEEDS_PER_RUN:
        raise ValueError(
            f"imitation learning needs 1..{SEEDS_PER_RUN} demonstration episodes, got {episodes} "
            "(set il_episodes: 0 to skip imitation learning)"
        )
    base = DEMO_SEED_BASE + SEEDS_PER_RUN * run_seed
    return list(range(base, base + episodes))


def collect_demonstrations(
    config: WorldConfig,
    seeds: list[int],
    gamma_step: float,
    safety_space: float = 0.15,
    batch_size: int = 100,
    discrete: bool = False,
) -> Demonstrations:
    """Run the ORCA planner on one episode per seed (``batch_size`` at a time); with
    ``discrete`` the robot executes the nearest discrete action to each ORCA command."""
    if not seeds:
        raise ValueError("no demonstration episodes: imitation learning needs at least one")
    if config.kinematics != "holonomic":
        raise ValueError(
            "ORCA demonstrations drive a holonomic robot; a unicycle world needs il_episodes: 0"
        )
    planner = OrcaPlanner(config.dt, config.orca, safety_space)
    parts = [
        _rollout(planner, config, seeds[i : i + batch_size], gamma_step, discrete)
        for i in range(0, len(seeds), batch_size)
    ]
    outcomes: dict[str, int] = {}
    for part in parts:
        for name, count in part.outcomes.items():
            outcomes[name] = outcomes.get(name, 0) + count

    def cat(arrays) -> np.ndarray:
        return np.concatenate(list(arrays))

    return Demonstrations(
        states=Features(*(cat(p.states[i] for p in parts) for i in range(3))),
        next_states=Features(*(cat(p.next_states[i] for p in parts) for i in range(3))),
        rewards=cat(p.rewards for p in parts),
        terminated=cat(p.terminated for p in parts),
        returns=cat(p.returns for p in parts),
        outcomes=outcomes,
        actions=cat(p.actions for p in parts) if discrete else None,
    )


def nearest_actions(commands: np.ndarray, robot: np.ndarray, config: WorldConfig) -> np.ndarray:
    """(E,) index of the discrete action whose velocity is closest to each (E, 2) command."""
    candidates, _ = every_action_velocity(
        robot, config.kinematics, config.action_frame, config.speed_sampling
    )
    return np.argmin(((candidates - commands[:, None, :]) ** 2).sum(axis=2), axis=1)


def _rollout(
    planner: OrcaPlanner,
    config: WorldConfig,
    seeds: list[int],
    gamma_step: float,
    discrete: bool = False,
) -> Demonstrations:
    world = World(config, len(seeds))
    world.reset(seeds)
    active = np.ones(len(seeds), dtype=bool)
    final = np.full(len(seeds), RUNNING)
    observations, rewards, terminated, alive, actions = [world.observe()], [], [], [], []
    while active.any():
        command = planner.act(*observations[-1]).actions
        if discrete:
            command = nearest_actions(command, observations[-1][0], config)
            actions.append(command)
        step = world.step(command, active)
        observations.append(world.observe())
        rewards.append(step.reward)  # 0 in environments whose episode has ended
        terminated.append(step.terminated)
        alive.append(active.copy())
        final = np.where(active, step.outcome, final)
        active &= step.outcome == RUNNING
    reward = np.array(rewards)  # (T, E)
    returns = np.zeros_like(reward)
    future = np.zeros(len(seeds))
    for t in range(len(reward) - 1, -1, -1):
        future = reward[t] + gamma_step * future
        returns[t] = future
    rows = np.array(alive)  # (T, E): the steps that belong to an episode
    robot, humans, mask = (np.array([obs[i] for obs in observations]) for i in range(3))
    unicycle = config.kinematics == "unicycle"
    names, counts = np.unique([OUTCOME_NAMES[int(code)] for code in final], return_counts=True)
    return Demonstrations(
        states=robot_centric(robot[:-1][rows], humans[:-1][rows], mask[:-1][rows], unicycle),
        next_states=robot_centric(robot[1:][rows], humans[1:][rows], mask[1:][rows], unicycle),
        rewards=reward[rows].astype(np.float32),
        terminated=np.array(terminated)[rows],
        returns=returns[rows].astype(np.float32),
        outcomes={str(n): int(c) for n, c in zip(names, counts, strict=True)},
        actions=np.array(actions)[rows] if discrete else None,
    )


def fit_values(
    net: nn.Module,
    demos: Demonstrations,
    epochs: int,
    lr: float,
    batch_size: int,
    generator: torch.Generator,
    momentum: float = 0.9,
    log: Callable[[str], None] | None = None,
) -> float:
    """Regress ``net`` on the demonstrations' returns (MSE, SGD with momentum, shuffled
    mini-batches drawn with ``generator``); returns the mean loss of the last epoch."""
    if epochs < 1:
        raise ValueError(f"imitation learning needs at least one epoch, got {epochs}")
    device = next(net.parameters()).device
    robot, humans, mask = (torch.from_numpy(x).to(device) for x in demos.states)
    target = torch.from_numpy(demos.returns).to(device)
    optimizer = torch.optim.SGD(net.parameters(), lr=lr, momentum=momentum)
    n = len(target)
    mean_loss = float("nan")
    for epoch in range(epochs):
        order = torch.randperm(n, generator=generator).to(device)
        total = 0.0
        for start in range(0, n, batch_size):
            index = order[start : start + batch_size]
            values, _ = net(robot[index], humans[index], mask[index])
            loss = torch.nn.functional.mse_loss(values, target[index])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += float(loss.detach()) * len(index)
        mean_loss = total / n
        if log is not None:
            log(f"imitation learning epoch {epoch + 1}/{epochs}: loss {mean_loss:.5f}")
    return mean_loss


def fit_actions(
    actor: nn.Module,
    demos: Demonstrations,
    epochs: int,
    lr: float,
    batch_size: int,
    generator: torch.Generator,
    log: Callable[[str], None] | None = None,
) -> dict[str, float]:
    """Behaviour cloning: train ``actor`` (``actor(robot, humans, mask)`` returns the logits
    first) to pick the demonstrated actions (cross-entropy, Adam, shuffled mini-batches drawn
    with ``generator``). Returns the last epoch's mean loss and its share of demonstrated
    actions that are the policy's argmax."""
    if demos.actions is None:
        raise ValueError("behaviour cloning needs discrete demonstrations (discrete=True)")
    if epochs < 1:
        raise ValueError(f"behaviour cloning needs at least one epoch, got {epochs}")
    device = next(actor.parameters()).device
    robot, humans, mask = (torch.from_numpy(x).to(device) for x in demos.states)
    target = torch.from_numpy(demos.actions).to(device)
    optimizer = torch.optim.Adam([p for p in actor.parameters() if p.requires_grad], lr=lr)
    n = len(target)
    stats = {"bc_loss": float("nan"), "bc_accuracy": float("nan")}
    for epoch in range(epochs):
        order = torch.randperm(n, generator=generator).to(device)
        total_loss, hits = 0.0, 0
        for start in range(0, n, batch_size):
            index = order[start : start + batch_size]
            logits = actor(robot[index], humans[index], mask[index])[0]
            loss = torch.nn.functional.cross_entropy(logits, target[index])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total_loss += float(loss.detach()) * len(index)
            hits += int((logits.detach().argmax(dim=1) == target[index]).sum())
        stats = {"bc_loss": total_loss / n, "bc_accuracy": hits / n}
        if log is not None:
            log(
                f"behaviour cloning epoch {epoch + 1}/{epochs}: loss {stats['bc_loss']:.4f}, "
                f"accuracy {stats['bc_accuracy']:.3f}"
            )
    return stats
