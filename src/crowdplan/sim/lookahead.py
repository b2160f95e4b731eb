"""Batched one-step lookahead over every discrete action (the value-based baselines, SPEC 6).

The candidate next states, their rewards and features come from :mod:`crowdplan.sim.candidates`
(numpy only, shared with the deployment runtime); :func:`action_values` evaluates the value
network on all of them in one torch call and scores each candidate ``r + gamma_step * V(s')``,
without the bootstrap term where the candidate ends the episode (collision or goal).

The value call runs in float32 or, on request, under bfloat16 autocast on the CPU: about twice
as fast where the CPU has bfloat16 instructions, but its rounding moves the values by up to about
0.006 and so changes some greedy actions (docs/benchmarks.md, "bfloat16 for the lookahead").
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

PRECISIONS = ("float32", "bfloat16")

# The value network sees the candidates in chunks of about this many (state, human) pairs: a
# 64-environment decision has 81 x 64 x N of them, and in one call every layer's activations
# (tens of MB in float32) leave the cache and are paged in afresh by each call. Chunks of a few
# thousand pairs run faster (docs/benchmarks.md). A chunk starts at a multiple of
# STATES_ALIGNED states, so that each row keeps its place in the matmul kernels' row blocks and
# gets the same value as in one call (on one thread; measured, not promised by the libraries).
PAIRS_PER_CALL = 4096
STATES_ALIGNED = 64

__all__ = [
    "LOOKAHEAD_MODES",
    "PRECISIONS",
    "Candidates",
    "check_precision",
    "Timing",
    "action_values",
    "check_mode",
    "next_humans",
    "one_step",
    "step_discount",
]


def check_precision(precision: str) -> None:
    """Refuse a precision of the value call other than :data:`PRECISIONS`."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {list(PRECISIONS)}, got {precision!r}")


@torch.no_grad()
def action_values(
    candidates: Candidates, value_net: Any, gamma_step: float, precision: str = "float32"
) -> torch.Tensor:
    """(E, A) ``r + gamma_step * V(s')`` of every candidate; terminal candidates score ``r``.

    ``precision``: ``float32``, or ``bfloat16`` for the value call alone under autocast (on
    the network's device); the candidates, rewards and scores are computed as in float32."""
    check_precision(precision)
    device = next(value_net.parameters()).device
    features = [torch.from_numpy(np.ascontiguousarray(x)).to(device) for x in candidates.features]
    per_chunk = PAIRS_PER_CALL // max(features[1].shape[1], 1)
    per_chunk = max(STATES_ALIGNED, per_chunk - per_chunk % STATES_ALIGNED)
    chunks = zip(*(x.split(per_chunk) for x in features), strict=True)
    with torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bfloat16"):
        values = torch.cat([value_net(*chunk)[0] for chunk in chunks])
    values = values.float().cpu().numpy()
    return torch.from_numpy(candidate_values(candidates, values, gamma_step))
