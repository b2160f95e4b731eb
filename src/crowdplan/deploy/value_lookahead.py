"""The one-step lookahead of an exported value network, numpy + onnxruntime only (no torch).

The greedy action of CADRL, LSTM-RL and SARL is ``argmax_a r(s, a) + gamma_step * V(s'_a)``. The
81 candidate next states (constant-velocity humans), their rewards and features come from
:mod:`crowdplan.sim.candidates`, the module the training-time lookahead uses; the exported network
evaluates all of them, and the current states when their attention scores are wanted, in one
batched onnxruntime call.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from crowdplan.config import WorldConfig
from crowdplan.deploy.manifest import DEPLOYABLE_LOOKAHEAD, Manifest, check_deployable_lookahead
from crowdplan.features import Features
from crowdplan.sim.candidates import candidate_values, one_step

# runs the network on robot-centric features; returns its outputs (value (B,) first)
Network = Callable[[Features], list[np.ndarray]]


class ValueLookahead:
    """Greedy one-step lookahead over an exported value network.

    Args:
        manifest: the export's manifest (kind "value-network" with its lookahead fields).
        network: runs the exported network on robot-centric features.
    """

    def __init__(self, manifest: Manifest, network: Network):
        if not manifest.is_value_network:
            raise ValueError(f"a {manifest.kind!r} is not a value network")
        check_deployable_lookahead(manifest.lookahead)
        # the world the network was trained in: dt, kinematics, action frame and table, the
        # discomfort distance of the reward
        self.config = WorldConfig.from_dict(manifest.world)
        self.gamma_step = float(manifest.gamma_step)
        self.network = network

    def evaluate(
        self, robot: np.ndarray, humans: np.ndarray, mask: np.ndarray, current: Features | None
    ) -> tuple[np.ndarray, list[np.ndarray] | None]:
        """Action values (E, 81) for raw observations robot (E, 9), humans (E, N, 5), mask
        (E, N), and the network's outputs on ``current`` (the features of the observed states,
        None: not wanted) from the same call."""
        candidates = one_step(robot, humans, mask, self.config, DEPLOYABLE_LOOKAHEAD)
        feats = candidates.features
        if current is not None:
            feats = Features(*(np.concatenate([c, x]) for c, x in zip(feats, current, strict=True)))
        outputs = self.network(feats)
        rows = candidates.rewards.size
        values = candidate_values(candidates, outputs[0][:rows], self.gamma_step)
        return values, None if current is None else [out[rows:] for out in outputs]
