"""What DSAC's critic says where its policy stands still for good.

A run trained with ``keep_validation_networks: true`` writes its networks at every validation
(``validation_networks/episode-NNNNNN.pt``). For each such file this module plays the test
cases with the file's greedy policy, takes the timeouts that ended frozen
(:mod:`crowdplan.analysis.timeouts`) and, at the last state of each, as it was and with the
robot moving at its preferred speed to its goal (``timeouts --probe-stop``), reads the actor
and the critic of the same moment:

- ``P(stop)``: the actor's probability of the stop action (action 0);
- ``critic prefers stop``: the share of those states where the twin critics' joint estimate
  (their mean with ``dsac.average_q``, else their minimum: the value the actor is trained to
  follow) is highest for the stop action;
- ``max Q - Q(greedy)``: what the critic says the actor's greedy action gives up against the
  critic's best action (0 where they agree). The critic's values of actions the policy never
  takes are extrapolations, so the same columns on ordinary states (the steps of ORCA's paths
  through the first 100 validation cases) are the scale to read them against;
- ``log P(greedy) - log P(critic's best)``: how far the actor's softmax is from the critic's
  best action, in nats (0 where they agree). The policy loss moves an action's logit in
  proportion to its probability, so at a gap of tens of nats the actor has, in effect, no
  gradient towards the critic's choice.

::

    python -m crowdplan.analysis.frozen_critic NETWORKS... [--scenario circle_crossing]
        [--humans 5] [--episodes 500]
"""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from crowdplan.algos.dsac import DSAC
from crowdplan.algos.dsac_networks import NETWORKS_FORMAT, networks_of
from crowdplan.analysis.argmax_flips import probe_states
from crowdplan.analysis.timeouts import (
    add_test_case_args,
    check_test_case_args,
    frozen,
    last_state,
    load_each,
    print_table_head,
)
from crowdplan.config import WorldConfig
from crowdplan.evaluation import Trace, run_episodes, test_seeds
from crowdplan.features import robot_centric
from crowdplan.models import DSACPolicy
from crowdplan.sim.actions import STOP
from crowdplan.training.checkpoint import read_checkpoint
from crowdplan.training.config import TrainConfig, config_from_dict, with_legacy_defaults

ORCA_CASES = 100  # validation cases whose ORCA paths give the comparison states


@dataclass(frozen=True)
class Readings:
    """The actor and the critic at a batch of states, one entry per state."""

    p_stop: np.ndarray  # the actor's probability of stopping
    critic_prefers_stop: np.ndarray  # bool: the critic's best action is the stop
    regret: np.ndarray  # max Q - Q(the actor's greedy action): what the critic would gain
    log_p_gap: np.ndarray  # log P(the actor's greedy action) - log P(the critic's best action)


def load_networks(path: Path) -> tuple[DSAC, TrainConfig]:
    """The DSAC networks and temperature of a networks file (a run's
    ``validation_networks/episode-NNNNNN.pt``, or one written by
    :mod:`crowdplan.algos.dsac_networks`) or of a DSAC training checkpoint, with the run's
    config."""
    state = read_checkpoint(path, also=(NETWORKS_FORMAT,))
    config = config_from_dict(with_legacy_defaults(state["config"]))
    core = DSAC(config.algo_config, config.encoder, seed=config.seed)
    core.load_networks(networks_of(state, path))
    return core, config


@torch.no_grad()
def read_states(
    core: DSAC, robot: np.ndarray, humans: np.ndarray, present: np.ndarray, unicycle: bool
) -> Readings:
    """The actor's and the critic's view of a batch of observations."""
    features = [torch.from_numpy(x) for x in robot_centric(robot, humans, present, unicycle)]
    logits, _ = core.actor(*features)
    log_p = torch.log_softmax(logits, dim=1)
    q = core.twin_q(*core.critic(*features))
    critic_best = q.argmax(dim=1, keepdim=True)
    return Readings(
        p_stop=log_p[:, STOP].exp().numpy(),
        critic_prefers_stop=(critic_best[:, 0] == STOP).numpy(),
        regret=(
            q.max(dim=1).values - q.gather(1, logits.argmax(dim=1, keepdim=True))[:, 0]
        ).numpy(),
        log_p_gap=(log_p.max(dim=1).values - log_p.gather(1, critic_best)[:, 0]).numpy(),
    )


def frozen_readings(
    core: DSAC, world: WorldConfig, traces: list[Trace], moving: bool
) -> Readings | None:
    """The readings at the last state of each frozen trace of ``world`` (None without one): as
    it was, or with the robot moving to its goal."""
    if not traces:
        return None
    holonomic = world.kinematics == "holonomic"
    states = [last_state(t, world.robot_v_pref, moving, holonomic) for t in traces]
    batch = [np.concatenate([s[i] for s in states]) for i in range(3)]
    return read_states(core, *batch, unicycle=not holonomic)


def columns(readings: Readings | None) -> list[str]:
    """The table cells of a batch of readings, means over it (dashes for none)."""
    if readings is None:
        return ["-"] * len(READINGS)
    return [
        f"{readings.p_stop.mean():.3f}",
        f"{readings.critic_prefers_stop.mean():.2f}",
        f"{readings.regret.mean():.4f}",
        f"{readings.log_p_gap.mean():.1f}",
    ]


READINGS = (
    "P(stop)",
    "critic prefers stop",
    "max Q - Q(greedy)",
    "log P(greedy) - log P(critic's best)",
)
PLACES = ("frozen, as it was", "frozen, moving to the goal", "ORCA paths")
HEADER = [
    "networks",
    "temperature",
    "success",
    "frozen timeouts",
    *(f"{where}: {what}" for where in PLACES for what in READINGS),
]


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "networks", nargs="+", type=Path, help="DSAC networks files or training checkpoints"
    )
    add_test_case_args(parser, scenario="circle_crossing")
    args = parser.parse_args(argv)
    check_test_case_args(parser, args)
    torch.set_num_threads(1)
    loaded = load_each(parser, load_networks, args.networks)
    print_table_head(args, HEADER)
    for path, (core, config) in zip(args.networks, loaded, strict=True):
        world = dataclasses.replace(config.world, scenario=args.scenario, humans=args.humans)
        policy = DSACPolicy(core.actor, world, config.name)
        records = run_episodes(policy, world, test_seeds(args.episodes), record_traces=True)
        traces = frozen(records)
        orca_paths = probe_states(world, ORCA_CASES)
        readings = [
            frozen_readings(core, world, traces, moving=False),
            frozen_readings(core, world, traces, moving=True),
            read_states(core, *orca_paths, unicycle=world.kinematics == "unicycle"),
        ]
        success = np.mean([r.outcome == "goal" for r in records])
        alpha = float(core.log_alpha.detach().exp())
        row = [str(path), f"{alpha:.2e}", f"{success:.3f}", str(len(traces))]
        for reading in readings:
            row += columns(reading)
        print("| " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
