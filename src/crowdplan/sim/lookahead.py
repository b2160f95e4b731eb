"""Batched one-step lookahead over every discrete action (the value-based baselines, SPEC 6).

The candidate next states, their rewards and features come from :mod:`crowdplan.sim.candidates`
(numpy only, shared with the deployment runtime); :func:`action_values` evaluates the value
network on all of them in one torch call and scores each candidate ``r + gamma_step * V(s')``,
without the bootstrap term where the candidate ends the episode (collision or goal).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from crowdplan.sim.candidates import (
    LOOKAHEAD_MODES,
    Candidates,
    Timing,
    candidate_values,
    check_mode,
    next_humans,
    one_step,
    step_discount,
)

__all__ = [
    "LOOKAHEAD_MODES",
    "Candidates",
    "Timing",
    "action_values",
    "check_mode",
    "next_humans",
    "one_step",
    "step_discount",
]


@torch.no_grad()
def action_values(candidates: Candidates, value_net: Any, gamma_step: float) -> torch.Tensor:
    """(E, A) ``r + gamma_step * V(s')`` of every candidate; terminal candidates score ``r``."""
    device = next(value_net.parameters()).device
    values, _ = value_net(
        *(torch.from_numpy(np.ascontiguousarray(x)).to(device) for x in candidates.features)
    )
    return torch.from_numpy(candidate_values(candidates, values.cpu().numpy(), gamma_step))
